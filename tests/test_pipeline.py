"""The pipeline as a library (samii.pipeline): typed results, a folder read back into the same types, a run saved
elsewhere, the run folder's schema versions; and library modules that leave the command line to the commands."""

from __future__ import annotations

import ast
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import samii
from samii.errors import InputError
from samii.run_summary import summary_lines
from samii.schema import SCHEMA_VERSION

# the `runs` fixture (conftest.py): a by `samii run --seed 3`, b by samii.pipeline.run(seed=3) saved with Run.save


def _copy(run_folder: Path, to: Path) -> Path:
    """A main job's folder without its recordings (20 MB the tests below do not read)."""
    shutil.copytree(run_folder, to, ignore=shutil.ignore_patterns("*.rrd"))
    return to


@pytest.mark.slow
def test_a_saved_folder_reads_back_into_typed_results(runs):
    from samii.closedloop.controllers import SavedController
    from samii.diagnose.baseline import SavedFit
    from samii.frequency_response import FrequencyResponse
    from samii.pipeline import Run
    from samii.schema.summary import RunSummary
    from samii.timeseries import TimeSeries

    a = runs[0]
    run = Run.load(a)
    doc = json.loads((a / "summary.json").read_text())
    assert isinstance(run.summary, RunSummary) and run.summary.schema_version == doc["schema_version"] == SCHEMA_VERSION
    assert run.summary.to_json() == doc  # every field of summary.json, typed and back, unchanged
    assert run.summary.seed == 3 and run.summary.model_file == "embedded default"
    assert run.summary.fit.params["w1"] == doc["fit"]["params"]["w1"]
    assert isinstance(run.frf, FrequencyResponse) and set(run.frf.channels) >= {"act", "base"}
    assert isinstance(run.fit, SavedFit) and run.fit.path == "fit/fit.json"
    assert run.fit.params == pytest.approx({k: v for k, v in run.fit_record["params"].items() if v is not None})
    assert isinstance(run.damping, SavedController)
    assert run.damping.controller.name == json.loads((a / "controllers" / "damping.json").read_text())["name"]
    from samii.run_summary import CONTROLLERS, SCENARIOS

    # the servo loop alone's step, and each controller in each scenario
    assert set(run.closed_loop) == set(doc["closed_loop"]) and len(run.closed_loop) == 1 + len(CONTROLLERS) * len(SCENARIOS)
    loper = run.closed_loop["damping_loper"]
    assert isinstance(loper.trace, TimeSeries) and loper.record.stable is run.summary.closed_loop["damping_loper"].stable is True
    # (2 s: the Loper scenario's switch-on, samii.closedloop.scenario.scenario("loper"))
    assert loper.record.scenario_settings.switch_on_s == 2.0 and loper.record.theta == run.summary.closed_loop["damping_loper"].theta
    rate = run.measurement_record.daq.sample_rate_hz
    assert isinstance(run.timeseries, TimeSeries) and abs(run.timeseries.t.size - run.measurement_record.timing.simulated_s * rate) <= 1
    assert run.diagnosis.verdict == run.summary.diagnosis.verdict
    assert run.summary.diagnosis.effects == run.diagnosis.found
    # the lines a person reads are the command's
    assert summary_lines(run.summary, a)[-1].startswith(f"wrote {a}/ in ")


@pytest.mark.slow
def test_the_library_run_and_the_command_write_the_same_numbers(runs):
    """b is samii.pipeline.run() into a temporary folder, then Run.save(b): the same summary as the command's run a
    (wall time and recording sizes aside), the same measured FRF, fit and diagnosis to the byte, and its report names
    its own folder. a forked its diagnosis, the notebook's controllers and a figure beside its other stages, b ran them
    in turn in one process (conftest.py's ``runs``): the same bits either way."""
    from samii.pipeline import Run

    a, b = (Run.load(r) for r in runs)
    ja, jb = a.summary.to_json(), b.summary.to_json()
    for k in ("wall_s", "recordings_mb"):
        ja.pop(k), jb.pop(k)
    assert ja == jb
    for f in ("measure/frf.csv", "fit/fit.json", "diagnose/diagnosis.json"):
        assert (runs[0] / f).read_bytes() == (runs[1] / f).read_bytes(), f
    assert np.array_equal(a.closed_loop["damping_loper"].trace.accel, b.closed_loop["damping_loper"].trace.accel)
    page = (runs[1] / "report.html").read_text()
    assert f"wrote {runs[1].name}/" in page and "samii-run-" not in page
    assert b.measurement_record.argv == ()  # (the library records no command line unless given one)


