"""``samii design``: bad inputs and misuses end in one line and exit 2 with nothing written; the tester's defects stay fixed.

Every command runs in-process through :func:`samii.cli.main`. A rejected
command must exit 2 with exactly one line on stderr that names the option,
print nothing on stdout, and leave an ``--out`` folder exactly as it was.
"""

from __future__ import annotations

import json
import math
import os
import struct

import numpy as np
import pytest

from samii.cli import main

# ---- helpers ----


def _run(argv, capsys):
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse rejects a value at parse time
        rc = exc.code
    out, err = capsys.readouterr()
    return rc, out, err


def _snapshot(folder) -> dict:
    """Every entry under ``folder`` (hidden ones too) with its size and modification time."""
    if folder is None or not os.path.exists(folder):
        return {}
    snap = {}
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            p = os.path.join(root, name)
            st = os.stat(p)
            snap[os.path.relpath(p, folder)] = (st.st_size, st.st_mtime_ns, os.path.isdir(p))
    return snap


def _assert_rejected(capsys, argv, option, *, folder=None):
    before = _snapshot(folder)
    existed = folder is not None and os.path.exists(folder)
    rc, out, err = _run(["design", *argv], capsys)
    lines = err.strip().splitlines()
    assert rc == 2, (argv, rc, err)
    assert len(lines) == 1, (argv, err)
    assert lines[0].startswith(f"samii design {argv[0]}: error: "), lines[0]
    assert option in lines[0], (option, lines[0])
    assert "Traceback" not in err and "internal error" not in err
    assert out == "", out
    if folder is not None:
        assert os.path.exists(folder) == existed
        assert _snapshot(folder) == before, f"{argv} changed {folder}"
    return lines[0]


def _strict_json(text: str):
    def no_constants(name):
        raise AssertionError(f"non-standard JSON token {name}")

    return json.loads(text, parse_constant=no_constants)


def _png_size(path) -> tuple[int, int]:
    with open(path, "rb") as f:
        head = f.read(24)
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


@pytest.fixture
def out_dir(tmp_path):
    """An existing --out folder holding a file of the user's and a summary.json from an earlier run."""
    d = tmp_path / "out"
    d.mkdir()
    (d / "notes.txt").write_text("keep me\n")
    (d / "summary.json").write_text("[]\n")
    (d / "ccf_2mode_accel.tex").write_text("% earlier\n")
    return d


# ---- the battery: every action, bad values and misuses ----

BAD_VALUES = [
    # place: sample time (parse time, then the model's bound), damping, Kalman noise, misuse
    (["place", "--sample-time-s", "0"], "--sample-time-s"),
    (["place", "--sample-time-s", "-1"], "--sample-time-s"),
    (["place", "--sample-time-s", "nan"], "--sample-time-s"),
    (["place", "--sample-time-s", "inf"], "--sample-time-s"),
    (["place", "--sample-time-s", "1ms"], "--sample-time-s"),
    (["place", "--sample-time-s", "1e6"], "--sample-time-s"),
    (["place", "--sample-time-s", "0.002"], "--sample-time-s"),  # above 1.849 ms: < 10 samples per observer-pole period
    (
        [
            "place",
            "--sample-time-s",
            "0.004",
            "--observer",
            "kalman",
            "--input-noise-std",
            "0.01",
            "--theta-noise-std",
            "0.01",
            "--accel-noise-std",
            "0.1",
        ],
        "--sample-time-s",
    ),  # fmt: skip
    (["place", "--sample-time-s", "1e-9"], "--sample-time-s"),  # every z crowds at 1: placement inaccurate
    (["place", "--zeta", "0"], "--zeta"),
    (["place", "--zeta", "-1"], "--zeta"),
    (["place", "--zeta", "nan"], "--zeta"),
    (["place", "--zeta", "5"], "--zeta"),
    (["place", "--zeta", "1"], "--zeta"),
    (["place", "--observer", "kalman"], "--input-noise-std"),
    (["place", "--observer", "kalman", "--input-noise-std", "0.01"], "--theta-noise-std"),
    (["place", "--observer", "kalman", "--input-noise-std", "0.01", "--theta-noise-std", "0.01"], "--accel-noise-std"),
    (
        ["place", "--observer", "kalman", "--input-noise-std", "-0.01", "--theta-noise-std", "0.01", "--accel-noise-std", "0.1"],
        "--input-noise-std",
    ),  # fmt: skip
    (
        ["place", "--observer", "kalman", "--input-noise-std", "0.01", "--theta-noise-std", "0", "--accel-noise-std", "0.1"],
        "--theta-noise-std",
    ),  # fmt: skip
    (
        ["place", "--observer", "kalman", "--input-noise-std", "0.01", "--theta-noise-std", "0.01", "--accel-noise-std", "nan"],
        "--accel-noise-std",
    ),  # fmt: skip
    (["place", "--input-noise-std", "0.01"], "--input-noise-std"),  # noise without the Kalman observer
    (["place", "--observer", "luenberger"], "--observer"),
    # cancel
    (["cancel", "--gain", "nan"], "--gain"),
    (["cancel", "--gain", "0"], "--gain"),
    (["cancel", "--gain", "-0"], "--gain"),
    (["cancel", "--gain", "inf"], "--gain"),
    (["cancel", "--gain", "1e13"], "--gain"),
    (["cancel", "--gain", "K"], "--gain"),
    (["cancel", "--loop", "x"], "--loop"),
    # rlocus
    (["rlocus", "--n-gains", "-5"], "--n-gains"),
    (["rlocus", "--n-gains", "0"], "--n-gains"),
    (["rlocus", "--n-gains", "99"], "--n-gains"),
    (["rlocus", "--n-gains", "2.5"], "--n-gains"),
    (["rlocus", "--n-gains", "1000001"], "--n-gains"),
    (["rlocus", "--no-plots"], "--no-plots"),  # without --out
    (["rlocus", "--force"], "--force"),  # without --out
    (["rlocus", "--out", ""], "--out"),
    (["rlocus", "--out", "  "], "--out"),
    # canonical
    (["canonical", "--modes", "4"], "--modes"),
    (["canonical", "--modes", "two"], "--modes"),
    (["canonical", "--outputs", "gyro"], "--outputs"),
    (["canonical", "--out", ""], "--out"),
    (["canonical", "--overwrite"], "--force"),  # without --out
    # an option meant for another action, or none at all
    (["seed-report", "--json", "--out", "x"], "--out"),
    (["place", "--bogus"], "--bogus"),
    (["cancel", "--gain"], "--gain"),
]


