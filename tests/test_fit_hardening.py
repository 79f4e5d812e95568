"""``samii fit`` hardened (tester's report): scale, errors that name the file, absurd frequencies,
strict JSON, .mat files, options checked at parse time, all-or-nothing --out, plain numbers in
messages, and a battery of bad inputs (each: exit 2, one line on stderr naming the file or
option, no file left behind). No timed assertions: the scale is checked by counting the passes
over all the points (``benchmarks/fit_scale.py`` times it).
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os

import matplotlib

matplotlib.use("Agg")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

from samii import FrequencyResponse  # noqa: E402
from samii import notebook as nb  # noqa: E402
from samii.cli import main  # noqa: E402
from samii.formats import write_frf_csv  # noqa: E402
from samii.identify import FitProblem, ModelStructure, SweptSineNoise, fit, synthesize  # noqa: E402
from samii.identify.cost import FREQ_RANGE_HZ, frequency_out_of_range, thinning_step  # noqa: E402
from samii.identify.fit import SEARCH_POINTS  # noqa: E402
from samii.identify.report import fit_output_names, json_text, summary_dict  # noqa: E402
from samii.identify.studies import from_notebook_units  # noqa: E402

ST3 = ModelStructure.notebook_3mode()
SI_EQ9_4 = from_notebook_units(nb.EQ9_4)
F_HZ = np.geomspace(0.1, 40.0, 300)


def _strict_json(text: str):
    """json.loads that refuses NaN and Infinity (RFC 8259)."""

    def refuse(token):
        raise ValueError(f"not JSON: {token}")

    return json.loads(text, parse_constant=refuse)


def _listing(folder) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


@pytest.fixture(scope="module")
def good_csv(tmp_path_factory):
    data = synthesize(F_HZ, {c: ST3.response(SI_EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=SweptSineNoise(), rng=np.random.default_rng(5))
    return write_frf_csv(data, tmp_path_factory.mktemp("frf") / "good.csv")


# ---------------------------------------------------------------------------- 1. scale


def test_thinned_problem_keeps_every_kth_point_and_the_settings():
    f = np.geomspace(0.1, 40.0, 2500)
    data = synthesize(f, {c: ST3.response(SI_EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    problem = FitProblem(data, ST3, phase_weight=0.2, weighting="coherence")
    thin = problem.thinned(1000)
    assert thinning_step(2500, 1000) == 3 and thin.n_points == 834  # ceil(2500 / 3)
    np.testing.assert_array_equal(thin.data.freq_hz, f[::3])
    assert (thin.phase_weight, thin.weighting, thin.channels) == (0.2, "coherence", ("act", "base"))
    assert problem.thinned(2500) is problem


def test_large_data_are_searched_on_a_subset_and_refined_on_all_points(monkeypatch, heard):
    """The work on all points is a bounded number of passes, whatever the number of points: the
    starts (and their grid searches) see at most SEARCH_POINTS points."""
    n = 5 * SEARCH_POINTS
    f = np.geomspace(0.1, 40.0, n)
    data = synthesize(f, {c: ST3.response(SI_EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    sizes = []
    original = FitProblem.residuals_and_jacobian

    def counting(self, x, *, jacobian=True):
        sizes.append(self.n_points)
        return original(self, x, jacobian=jacobian)

    monkeypatch.setattr(FitProblem, "residuals_and_jacobian", counting)
    res = fit(data, ST3, phase_weight=0.1, progress=heard)
    full = sum(1 for s in sizes if s == n)
    assert set(sizes) <= {n, SEARCH_POINTS} and 0 < full <= 40, (full, len(sizes))
    assert sum(1 for s in sizes if s == SEARCH_POINTS) > 100  # the search did the bulk of the work
    assert res.n_points == n and res.converged, res.message
    assert f"refined on all {n} points" in res.message and "1 point in 5" in res.message
    for k, v in SI_EQ9_4.items():
        assert res.params[k] == pytest.approx(v, rel=1e-6), k
    # its total said once, before it advanced, and reached exactly at the end
    assert heard.said[0][0] == "expect" and [k for k, _ in heard.said].count("expect") == 1
    # (at least the notebook's and the automatic start, the refinement on all points and the diagnosis)
    assert heard.done == heard.total and heard.total >= 4
    stages = heard.stages
    assert f"refining on all {n} points, evaluation 1" in stages  # a long stage shows it is alive
    assert f"refined on all {n} points" in stages


def test_small_data_are_fitted_as_before():
    data = synthesize(F_HZ, {c: ST3.response(SI_EQ9_4, F_HZ, c) for c in ("act", "base")}, noise=None)
    res = fit(data, ST3, phase_weight=0.1, n_perturbed=0)
    assert res.message.startswith("best of 3 starts") and "refined" not in res.message  # notebook, auto, modes scanned


def test_progress_is_quiet_off_a_terminal_and_can_be_turned_off(good_csv, capsys):
    assert main(["fit", str(good_csv), "--start", "notebook", "--no-progress"]) == 0
    assert capsys.readouterr().err == ""
    assert main(["fit", str(good_csv), "--start", "notebook"]) == 0  # stderr is not a terminal here
    assert capsys.readouterr().err == ""


# ---------------------------------------------------------------------------- 2, 3. errors name the file; absurd frequencies


def test_fit_level_errors_name_the_file(tmp_path, capsys):
    few = write_frf_csv(FrequencyResponse(F_HZ[:3], act=ST3.response(SI_EQ9_4, F_HZ[:3], "act")), tmp_path / "few.csv")
    assert main(["fit", str(few), "--phase-weight", "0"]) == 2  # 3 residuals for 6 parameters
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "few.csv" in err and "residuals" in err
    assert main(["fit", str(few), "--band-hz", "50", "60"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "few.csv" in err and "--band-hz 50 60" in err


@pytest.mark.parametrize("f0", ["1e-300", "1e-7"])
def test_absurd_first_frequency_is_refused_with_file_and_line(tmp_path, capsys, f0):
    rows = ["freq_hz,act_mag,act_phase_deg"] + [
        f"{f:.10g},{abs(h):.10g},{np.degrees(np.angle(h)):.10g}" for f, h in zip(F_HZ, ST3.response(SI_EQ9_4, F_HZ, "act"))
    ]
    rows[1] = f"{f0},1.0,-90"
    path = tmp_path / "tiny.csv"
    path.write_text("# source: test\n\n" + "\n".join(rows) + "\n")
    assert main(["fit", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error" not in err
    assert f"tiny.csv, line 4, column 'freq_hz': frequency {float(f0):g} Hz is outside 1e-06...1e+06 Hz" in err
    assert "underflow" in err  # the reason for the bound


def test_library_refuses_frequencies_outside_the_range():
    assert frequency_out_of_range(np.array([1e-6, 1.0, 1e6])) is None
    k, why = frequency_out_of_range(np.array([1.0, 2e6]))
    assert k == 1 and "2e+06 Hz" in why
    f = np.array([1e-300, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0])
    data = FrequencyResponse(f, act=np.ones(f.size, complex))
    with pytest.raises(ValueError, match=r"point 1 of the data: frequency 1e-300 Hz is outside"):
        FitProblem(data, ST3, phase_weight=0.1)
    assert FREQ_RANGE_HZ == (1e-6, 1e6)


def test_no_uncertainty_where_the_model_overflows():
    from samii.identify.fit import _covariance

    f = np.geomspace(0.1, 40.0, 50)
    data = synthesize(f, {c: ST3.response(SI_EQ9_4, f, c) for c in ("act", "base")}, noise=None)
    problem = FitProblem(data, ST3, phase_weight=0.1)
    x = ST3.vector(SI_EQ9_4)
    r, J = problem.residuals_and_jacobian(x)
    J[0, 0] = np.nan
    cov, se, corr, warnings = _covariance(problem, x, (r, J))
    assert np.all(np.isinf(se)) and "no standard errors" in warnings[0]


# ---------------------------------------------------------------------------- 4. parameters.png


def test_absurd_standard_error_does_not_flatten_its_panel():
    from samii.viz.fit_plot import plot_parameter_sweep

    pws = [0.0, 0.1, 0.2]
    est = [dict(SI_EQ9_4, tau=t) for t in (150.0, 140.0, 130.0)]
    se = [{k: 0.01 * abs(v) for k, v in e.items()} for e in est]
    se[0]["tau"] = 1.5e12  # not identifiable
    se[1]["wp"] = np.inf
    ref = {"tau": [294.127, 158.869, 143.207]}
    fig = plot_parameter_sweep(pws, est, se, ST3.param_names, xlabel="phase weight", reference=ref)
    ax = {a.get_title(): a for a in fig.axes}
    lo, hi = ax["tau"].get_ylim()
    assert 100 < lo and hi < 320  # the estimates and the notebook's values, not +-1.5e12
    texts = [t.get_text() for t in ax["tau"].texts]
    assert any("not identifiable" in t and "2.9e+12" in t for t in texts)
    lo, hi = ax["wp"].get_ylim()
    assert np.isfinite(lo) and hi - lo < 10 and any("±inf" in t.get_text() for t in ax["wp"].texts)
    assert ax["K1"].get_legend() is not None and "notebook" in [t.get_text() for t in ax["K1"].get_legend().get_texts()]


def test_estimate_on_its_bound_gets_a_log_axis():
    from samii.viz.fit_plot import plot_parameter_sweep

    est = [dict(SI_EQ9_4, tau=t) for t in (1e6, 150.0, 90.0)]
    se = [{k: 0.01 * abs(v) for k, v in e.items()} for e in est]
    se[0]["tau"] = 1.3e12
    fig = plot_parameter_sweep([0.0, 0.1, 0.2], est, se, ST3.param_names, xlabel="phase weight")
    tau = next(a for a in fig.axes if a.get_title() == "tau")
    assert tau.get_yscale() == "log"
    lo, hi = tau.get_ylim()
    assert lo > 10 and hi < 1e7


# ---------------------------------------------------------------------------- 5. strict JSON


def test_json_output_has_no_nan_or_infinity(good_csv, tmp_path, capsys, monkeypatch):
    import importlib

    fit_module = importlib.import_module("samii.identify.fit")  # the package's `fit` attribute is the function
    real_fit = fit_module.fit
    import samii.identify.fit_file as fit_file  # (patched where the command's call looks it up)

    def unidentifiable(*args, **kwargs):
        res = real_fit(*args, **kwargs)
        return dataclasses.replace(res, stderr=dict(res.stderr, tau=np.inf), cost=np.inf)

    monkeypatch.setattr(fit_file, "fit", unidentifiable)
    out = tmp_path / "out"
    assert main(["fit", str(good_csv), "--start", "notebook", "--json", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Infinity" not in text and "NaN" not in text
    d = _strict_json(text)
    assert d["stderr"]["tau"] is None and d["cost"] is None and d["params"]["tau"] > 0
    saved = _strict_json((out / "fit.json").read_text())
    assert saved["stderr"]["tau"] is None


def test_summary_and_to_json_are_strict():
    data = synthesize(F_HZ, {"act": ST3.response(SI_EQ9_4, F_HZ, "act")}, noise=None)
    res = fit(data, ST3, phase_weight=0.1, n_perturbed=0)  # base parameters not fitted: NaN
    res = dataclasses.replace(res, stderr=dict(res.stderr, wp=np.inf))
    d = _strict_json(json_text(summary_dict(res)))
    assert d["params"]["w1"] is None and d["stderr"]["wp"] is None
    assert _strict_json(res.to_json())["correlation"]["matrix"][0][-1] is None


# ---------------------------------------------------------------------------- 6. .mat files


@pytest.fixture(scope="module")
def mats(tmp_path_factory):
    from scipy.io import savemat

    d = tmp_path_factory.mktemp("mat")
    act, base = (ST3.response(SI_EQ9_4, F_HZ, c) for c in ("act", "base"))
    bode = {
        "mean_io_mr": np.abs(act),
        "mean_io_ph": np.degrees(np.angle(act)),
        "mean_a2_j2a_mr": np.abs(base),
        "mean_a2_j2a_ph": np.degrees(np.angle(base)),
    }
    savemat(d / "rig.mat", {"freq": F_HZ, **bode})
    savemat(d / "rads.mat", {"w_rad": 2 * np.pi * F_HZ, **bode})
    savemat(d / "nobode.mat", {"freq": F_HZ, "y": F_HZ})
    return d


def test_mat_file_is_fitted(mats, capsys):
    assert main(["fit", str(mats / "rig.mat"), "--json", "--start", "notebook"]) == 0
    d = _strict_json(capsys.readouterr().out)
    for k, v in SI_EQ9_4.items():
        assert d["params"][k] == pytest.approx(v, rel=1e-5), k
    assert main(["fit", str(mats / "rads.mat"), "--mat-freq-name", "w_rad", "--mat-freq-unit", "rad/s", "--json", "--start", "notebook"]) == 0
    assert _strict_json(capsys.readouterr().out)["params"]["wp"] == pytest.approx(SI_EQ9_4["wp"], rel=1e-5)


def test_mat_file_errors_say_what_is_supported(mats, good_csv, capsys):
    assert main(["fit", str(mats / "nobode.mat")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nobode.mat" in err and "mean_io_mr/mean_io_ph" in err
    assert main(["fit", str(mats / "rads.mat")]) == 2  # its frequency vector has another name
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rads.mat" in err and "--mat-freq-name NAME" in err
    assert main(["fit", str(good_csv), "--mat-freq-name", "f"]) == 2
    err = capsys.readouterr().err
    assert "--mat-freq-name: only for a .mat file" in err and "good.csv" in err


# ---------------------------------------------------------------------------- 7. --out all or nothing


def test_full_disk_leaves_nothing_behind(good_csv, tmp_path, capsys, monkeypatch):
    import samii.identify.report as report  # (patched where the fit's outputs look it up)

    def full_disk(fig, path, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(report, "save_figure", full_disk)
    out = tmp_path / "out"
    assert main(["fit", str(good_csv), "--start", "notebook", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "no space left on device" in err and str(out) in err  # the --out, not a staged file
    assert not out.exists()  # not fit.json without its plot


def test_out_names_are_known_before_the_fit():
    assert fit_output_names([0.1]) == ["fit.json", "bode_fit.png"]
    assert fit_output_names([0.0, 0.1]) == ["fit_pw0.json", "fit_pw0.1.json", "bode_fit.png", "parameters.png"]


# ---------------------------------------------------------------------------- 8. plain numbers


def test_lack_of_fit_bands_do_not_fragment_on_dense_grids():
    """A misfit region is one band however densely it is sampled (FFT grids have thousands of lines)."""
    from samii.identify import lack_of_fit
    from samii.identify.studies import synthetic_rig_frf

    x = ST3.vector(SI_EQ9_4)  # the stand-in rig data carry effects eq 9.4 lacks
    summaries = {}
    for n in (400, 40_000):
        data = synthetic_rig_frf(np.geomspace(0.1, 40.0, n), rng=np.random.default_rng(1))
        summaries[n] = lack_of_fit(FitProblem(data, ST3, phase_weight=0.1), x).bands
    assert {b.channel for b in summaries[400]} == {b.channel for b in summaries[40_000]} == {"act", "base"}
    assert len(summaries[40_000]) <= 2 * len(summaries[400])


def test_messages_never_show_numpy_reprs():
    f = np.array([1.0, 2.0, 3.0])
    data = FrequencyResponse(f, act=np.ones(3, complex))
    with pytest.raises(ValueError) as exc:
        FitProblem(data, ST3, band_hz=(np.float64(50.0), np.float64(60.0)))
    assert "np." not in str(exc.value) and "50-60 Hz" in str(exc.value)
    with pytest.raises(ValueError) as exc:
        ST3.vector(dict(SI_EQ9_4, tau=np.float64("nan")))
    assert "np." not in str(exc.value) and "tau = nan" in str(exc.value)


# ---------------------------------------------------------------------------- 9. the battery


@pytest.fixture
def inputs(tmp_path, good_csv):
    d = tmp_path / "in"
    d.mkdir()
    (d / "empty.csv").write_text("")
    (d / "garbage.csv").write_bytes(bytes(range(256)) * 8)
    (d / "folder").mkdir()
    (d / "ts.csv").write_text("# sample_rate_hz: 1000\nt,v,theta,accel\n0,0,0,0\n0.001,0.1,0,0\n0.002,0.2,0,0\n")
    (d / "afile").write_text("not a folder\n")
    os.mkfifo(d / "pipe.csv")  # reading it must not block
    (d / "good.csv").write_bytes(good_csv.read_bytes())
    return d


# (argv after "fit" with {d} the inputs folder, what stderr must name)
BATTERY = {
    "nonexistent file": (["{d}/missing.csv"], "missing.csv"),
    "directory": (["{d}/folder"], "folder"),
    "empty file": (["{d}/empty.csv"], "empty.csv"),
    "named pipe": (["{d}/pipe.csv"], "pipe.csv"),
    "binary garbage": (["{d}/garbage.csv"], "garbage.csv"),
    "time series": (["{d}/ts.csv"], "ts.csv: this is a time series"),
    "empty FRF argument": ([""], "FRF"),
    "phase weight nan": (["{d}/good.csv", "--phase-weight", "nan"], "--phase-weight"),
    "phase weight negative": (["{d}/good.csv", "--phase-weight", "-0.1"], "--phase-weight"),
    "phase weight huge": (["{d}/good.csv", "--phase-weight", "1e300"], "--phase-weight"),
    "phase weights inf": (["{d}/good.csv", "--phase-weights", "0,inf"], "--phase-weights"),
    "phase weights twice": (["{d}/good.csv", "--phase-weights", "0.1,0.10"], "--phase-weights"),
    "phase weights too many": (["{d}/good.csv", "--phase-weights", ",".join(["0.1"] * 21)], "--phase-weights"),
    "modes zero": (["{d}/good.csv", "--modes", "0"], "--modes"),
    "modes huge": (["{d}/good.csv", "--modes", "1000000"], "--modes"),
    "modes not integer": (["{d}/good.csv", "--modes", "2.5"], "--modes"),
    "band nan": (["{d}/good.csv", "--band-hz", "nan", "10"], "--band-hz"),
    "band zero": (["{d}/good.csv", "--band-hz", "0", "10"], "--band-hz"),
    "band reversed": (["{d}/good.csv", "--band-hz", "10", "1"], "--band-hz 10 1"),
    "band beyond the data": (["{d}/good.csv", "--band-hz", "100", "1e5"], "good.csv: --band-hz 100 100000"),
    "averages zero": (["{d}/good.csv", "--averages", "0"], "--averages"),
    "averages huge": (["{d}/good.csv", "--averages", "99999999"], "--averages"),
    "averages negative": (["{d}/good.csv", "--averages", "-3"], "--averages"),
    "out empty": (["{d}/good.csv", "--out", ""], "--out"),
    "out is a file": (["{d}/good.csv", "--out", "{d}/afile"], "--out"),
    "mat option on a CSV": (["{d}/good.csv", "--mat-freq-unit", "rad/s"], "--mat-freq-unit"),
    "both phase options": (["{d}/good.csv", "--phase-weight", "0.1", "--phase-weights", "0,0.1"], "--phase-weight"),
}


@pytest.mark.parametrize("case", list(BATTERY))
def test_bad_input_exits_2_with_one_line_and_leaves_nothing(case, inputs, capsys):
    argv, named = BATTERY[case]
    argv = [a.format(d=inputs) for a in argv]
    before = _listing(inputs.parent)
    assert main(["fit", *argv]) == 2
    cap = capsys.readouterr()
    assert cap.err.count("\n") == 1 and cap.err.startswith("samii fit: error: "), cap.err
    assert named in cap.err and "Traceback" not in cap.err and "internal error" not in cap.err
    assert "np.float64" not in cap.err and "usage:" not in cap.err
    assert _listing(inputs.parent) == before


def test_existing_outputs_are_kept_without_overwrite(inputs, capsys):
    out = inputs / "out"
    out.mkdir()
    (out / "fit.json").write_text("{}\n")
    before = _listing(inputs)
    assert main(["fit", str(inputs / "good.csv"), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--out" in err and "fit.json" in err and "--overwrite" in err
    assert _listing(inputs) == before and (out / "fit.json").read_text() == "{}\n"


def test_out_under_a_read_only_folder(inputs, capsys, monkeypatch):
    ro = inputs / "ro"
    ro.mkdir()
    if os.geteuid() == 0:  # root writes anywhere: make the check see the folder as read-only
        real = os.access
        monkeypatch.setattr(os, "access", lambda p, mode, *a, **k: False if os.fspath(p) == str(ro) else real(p, mode, *a, **k))
    else:
        ro.chmod(0o555)
    try:
        before = _listing(inputs)
        assert main(["fit", str(inputs / "good.csv"), "--out", str(ro / "sub")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "--out" in err and "not writable" in err
        assert _listing(inputs) == before
    finally:
        ro.chmod(0o755)