@pytest.mark.slow
def test_a_newer_schema_version_is_refused_by_name_and_an_older_one_read(runs, tmp_path, capsys):
    from samii.cli import main
    from samii.pipeline import Run

    folder = _copy(runs[0], tmp_path / "run")
    summary = folder / "summary.json"
    doc = json.loads(summary.read_text())

    newer = SCHEMA_VERSION + 1
    summary.write_text(json.dumps({**doc, "schema_version": newer}))
    with pytest.raises(
        InputError, match=rf"summary.json: schema_version {newer}, written by a newer samii; this one \(.*\) reads versions up to {SCHEMA_VERSION}"
    ):
        Run.load(folder)
    capsys.readouterr()
    assert main(["report", str(folder), "--out", str(tmp_path / "page.html")]) == 2
    assert f"summary.json: schema_version {newer}, written by a newer samii" in capsys.readouterr().err

    summary.write_text(json.dumps({**doc, "schema_version": "1"}))
    with pytest.raises(InputError, match=r"summary.json: field 'schema_version' holds '1'; expected a whole number"):
        Run.load(folder)

    # a folder written before versions were stated (no key anywhere): version 0, the same fields, read
    summary.write_text(json.dumps({k: v for k, v in doc.items() if k != "schema_version"}))
    for rel in ("measure/run.json", "fit/fit.json", "diagnose/diagnosis.json", *(f"closedloop/{n}/run.json" for n in doc["closed_loop"])):
        d = json.loads((folder / rel).read_text())
        (folder / rel).write_text(json.dumps({k: v for k, v in d.items() if k != "schema_version"}))
    old = Run.load(folder)
    assert old.summary.schema_version == 0 and old.summary.fit == Run.load(runs[0]).summary.fit

    assert old.fit.params == Run.load(runs[0]).fit.params  # (fit.json took the key later: one without it is read too)

    # a saved fit of a newer version is refused by the run's reader and by a diagnosis that takes it as its baseline
    fit = folder / "fit" / "fit.json"
    fit.write_text(json.dumps({**json.loads(fit.read_text()), "schema_version": newer}))
    with pytest.raises(InputError, match=rf"fit/fit.json: schema_version {newer}, written by a newer samii"):
        Run.load(folder)
    from samii.diagnose.baseline import read_fit_json

    with pytest.raises(InputError, match=rf"fit.json: schema_version {newer}, written by a newer samii"):
        read_fit_json(fit)
    fit.write_text(json.dumps({**json.loads(fit.read_text()), "schema_version": 0}))

    diag = folder / "diagnose" / "diagnosis.json"
    diag.write_text(json.dumps({**json.loads(diag.read_text()), "schema_version": 7}))
    with pytest.raises(InputError, match=r"diagnose/diagnosis.json: schema_version 7, written by a newer samii"):
        Run.load(folder)


@pytest.mark.slow
def test_fit_json_states_its_version(runs):
    assert json.loads((runs[0] / "fit" / "fit.json").read_text())["schema_version"] == SCHEMA_VERSION


@pytest.mark.slow
def test_a_stages_result_is_read_when_asked_for_and_its_damage_named_then(runs, tmp_path, capsys):
    """Run.load checks the documents; a stage's result file is read when first asked for. A fit.json whose parameter
    is null (damage) still gives a run to report (the page marks the gap), and asking for the fit names the field."""
    from samii.cli import main
    from samii.pipeline import Run

    folder = _copy(runs[0], tmp_path / "run")
    fit = folder / "fit" / "fit.json"
    doc = json.loads(fit.read_text())
    doc["params"]["w1"] = None
    fit.write_text(json.dumps(doc))
    run = Run.load(folder)
    with pytest.raises(InputError, match=r"fit/fit.json: field 'params.w1': expected a finite number, got None"):
        _ = run.fit
    (folder / "report.html").unlink()
    assert main(["report", str(folder)]) == 0
    assert "fit/fit.json: params.w1 holds null" in capsys.readouterr().err


