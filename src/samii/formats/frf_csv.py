"""The frequency-response CSV format (DATA_FORMATS.md) <-> :class:`samii.FrequencyResponse`."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from samii.formats.files import _AXIS_FMT, _VALUE_FMT, DataFormatError, _format_table, _num, _read_table, _short, _Table, _write_atomic
from samii.formats.timeseries_csv import _stated_rate
from samii.frequency_response import CHANNELS, FrequencyResponse

#: Range of a linear FRF magnitude: 1e-20...1e20 (-400...+400 dB). SAMII's
#: channels lie within about 1e-4...1e4 in SI units; the range leaves 16 orders
#: of margin either way and refuses what has no dB value (0) or no meaning
#: (1e300, whose square overflows). The fit works on 20*log10|H|.
MAG_RANGE = (1e-20, 1e20)
#: Largest |phase| [deg]: 1e5 (about 280 turns). Each pole or zero turns the
#: phase by at most 90 deg and a delay tau by 360*f*tau: SAMII's channels (a
#: few poles, millisecond delays, below 1 kHz) stay within a few thousand
#: degrees even unwrapped; 1e5 deg would take a 0.28 s delay at 1 kHz. A phase
#: beyond it is a corrupt cell or a unit slip, not a measured phase.
MAX_ABS_PHASE_DEG = 1e5
#: Highest frequency [Hz]: 1 MHz. Hydraulics, beam and sensors carry nothing
#: above tens of kHz; beyond 1 MHz a frequency axis is corrupt or in the wrong unit.
MAX_FREQ_HZ = 1e6


def _frf_column(name: str) -> bool:
    """A column the FRF format defines: freq_hz and each channel's magnitude, phase and coherence."""
    return name == "freq_hz" or any(name in (f"{ch}_mag", f"{ch}_phase_deg", f"{ch}_coh") for ch in CHANNELS)


# --------------------------------------------------------------------------- frequency response


def _check_nyquist(table: _Table, f: np.ndarray) -> None:
    """A response estimated from records sampled at a stated ``# sample_rate_hz:`` (a plain number) ends at its Nyquist
    frequency: a point above it contradicts the header (a diagnosis models the sampling from it)."""
    rate = _stated_rate(table)
    if rate is None:
        return
    text = table.metadata["sample_rate_hz"]
    bad = np.flatnonzero(f > rate / 2)
    if bad.size:
        raise table.error(
            f"frequency {_num(f[bad[0]])} Hz lies above the Nyquist frequency {rate / 2:g} Hz of '# sample_rate_hz: "
            f"{_short(text)}' (line {table.metadata_lines.get('sample_rate_hz')}): no record sampled so holds a "
            "response there; the header or the frequencies are wrong",
            row=int(bad[0]),
            column="freq_hz",
        )


def read_frf_csv(path) -> FrequencyResponse:
    """Read a frequency-response CSV (DATA_FORMATS.md) into a :class:`~samii.FrequencyResponse`.

    Channels present as ``<ch>_mag`` (linear) and ``<ch>_phase_deg`` (wrapped or
    unwrapped), with optional ``<ch>_coh``. Other columns are ignored.

    Raises
    ------
    DataFormatError
        On any defect; the message names the file, line and/or column.
    """
    table = _read_table(path, known=_frf_column)
    table.require(("freq_hz",))
    f = table.col("freq_hz")
    bad = np.flatnonzero(f <= 0)
    if bad.size:
        raise table.error(f"expected a positive frequency, got {_num(f[bad[0]])}", row=int(bad[0]), column="freq_hz")
    bad = np.flatnonzero(f > MAX_FREQ_HZ)
    if bad.size:
        raise table.error(
            f"expected a frequency up to {MAX_FREQ_HZ:g} Hz, got {_num(f[bad[0]])} (in rad/s, or corrupt?)", row=int(bad[0]), column="freq_hz"
        )
    bad = np.flatnonzero(np.diff(f) <= 0)
    if bad.size:
        k = int(bad[0]) + 1
        what = "a repeated" if f[k] == f[k - 1] else "a decreasing"
        raise table.error(
            f"expected strictly increasing frequency, got {what} {_num(f[k])} after {_num(f[k - 1])} (line {int(table.lines[k - 1])})",
            row=k,
            column="freq_hz",
        )
    _check_nyquist(table, f)
    kw = {}
    for ch in CHANNELS:
        mag_name, ph_name, coh_name = f"{ch}_mag", f"{ch}_phase_deg", f"{ch}_coh"
        if table.has(mag_name) != table.has(ph_name):
            have, lack = (mag_name, ph_name) if table.has(mag_name) else (ph_name, mag_name)
            raise DataFormatError(table.path, f"column {have!r} needs its partner {lack!r}", line=table.header_line, column=lack)
        if not table.has(mag_name):
            if table.has(coh_name):
                raise DataFormatError(
                    table.path, f"coherence without its channel: expected {mag_name!r} and {ph_name!r}", line=table.header_line, column=coh_name
                )
            continue
        mag, phase = table.col(mag_name), table.col(ph_name)
        k, message = _bad_magnitude(mag)
        if message:
            raise table.error(message, row=k, column=mag_name)
        k, message = _bad_phase(phase)
        if message:
            raise table.error(message, row=k, column=ph_name)
        if (why := _phase_in_radians(ch, mag, phase)) is not None:
            raise DataFormatError(
                table.path,
                f"every value of {ph_name!r} lies within +-{RADIAN_CHECK_MAX:.3g} ({phase.size} points): "
                f"that is a phase in radians; expected degrees ({why})",
                line=table.header_line,
                column=ph_name,
            )
        kw[ch] = mag * np.exp(1j * np.unwrap(np.radians(phase)))
        if table.has(coh_name):
            coh = table.col(coh_name)
            bad = np.flatnonzero((coh < 0) | (coh > 1))
            if bad.size:
                raise table.error(f"expected a coherence in 0...1, got {_num(coh[bad[0]])}", row=int(bad[0]), column=coh_name)
            kw[coh_name] = coh
    if not any(ch in kw for ch in CHANNELS):
        raise DataFormatError(
            table.path,
            "no channel found: expected at least one pair of columns act_mag/act_phase_deg, base_mag/base_phase_deg or total_mag/total_phase_deg",
            line=table.header_line,
        )
    try:
        return FrequencyResponse(f, metadata=table.metadata, **kw)
    except ValueError as exc:  # the checks above should have said it first
        raise DataFormatError(table.path, str(exc)) from None