@pytest.mark.parametrize("argv, option", BAD_VALUES, ids=[" ".join(a) for a, _ in BAD_VALUES])
def test_bad_values_are_one_line_and_exit_2(capsys, argv, option):
    _assert_rejected(capsys, argv, option)


@pytest.mark.parametrize("argv, expected", [([], "ACTION"), (["bogus"], "bogus")])
def test_missing_or_unknown_action_is_one_line(capsys, argv, expected):
    rc, out, err = _run(["design", *argv], capsys)
    lines = err.strip().splitlines()
    assert rc == 2 and out == "" and len(lines) == 1
    assert lines[0].startswith("samii design: error: ") and expected in lines[0]


@pytest.mark.parametrize("action", [["rlocus"], ["rlocus", "--no-plots"], ["canonical"], ["canonical", "--modes", "3"]])
def test_existing_outputs_need_force_and_stay_untouched(capsys, out_dir, action):
    extra = ["--n-gains", "100"] if action[0] == "rlocus" else []
    # rlocus finds summary.json, canonical ccf_2mode_accel.tex (or nothing for 3 modes: see below)
    if action == ["canonical", "--modes", "3"]:
        (out_dir / "ccf_3mode_accel.tex").write_text("% earlier\n")
    line = _assert_rejected(capsys, [*action, *extra, "--out", str(out_dir)], "--out", folder=out_dir)
    assert "--force" in line