@pytest.mark.slow
def test_a_closed_loop_run_without_its_time_series_is_read_only_when_it_was_not_recorded(runs, tmp_path, capsys):
    """A run that diverged in its first step writes run.json alone, saying so ("recorded": false, samii.closedloop.trial):
    Run.load reads it without a time series (trace None) and the report is written. A recorded run that lacks its time
    series, stable or not, is a folder not whole: refused naming the file."""
    from samii.cli import main
    from samii.pipeline import Run

    folder = _copy(runs[0], tmp_path / "run")
    record = folder / "closedloop" / "notebook_place_step" / "run.json"
    place = json.loads(record.read_text())
    assert place["stable"] is False and place["recorded"] is True  # (pole placement diverges within ms, after its first step)
    (folder / "closedloop" / "notebook_place_step" / "timeseries.csv").unlink()
    with pytest.raises(InputError, match=r"notebook_place_step/timeseries.csv: missing, and the run was recorded"):
        Run.load(folder)  # (an unstable run's lost record is a folder not whole, as any other's)
    record.write_text(json.dumps({**place, "recorded": False}))  # as a run that diverged in its first step writes it
    assert Run.load(folder).closed_loop["notebook_place_step"].trace is None
    assert main(["report", str(folder), "--out", str(tmp_path / "page.html")]) == 0
    capsys.readouterr()
    lost = folder / "closedloop" / "damping_loper" / "timeseries.csv"
    lost.unlink()
    with pytest.raises(InputError, match=rf"{lost}: missing, and the run was recorded"):
        Run.load(folder)
    assert main(["report", str(folder), "--out", str(tmp_path / "again.html")]) == 2
    assert f"{lost}: missing" in capsys.readouterr().err and not (tmp_path / "again.html").exists()
    # a damaged verdict in a run's own record is refused too, not only the summary's copy
    record.write_text(json.dumps({**place, "recorded": False, "stable": "false"}))
    with pytest.raises(InputError, match=r"notebook_place_step/run.json: field 'stable' holds 'false'; expected true or false"):
        Run.load(folder)


@pytest.mark.slow
def test_a_summary_field_of_the_wrong_kind_is_named(runs):
    from samii.schema.summary import RunSummary

    doc = json.loads((runs[0] / "summary.json").read_text())
    for path, value, said in (
        (("fit", "sound"), "yes", "field 'fit.sound' holds 'yes'; expected true or false"),
        (("closed_loop", "damping_step", "stable"), "false", "field 'closed_loop.damping_step.stable' holds 'false'; expected true or false"),
        (("measurement", "amplitude_v"), None, "field 'measurement.amplitude_v' holds None; expected a number"),
        (("seed",), 3.5, "field 'seed' holds 3.5; expected a whole number"),
        (("modes", "pose_deg"), 5, "field 'modes.pose_deg' holds 5; expected a list of some numbers"),
        (("modes", "servo_pair_1_s"), [True, 1], "field 'modes.servo_pair_1_s' holds [True, 1]; expected a list of 2 numbers or null"),
    ):
        bad = json.loads(json.dumps(doc))
        d = bad
        for k in path[:-1]:
            d = d[k]
        d[path[-1]] = value
        with pytest.raises(InputError) as exc:
            RunSummary.from_json(bad, "summary.json")
        assert str(exc.value) == f"summary.json: {said}", exc.value
    missing = json.loads(json.dumps(doc))
    del missing["fit"]["verdict"]
    with pytest.raises(InputError, match=r"^summary.json: field 'fit.verdict' is missing$"):
        RunSummary.from_json(missing, "summary.json")
    # what a run may not have is null and reads n/a: a parameter not fitted, a settling time of a joint that did not follow
    gaps = json.loads(json.dumps(doc))
    gaps["fit"]["params"]["w1"] = None
    gaps["closed_loop"]["damping_step"]["theta"]["settle_s"] = None
    gaps["fit"]["concerns"] = None  # (samii 0.1.0 wrote an empty list so; read as none)
    text = "\n".join(summary_lines(RunSummary.from_json(gaps, "summary.json"), "out"))
    assert "modes n/a / " in text and "damping controller       stable; step: theta settles n/a s" in text