def _bad_magnitude(mag: np.ndarray) -> tuple[int, str]:
    """(index, message) of the first magnitude out of MAG_RANGE, or (-1, "")."""
    lo, hi = MAG_RANGE
    bad = np.flatnonzero(~((mag >= lo) & (mag <= hi)))
    if not bad.size:
        return -1, ""
    k = int(bad[0])
    if mag[k] < 0:
        return k, f"expected a non-negative linear magnitude (not dB), got {_num(mag[k])}"
    return k, (
        f"expected a linear magnitude within {lo:g}...{hi:g} ({20 * np.log10(lo):+.0f}...{20 * np.log10(hi):+.0f} dB), "
        f"got {_num(mag[k])}" + (" (a magnitude of 0 has no dB value: is the channel connected?)" if mag[k] == 0 else "")
    )


#: theta/v phase columns this long are checked for radians: every value within RADIAN_CHECK_MAX (3 pi: an
#: unwrapped phase in radians to -540 deg) is not a phase in degrees of an integrator.
RADIAN_CHECK_POINTS = 10
RADIAN_CHECK_MAX = 3.0 * np.pi


#: A magnitude peak this prominent [dB] is a resonance, across which a phase in degrees swings far beyond +-3 pi.
RADIAN_CHECK_PEAK_DB = 6.0


def _phase_in_radians(ch: str, mag: np.ndarray, phase: np.ndarray) -> str | None:
    """Why a phase column whose every value lies within +-RADIAN_CHECK_MAX (3 pi) of RADIAN_CHECK_POINTS or more points
    cannot be in degrees, or None. theta/v (``act``) and xdd/v (``total``) integrate: -90 deg at low frequency, lagging
    further past the actuator's resonance. xdd/theta (``base``) may stay near 0 deg over a band below its first mode
    (its s^4 rise), so it is held to it only where its magnitude shows a resonance: across one a phase in degrees swings
    by about 180. (In radians, wrapped or not, each stays within 3 pi over 0.1-40 Hz.)"""
    if phase.size < RADIAN_CHECK_POINTS or not np.all(np.abs(phase) <= RADIAN_CHECK_MAX):
        return None
    if ch in ("act", "total"):
        return f"{'theta/v' if ch == 'act' else 'xdd/v'}'s phase is near -90 deg at low frequency, where theta/v integrates"
    from scipy.signal import find_peaks  # (lazy: imports scipy, only when called)

    with np.errstate(divide="ignore"):
        db = 20.0 * np.log10(np.abs(mag))
    peaks, _ = find_peaks(np.nan_to_num(db, neginf=-400.0), prominence=RADIAN_CHECK_PEAK_DB)
    if peaks.size:
        return (
            f"its magnitude has a resonance {RADIAN_CHECK_PEAK_DB:g} dB or more above its surroundings, across which a phase "
            "in degrees swings by about 180"
        )
    return None


def _bad_phase(phase: np.ndarray) -> tuple[int, str]:
    """(index, message) of the first phase beyond MAX_ABS_PHASE_DEG, or (-1, "")."""
    bad = np.flatnonzero(~(np.abs(phase) <= MAX_ABS_PHASE_DEG))
    if not bad.size:
        return -1, ""
    k = int(bad[0])
    return k, (
        f"expected a phase within +-{MAX_ABS_PHASE_DEG:g} deg (about {MAX_ABS_PHASE_DEG / 360:.0f} turns; "
        f"no measured phase comes near it), got {_num(phase[k])}"
    )


def write_frf_csv(frf: FrequencyResponse, path, *, overwrite: bool = False) -> Path:
    """Write ``frf`` as a frequency-response CSV (magnitude linear, phase unwrapped in degrees).

    Raises
    ------
    FileExistsError
        If ``path`` exists and ``overwrite`` is False.
    """
    columns: dict[str, np.ndarray] = {"freq_hz": frf.freq_hz}
    for ch in frf.channels:
        columns[f"{ch}_mag"] = np.abs(frf.response(ch))
        columns[f"{ch}_phase_deg"] = frf.phase_deg(ch)
        coh = frf.coherence(ch)
        if coh is not None:
            columns[f"{ch}_coh"] = np.clip(coh, 0.0, 1.0)  # FrequencyResponse allows 1e-9 of round-off
    formats = [_AXIS_FMT] + [_VALUE_FMT] * (len(columns) - 1)
    return _write_atomic(path, _format_table(frf.metadata, columns, formats), overwrite)