@pytest.mark.parametrize("action", ["rlocus", "canonical"])
def test_out_that_cannot_be_created(capsys, tmp_path, action):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder\n")
    _assert_rejected(capsys, [action, "--out", str(blocker / "sub")], "--out", folder=tmp_path)
    _assert_rejected(capsys, [action, "--out", str(blocker)], "--out", folder=tmp_path)


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into a read-only folder")
def test_out_in_a_read_only_folder(capsys, tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        _assert_rejected(capsys, ["canonical", "--out", str(ro / "new")], "--out", folder=ro)
    finally:
        ro.chmod(0o755)


def test_failure_after_the_work_leaves_the_folder_untouched(capsys, out_dir):
    # with --force the names may exist, but summary.md is a folder: found when the files move into place
    (out_dir / "summary.md").mkdir()
    (out_dir / "summary.md" / "inside.txt").write_text("x\n")
    _assert_rejected(capsys, ["rlocus", "--no-plots", "--n-gains", "100", "--no-progress", "--force", "--out", str(out_dir)],
                     "--out", folder=out_dir)  # fmt: skip
    assert (out_dir / "summary.json").read_text() == "[]\n"


@pytest.mark.slow
def test_a_new_out_folder_is_not_left_behind_after_a_failure(capsys, tmp_path, monkeypatch):
    import samii.viz.rootlocus_plot as rp

    calls = []

    def failing_plot(*args, **kwargs):  # the third figure fails: two are already staged
        calls.append(1)
        if len(calls) == 3:
            raise InterruptedError("disk went away")
        return real(*args, **kwargs)

    real = rp.plot_variant
    monkeypatch.setattr(rp, "plot_variant", failing_plot)
    new = tmp_path / "new" / "deeper"
    rc, out, err = _run(["design", "rlocus", "--n-gains", "100", "--no-progress", "--out", str(new)], capsys)
    assert rc != 0 and len(err.strip().splitlines()) == 1 and out == ""
    assert len(calls) == 3
    assert not (tmp_path / "new").exists()  # created by the run, removed with it


# ---- the defects, one by one ----


def test_stability_limit_of_a_biproper_loop_is_evaluated_not_divided_by_zero():
    """eq 9.4 with the integrator actuator goes unstable exactly where 1 - K_a D = 0 (a pole through infinity)."""
    from samii.design import rootlocus as rl

    p, num = rl.default_models()["eq9.4_s4"]
    loop = rl.mass_damping_loop(p, numerator=num, variant=rl.NOTEBOOK_VARIANTS[1], model="eq9.4_s4")
    d = float(np.asarray(loop.statespace.D)[0, 0])
    k_lim = rl.stability_limit(rl.stable_gain_intervals(loop), +1)
    assert k_lim == pytest.approx(1.0 / d, rel=1e-12)
    at = rl.closed_loop_poles(loop, [k_lim])[0]
    assert at.shape == (loop.statespace.nstates,)
    assert np.sum(~np.isfinite(at)) == 1  # the pole passing through infinity
    finite = at[np.isfinite(at)]
    # the finite poles are continuous across the limit (both sides use the well-posed elimination far enough away)
    for side in (1 - 1e-5, 1 + 1e-5):
        near = rl.closed_loop_poles(loop, [k_lim * side])[0]
        near = near[np.abs(near) < 1e5]
        assert len(near) == len(finite)
        assert max(np.min(np.abs(near - f)) / max(abs(f), 1.0) for f in finite) < 1e-3
    # just below the limit the loop is stable, with one huge real pole going to -inf; just above it comes back from +inf
    below, above = rl.closed_loop_poles(loop, [k_lim * (1 - 1e-9), k_lim * (1 + 1e-9)])
    assert np.max(below.real) < 0 and np.min(below.real) < -1e9
    assert np.max(above.real) > 1e9


def test_feedback_poles_agree_with_the_polynomial_away_from_the_singular_gain():
    from samii import notebook as nb
    from samii.design import rootlocus as rl

    loop = rl.mass_damping_loop(nb.EQ1_3_MANUAL, numerator="s4", variant=rl.NOTEBOOK_VARIANTS[0])
    num = np.asarray(loop.open_loop.num[0][0], float)
    den = np.asarray(loop.open_loop.den[0][0], float)
    d = float(np.asarray(loop.statespace.D)[0, 0])
    for k in (0.3, -0.05, (1 / d) * (1 + 1e-8)):  # the last one is on the descriptor path
        roots = np.roots(np.polysub(den, k * np.pad(num, (len(den) - len(num), 0))))
        poles = rl.closed_loop_poles(loop, [k])[0]
        small = np.abs(roots) < 1e4
        for r in roots[small]:
            assert np.min(np.abs(poles - r)) < 1e-6 * max(abs(r), 1.0)
    # the cancelled mode-2 pole stays put to rounding on both paths
    m2 = loop.base_modes[1]
    for k in (0.3, (1 / d), (1 / d) * (1 + 1e-9)):
        assert np.min(np.abs(rl.closed_loop_poles(loop, [k])[0] - m2)) < 1e-9 * abs(m2)


@pytest.mark.slow
def test_rlocus_renders_every_plot(capsys, tmp_path):
    """The README command with figures (fewer gains for speed): 28 readable PNGs, strict JSON, progress on stderr only."""
    out = tmp_path / "rl"
    rc, stdout, err = _run(["design", "rlocus", "--out", str(out), "--n-gains", "100", "--json"], capsys)
    assert rc == 0, err
    rows = _strict_json(stdout)
    assert len(rows) == 28
    pngs = sorted(out.glob("rlocus_*.png"))
    assert len(pngs) == 28 and "rlocus_eq9.4_s4_integrator_actuator.png" in {p.name for p in pngs}
    for p in pngs:
        w, h = _png_size(p)
        assert w >= 1600 and h >= 1200, (p.name, w, h)
    assert sorted(x.name for x in out.iterdir() if x.suffix != ".png") == ["summary.json", "summary.md"]
    _strict_json((out / "summary.json").read_text())
    assert "samii design rlocus" in err and "Traceback" not in err  # the progress bar


def test_plot_legend_stays_off_the_root_loci(tmp_path):
    """Readable figure: a legend beside each row (no legend on the locus panels), fonts >= 10 pt, a pole at infinity named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from samii.design import rootlocus as rl
    from samii.viz.rootlocus_plot import plot_variant

    p, num = rl.default_models()["eq9.4_s4"]
    loop = rl.mass_damping_loop(p, numerator=num, variant=rl.NOTEBOOK_VARIANTS[1], model="eq9.4_s4")
    fig = plot_variant(loop, rl.summarize(loop, n_gains=100), n_gains=100)
    try:
        plots = [ax for ax in fig.axes if ax.axison]
        sides = [ax for ax in fig.axes if not ax.axison]
        assert len(plots) == 4 and len(sides) == 2
        assert all(ax.get_legend() is None for ax in plots)
        legends = [ax.get_legend() for ax in sides]
        assert all(leg is not None for leg in legends)
        for leg in legends:
            assert min(t.get_fontsize() for t in leg.get_texts()) >= 10
        for ax in plots:
            assert ax.xaxis.label.get_fontsize() >= 10 and "[1/s]" in ax.get_xlabel() and "[rad/s]" in ax.get_ylabel()
        texts = " ".join(t.get_text() for t in legends[0].get_texts())
        assert "at infinity" in texts  # the K_a > 0 limit is where the loop is singular
        assert fig.get_size_inches()[0] * 100 >= 1600
    finally:
        plt.close(fig)


def test_cancel_flags_unstable_poles_in_text_and_json(capsys):
    rc, out, err = _run(["design", "cancel", "--gain=-1e9"], capsys)
    assert rc == 0 and err == ""
    assert "UNSTABLE" in out and "closed loop: UNSTABLE" in out
    unstable_lines = [ln for ln in out.splitlines() if "closed-loop pole" in ln and "UNSTABLE" in ln]
    assert unstable_lines and all(float(ln.split()[2]) >= 0 for ln in unstable_lines)
    rc, out, _ = _run(["design", "cancel", "--gain=-1e9", "--json"], capsys)
    d = _strict_json(out)
    assert d["closed_loop_stable"] is False
    assert any(re > 1e6 for re, _ in d["unstable_closed_loop_poles"])
    assert d["dc_gain_as_drawn"] is None and d["reference_gain_for_unit_dc"] is None
    # the default design is stable and says so
    rc, out, _ = _run(["design", "cancel", "--json"], capsys)
    d = _strict_json(out)
    assert d["closed_loop_stable"] is True and d["unstable_closed_loop_poles"] == []
    assert d["gain_chosen_by_rule"] is True
    # the accel loop at a large gain: two real poles in the right half plane
    rc, out, _ = _run(["design", "cancel", "--loop", "accel", "--gain", "1000"], capsys)
    assert rc == 0 and "closed loop: UNSTABLE, 2 of" in out


def test_place_reports_closed_loop_stability(capsys):
    rc, out, _ = _run(["design", "place", "--json"], capsys)
    d = _strict_json(out)
    assert rc == 0 and d["closed_loop_stable"] is True and d["unstable_closed_loop_poles_z"] == []
    assert d["closed_loop_max_abs_z"] < 1
    assert d["max_sample_time_s"] == pytest.approx(2 * math.pi / (10 * 2 * 169.8194), rel=1e-4)
    rc, out, _ = _run(["design", "place", "--observer", "kalman", "--input-noise-std", "0.05", "--theta-noise-std", "0.01",
                       "--accel-noise-std", "0.5"], capsys)  # fmt: skip
    assert rc == 0 and "closed loop: stable" in out and "UNSTABLE" not in out


def test_unstable_poles_helper():
    from samii.controller import unstable_poles

    assert unstable_poles([-1 + 2j, 0.1, 0j, complex(np.inf, 0)], discrete=False).tolist() == [0.1, 0j, complex(np.inf, 0)]
    assert unstable_poles([0.5, 1.0, -1.2, 0.9j], discrete=True).tolist() == [1.0, -1.2]


def test_place_help_states_the_model_derived_sample_time_bounds(capsys):
    from samii import notebook as nb
    from samii.design import canonical as cc
    from samii.design import placement as pl

    rc, out, _ = _run(["design", "place", "--help"], capsys)
    assert rc == 0
    text = " ".join(out.split())
    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    for observer in ("placement", "kalman"):
        t_max_ms = pl._floor_digits(pl.max_sample_time_s(model, observer=observer) * 1e3, 4)
        assert f"T <= {t_max_ms:g} ms" in text
    # the Kalman options say what they are and in which units
    for option, unit in (("--input-noise-std", "[V]"), ("--theta-noise-std", "[deg"), ("--accel-noise-std", "[ft/s²")):
        assert option in text
        assert unit in text


def test_sample_time_error_explains_the_bound(capsys):
    line = _assert_rejected(capsys, ["place", "--sample-time-s", "0.002"], "--sample-time-s")
    assert "339.6 rad/s" in line and "10 samples per period" in line and "0.001849" in line
    # just inside the bound is accepted
    rc, out, err = _run(["design", "place", "--sample-time-s", "0.001849"], capsys)
    assert rc == 0 and "closed loop: stable" in out


def test_kalman_error_names_every_missing_option(capsys):
    line = _assert_rejected(capsys, ["place", "--observer", "kalman", "--theta-noise-std", "0.1"], "--input-noise-std")
    assert line.split("(")[0].count("--accel-noise-std") == 1 and "--theta-noise-std and" not in line.split("(")[0]


@pytest.mark.slow
def test_no_numpy_reprs_and_strict_json_everywhere(capsys):
    runs = [
        ["cancel"], ["cancel", "--json"], ["cancel", "--loop", "accel", "--json"], ["cancel", "--gain", "0.0666"],
        ["place"], ["place", "--json"], ["place", "--zeta", "0.5", "--sample-time-s", "5e-4", "--json"],
        ["canonical"], ["canonical", "--json"],
        ["rlocus", "--n-gains", "100", "--no-progress"], ["rlocus", "--n-gains", "100", "--no-progress", "--json"],
    ]  # fmt: skip
    for argv in runs:
        rc, out, err = _run(["design", *argv], capsys)
        assert rc == 0, (argv, err)
        assert "np.float" not in out and "np.complex" not in out and "array(" not in out, argv
        if "--json" in argv:
            _strict_json(out)
        if "--no-progress" in argv:
            assert err == ""


@pytest.mark.slow
def test_seed_report_progress_and_no_progress(capsys):
    rc, out, err = _run(["design", "seed-report", "--json", "--no-progress"], capsys)
    assert rc == 0 and err == ""
    _strict_json(out)
    rc, out, err = _run(["design", "seed-report"], capsys)
    assert rc == 0 and "samii design seed-report" in err and "np.float" not in out
    assert "eq10_gain" in out


def test_force_and_overwrite_are_aliases(capsys, out_dir):
    for flag in ("--force", "--overwrite"):
        rc, out, err = _run(["design", "canonical", "--out", str(out_dir), flag], capsys)
        assert rc == 0, err
        assert (out_dir / "ccf_2mode_accel.tex").read_text().startswith("% Controllable canonical form")
    assert (out_dir / "notes.txt").read_text() == "keep me\n"
    assert not [p for p in out_dir.iterdir() if p.name.startswith(".samii-stage-")]


def test_library_rejects_what_the_cli_rejects():
    from samii import notebook as nb
    from samii.design import cancel
    from samii.design import canonical as cc
    from samii.design import placement as pl

    for g in (0.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="gain"):
            cancel.design_pole_cancel(nb.EQ9_4, gain=g)
    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    with pytest.raises(ValueError, match="too long"):
        pl.design_placement(model, sample_time_s=0.01)
    with pytest.raises(pl.PlacementInaccurate):
        pl.design_placement(model, sample_time_s=1e-9)
    with pytest.raises(ValueError, match="positive"):
        pl.design_placement(model, sample_time_s=1e-3, observer="kalman", input_noise_std=0.0, measurement_noise_std=(0.01, 0.1))
    # a looser rule is the caller's choice (Nyquist at the least)
    d = pl.design_placement(model, sample_time_s=0.005, min_samples_per_period=2)
    assert d.unstable_poles_z.size == 0
    with pytest.raises(ValueError, match="Nyquist"):
        pl.design_placement(model, sample_time_s=1e-3, min_samples_per_period=1.5)