def test_overrides_given_as_a_mapping_are_recorded_as_set_texts():
    from samii.pipeline import _override_texts
    from samii.sim.overrides import parse_overrides

    texts = _override_texts({"hydraulic.supply_pressure": 8e6, "beam.length_m": 4.3})
    assert texts == ["hydraulic.supply_pressure=8000000.0", "beam.length_m=4.3"]
    assert parse_overrides(texts) == {"hydraulic.supply_pressure": 8e6, "beam.length_m": 4.3}  # the same numbers, exactly
    assert _override_texts(["beam.length_m=4.0"]) == ["beam.length_m=4.0"]  # texts kept as given


#: The command layer: modules that parse a command line, show progress and print (and every module named cli*: the
#: commands' own, and identify/cli_studies, the experiment scripts' shared command line). Everything else is library.
_COMMANDS = ("samii.cli", "samii.cli_args", "samii.main_job", "samii.__main__")


def _library_modules():
    root = Path(samii.__file__).parent
    for path in sorted(root.rglob("*.py")):
        name = ".".join(("samii", *path.relative_to(root).with_suffix("").parts)).removesuffix(".__init__")
        if name in _COMMANDS or name.rsplit(".", 1)[-1].startswith("cli"):
            continue
        yield name, path


def test_library_modules_leave_the_command_line_to_the_commands():
    """No library module imports argparse or tqdm, changes the working folder or captures stdout (issue 33): a Python
    user calls them in a notebook, and the main job calls them in one process; a long call reports to a
    samii.progress.Progress, which the commands show."""
    found = []
    for name, path in _library_modules():
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.Import) and any(a.name in ("argparse", "tqdm") for a in node.names):
                found.append(f"{name}: imports {node.names[0].name}")
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] == "tqdm":
                found.append(f"{name}: imports from tqdm (progress is shown by the commands: samii.cli_progress)")
            elif isinstance(node, ast.Import) and any(a.name.rsplit(".", 1)[-1].startswith("cli") for a in node.names if a.name.startswith("samii")):
                found.append(f"{name}: imports a command module")
            elif isinstance(node, ast.ImportFrom) and node.module == "argparse":
                found.append(f"{name}: imports from argparse")
            elif isinstance(node, ast.Attribute) and node.attr in ("chdir", "redirect_stdout", "redirect_stderr"):
                found.append(f"{name}: uses {node.attr}")
            elif isinstance(node, ast.ImportFrom) and any(
                part == "cli" or part.startswith("cli_") for part in (node.module or "").split(".") if node.level or node.module.startswith("samii")
            ):
                found.append(f"{name}: imports from the command module {'.' * node.level}{node.module}")
    assert len(list(_library_modules())) > 100  # (117 at this writing: fewer than 100 is a walk that missed folders)
    assert not found, found


def _modules() -> dict[str, Path]:
    root = Path(samii.__file__).parent
    return {".".join(("samii", *p.relative_to(root).with_suffix("").parts)).removesuffix(".__init__"): p for p in sorted(root.rglob("*.py"))}


def _imports(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """The samii modules ``name`` imports, at its top and inside its functions alike (an import under ``if
    TYPE_CHECKING:`` is a type checker's only, never run, and not counted); ``from samii.x import y`` is an import of
    module samii.x.y where there is one, of samii.x otherwise."""
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    found: set[str] = set()

    def visit(node):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                for c in child.orelse:
                    visit(c)
                continue
            if isinstance(child, ast.Import):
                found.update(a.name for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - child.level + 1] + [child.module or ""]).rstrip(".") if child.level else child.module
                found.update(f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in child.names)
            visit(child)

    visit(ast.parse(path.read_text()))
    return {m for m in found if m in modules and m != name}


def test_the_import_graph_has_no_circles_counting_imports_inside_functions():
    """Issue 33, item 6: modules in rooms, no two that need each other (a circle hidden by function-level imports
    still ties two modules into one). The strongly connected components of the import graph are single modules."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    modules = _modules()
    names = sorted(modules)
    at = {n: i for i, n in enumerate(names)}
    edges = [(at[a], at[b]) for a in names for b in _imports(a, modules[a], modules)]
    assert len(names) > 100 and len(edges) > 400  # (136 modules, 537 imports at this writing: fewer is a walk that missed some)
    rows, cols = zip(*edges)
    n, label = connected_components(csr_matrix((np.ones(len(edges)), (rows, cols)), shape=(len(names),) * 2), directed=True, connection="strong")
    circles = [sorted(names[i] for i in np.flatnonzero(label == k)) for k in range(n) if np.count_nonzero(label == k) > 1]
    assert not circles, circles


def test_the_import_walk_sees_a_circle_through_a_function_level_import(tmp_path):
    """The control: two modules that import each other, one of them inside a function, are found; one that imports the
    other only for a type checker is not."""
    (tmp_path / "a.py").write_text("import samii.b\n")
    (tmp_path / "b.py").write_text("def f():\n    from samii import a\n")
    (tmp_path / "c.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from samii.a import x\n")
    modules = {f"samii.{m}": tmp_path / f"{m}.py" for m in "abc"}
    assert _imports("samii.a", modules["samii.a"], modules) == {"samii.b"}
    assert _imports("samii.b", modules["samii.b"], modules) == {"samii.a"}
    assert _imports("samii.c", modules["samii.c"], modules) == set()


def test_what_the_run_has_to_say_reaches_the_caller_and_the_run(tmp_path, monkeypatch, stub_summary):
    """The library prints nothing (issue 33, item 3): a note (here report.html not written) goes to ``note`` as it
    happens and stays on the returned Run's ``notes``; the summary records the report's failure."""
    import samii.pipeline as pl

    def stages(d, model, overrides, seed, progress, said, argv):
        return stub_summary(seed)

    def broken_report(stage, out):
        raise RuntimeError("no page today")

    monkeypatch.setattr(pl, "_run_stages", stages)
    monkeypatch.setattr(pl, "_report", broken_report)
    monkeypatch.setattr(pl.Run, "load", classmethod(lambda cls, folder: cls(Path(folder), None, {}, {}, {}, {})))
    heard: list[str] = []
    run = pl.run(tmp_path / "out", note=heard.append)
    assert heard == [
        f"warning: report.html not written (RuntimeError: no page today); every other output is; samii report {tmp_path / 'out'} tries again"
    ]
    assert run.notes == tuple(heard)
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["report_error"] == "RuntimeError: no page today"


def test_samii_imports_no_numpy_before_its_main():
    """The samii command installs its Ctrl-C and SIGTERM handling first thing in main; an import of numpy before it
    (a package __init__ importing a module at its top) turns a Ctrl-C during start-up into a traceback."""
    import subprocess
    import sys

    code = "import sys, samii.cli; print(sorted(m for m in ('numpy', 'scipy', 'mujoco') if m in sys.modules))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=Path(samii.__file__).parents[2], check=True)
    assert done.stdout.strip() == "[]", done.stdout


def test_every_library_module_imports():
    """A module that cannot be imported (a name moved, an import left behind) fails here at once, not in the one
    command that reaches it (a moved constant broke `samii diagnose` while every module parsed)."""
    import importlib

    for name in _modules():
        if name != "samii.__main__":  # (it runs the main job)
            importlib.import_module(name)


def test_a_library_modules_lazy_imports_say_why():
    """Issue 33, item 6: an import inside a function only where it saves start-up time for a command that does not
    need it, with that reason beside it ("(lazy: ...)": a heavy package imported only when called, or a module that
    samii's start-up imports deferring one it does not need). The commands' own modules defer every import by rule
    (samii builds its parser from all of them): they are not walked."""
    unsaid = []

    def visit(node, in_function: bool, name: str, lines: list[str]) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                continue
            if in_function and isinstance(child, (ast.Import, ast.ImportFrom)) and "(lazy:" not in lines[child.lineno - 1]:
                unsaid.append(f"{name}:{child.lineno}: {lines[child.lineno - 1].strip()}")
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)), name, lines)

    for name, path in _library_modules():
        text = path.read_text()
        visit(ast.parse(text), False, name, text.splitlines())
    assert not unsaid, unsaid
