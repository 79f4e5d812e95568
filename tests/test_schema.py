"""The run folder as a versioned schema (samii.schema): each document a type, read into it and written back unchanged,
its damage named by file and field, a writer's document that its type does not describe refused."""

from __future__ import annotations

import json
import shutil
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import pytest

from samii.errors import InputError
from samii.schema import SCHEMA_VERSION, as_json, document, key, read_as, read_typed, record_of
from samii.schema.closed_loop import ClosedLoopRecord
from samii.schema.diagnosis import DiagnosisRecord
from samii.schema.measurement import MeasurementRecord
from samii.schema.typed import OPTIONAL

#: Each document of a main job's folder and its type (summary.json: samii.schema.summary, test_pipeline.py).
_DOCUMENTS = {"measure/run.json": MeasurementRecord, "diagnose/diagnosis.json": DiagnosisRecord}


def _documents(folder):
    out = dict(_DOCUMENTS)
    out.update({str(p.relative_to(folder)): ClosedLoopRecord for p in sorted((folder / "closedloop").glob("*/run.json"))})
    return out


@pytest.mark.slow
def test_every_document_of_a_main_job_reads_into_its_type_and_back_unchanged(runs):
    folder = runs[0]
    docs = _documents(folder)
    assert len(docs) == 2 + 7  # the measurement, the diagnosis and the seven closed-loop runs
    for rel, tp in docs.items():
        text = (folder / rel).read_text()
        doc = json.loads(text)
        rec = read_typed(tp, doc, rel)
        assert isinstance(rec, tp)
        # every key, in order, every value: nothing the type does not hold (json.dumps keeps the order)
        assert json.dumps(document(rec)) == json.dumps(doc), rel
    diag = read_typed(DiagnosisRecord, json.loads((folder / "diagnose/diagnosis.json").read_text()), "diagnosis.json")
    assert all(e.category and e.kind for e in diag.found) and set(diag.error_before) >= {"act", "total"}
    loper = read_typed(ClosedLoopRecord, json.loads((folder / "closedloop/damping_loper/run.json").read_text()), "run.json")
    assert loper.recorded and loper.scenario_settings.switch_on_s == 2.0 and loper.controller_detail.servo_loop == "kept"


@pytest.mark.slow
@pytest.mark.parametrize(
    ("rel", "path", "value", "said"),
    [
        ("closedloop/damping_step/run.json", ("theta", "settle_s"), "1.2", "field 'theta.settle_s' holds '1.2'; expected a number or null"),
        ("closedloop/damping_loper/run.json", ("scenario_settings",), None, "field 'scenario_settings' holds None; expected an object"),
        ("closedloop/damping_loper/run.json", ("recorded",), "true", "field 'recorded' holds 'true'; expected true or false"),
        ("measure/run.json", ("daq", "sample_rate_hz"), None, "field 'daq.sample_rate_hz' holds None; expected a number"),
        ("measure/run.json", ("model", "params"), [1, 2], "field 'model.params' holds [1, 2]; expected an object or null"),
        (
            "diagnose/diagnosis.json",
            ("effects", 0, "params", "freq_hz"),
            "26",
            "field 'effects[0].params.freq_hz' holds '26'; expected a number or null",
        ),
        ("diagnose/diagnosis.json", ("effects", 0, "expected"), 0, "field 'effects[0].expected' holds 0; expected true or false"),
        ("diagnose/diagnosis.json", ("unexplained",), {}, "field 'unexplained' holds {}; expected a list of objects"),
        ("diagnose/diagnosis.json", ("refused", 0, "class"), 3, "field 'refused[0].class' holds 3; expected a string"),
        ("diagnose/diagnosis.json", ("refused", 0, "round"), 1.5, "field 'refused[0].round' holds 1.5; expected a whole number or a string"),
    ],
)
def test_a_damaged_field_of_a_stage_document_is_named_when_the_folder_is_read(runs, tmp_path, rel, path, value, said):
    from samii.pipeline import Run

    folder = tmp_path / "run"
    shutil.copytree(runs[0], folder, ignore=shutil.ignore_patterns("*.rrd", "report.html"))
    doc = json.loads((folder / rel).read_text())
    d = doc
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value
    (folder / rel).write_text(json.dumps(doc))
    with pytest.raises(InputError) as exc:
        Run.load(folder)
    assert str(exc.value) == f"{folder / rel}: {said} (the file is not as samii writes it; run samii run again for a report)"


@pytest.mark.slow
def test_a_field_missing_is_named_and_one_added_since_reads_as_its_default(runs):
    doc = json.loads((runs[0] / "closedloop/damping_step/run.json").read_text())
    with pytest.raises(InputError, match=r"^run.json: field 'base' is missing$"):
        read_typed(ClosedLoopRecord, {k: v for k, v in doc.items() if k != "base"}, "run.json")
    # 'recorded' came later: a run.json without it was recorded (it has its time series)
    assert read_typed(ClosedLoopRecord, {k: v for k, v in doc.items() if k != "recorded"}, "run.json").recorded is True
    newer = {**doc, "schema_version": SCHEMA_VERSION + 1}
    with pytest.raises(InputError, match=rf"run.json: schema_version {SCHEMA_VERSION + 1}, written by a newer samii"):
        read_typed(ClosedLoopRecord, newer, "run.json")


@pytest.mark.slow
def test_a_folder_of_an_earlier_samii_reads_and_renders(runs, tmp_path):
    """Documents of schema version 1 written before fields were added (a found effect's beside_nonlinearity, nonlinear,
    rivals and joined; a refusal's code and values; summary.json's effects null, as samii 0.1.0 wrote none) read
    with those fields at their defaults, and the report renders them."""
    from samii.pipeline import Run
    from samii.report.page import render_report

    folder = tmp_path / "run"
    shutil.copytree(runs[0], folder, ignore=shutil.ignore_patterns("*.rrd", "report.html"))
    diag = folder / "diagnose/diagnosis.json"
    doc = json.loads(diag.read_text())
    assert doc["effects"] and doc["refused"]
    for e in doc["effects"]:
        for k in ("beside_nonlinearity", "nonlinear", "rivals", "joined", "sample_s"):
            e.pop(k, None)
    for r in doc["refused"]:
        r.pop("code"), r.pop("values")
    diag.write_text(json.dumps(doc))
    summary = folder / "summary.json"
    sdoc = json.loads(summary.read_text())
    sdoc["diagnosis"]["effects"] = None
    summary.write_text(json.dumps(sdoc))
    run = Run.load(folder)
    assert run.summary.diagnosis.effects == ()
    e = run.diagnosis.effects[0]
    assert (e.beside_nonlinearity, e.nonlinear, e.rivals, e.joined, e.sample_s) == (False, None, (), None, None)
    assert run.diagnosis.refused[0].code is None and run.diagnosis.refused[0].values == {}
    assert e.evidence in render_report(run)


@dataclass(frozen=True)
class _Part:
    a: float
    b: tuple[int, ...]


@dataclass(frozen=True)
class _Doc:
    name: str
    part: _Part
    odd: float | None = field(metadata=key("odd.key"))
    free: Mapping  #: kept as written
    sometimes: tuple[str, ...] | None = field(default=None, metadata=OPTIONAL)


def test_a_writers_document_is_written_only_as_its_type_says():
    doc = {"name": "x", "part": {"a": 1, "b": [1, 2]}, "odd.key": None, "free": {"any": [1, "two"]}}
    rec = record_of(_Doc, doc, "test writer")
    assert rec.part.a == 1 and isinstance(rec.part.a, int)  # (a number kept as read: a whole number stays one)
    assert as_json(rec) == doc and list(as_json(rec)) == list(doc)  # the optional field left out when None, in order
    assert as_json(replace(rec, sometimes=("said",)))["sometimes"] == ["said"]
    assert record_of(_Doc, {**doc, "odd.key": float("nan")}, "w").odd is None  # non-finite: null where null is allowed
    with pytest.raises(TypeError, match=r"^w writes a document its schema does not describe: field 'part.a' holds None; expected a number$"):
        record_of(_Doc, {**doc, "part": {"a": float("inf"), "b": []}}, "w")  # and refused where it is not
    # the writer's mistakes are programming errors (TypeError), not the file's
    with pytest.raises(TypeError, match=r"test writer writes a document its schema does not describe: field 'extra' of"):
        record_of(_Doc, {**doc, "extra": 1}, "test writer")
    with pytest.raises(TypeError, match=r"field 'part.b\[1\]' holds|field 'part.b' holds \[1, 'x'\]; expected a list of whole numbers"):
        record_of(_Doc, {**doc, "part": {"a": 1, "b": [1, "x"]}}, "test writer")
    with pytest.raises(TypeError, match=r"^test writer writes a document its schema does not describe: field 'odd.key' is missing$"):
        record_of(_Doc, {k: v for k, v in doc.items() if k != "odd.key"}, "test writer")  # (a writer writes null, not nothing)
    # a reader is not strict about a key it does not know (it reads the fields it has), and names a kind it refuses
    assert read_as(_Doc, {**doc, "extra": 1}, "f.json") == rec
    with pytest.raises(InputError, match=r"^f.json: field 'odd.key' holds 'x'; expected a number or null$"):
        read_as(_Doc, {**doc, "odd.key": "x"}, "f.json")
    with pytest.raises(InputError, match=r"^f.json: field 'part' is missing$"):
        read_as(_Doc, {k: v for k, v in doc.items() if k != "part"}, "f.json")


def test_robust_json_reads_back_into_its_type_and_a_newer_one_is_refused(tmp_path):
    from samii.schema.robust import RobustRecord, read_robust_json

    row = {"index": 0, "stable": True, "zeta": 0.2, "mode_hz": 1.7, "growth_rate_1_s": None, "base_settle_s": 0.8, "theta_settle_s": 1.3,
           "theta_overshoot_pct": 22.0, "note": "", "valid": True, "linear_stable": True}  # fmt: skip
    doc = {
        "schema_version": SCHEMA_VERSION, "controller": "notebook-cancel", "scenario": "step", "seed": 0, "n_samples": 1,
        "engine": "1 process", "wall_s": 0.4, "warnings": [], "varied": [{"name": "beam.EI_Nm2", "nominal": 3.4e5, "source": "EI +-5 %"}],
        "nominal_plant": row,
        "summary": {"n_samples": 1, "n_invalid": 0, "n_unstable": 0, "p_unstable": 0.0, "p_unstable_ci95": [0.0, 0.975],
                    "zeta_percentiles": {"5": 0.2, "50": 0.2, "95": 0.2}, "n_zeta": 1, "base_settle_s_percentiles": None,
                    "worst": [{**row, "index": 1, "params": {"beam.EI_Nm2": 3.5e5}, "params_rel_pct": {"beam.EI_Nm2": 2.9}}], "influence": []},
        "samples": [{**row, "index": 1, "params": {"beam.EI_Nm2": 3.5e5}}],
    }  # fmt: skip
    path = tmp_path / "robust.json"
    path.write_text(json.dumps(doc))
    rec = read_robust_json(path)
    assert isinstance(rec, RobustRecord) and rec.summary.worst[0].params_rel_pct == {"beam.EI_Nm2": 2.9}
    assert json.dumps(document(rec)) == json.dumps(doc)
    path.write_text(json.dumps({**doc, "schema_version": SCHEMA_VERSION + 1}))
    with pytest.raises(InputError, match=rf"robust.json: schema_version {SCHEMA_VERSION + 1}, written by a newer samii"):
        read_robust_json(path)
    path.write_text(json.dumps({**doc, "seed": "0"}))
    with pytest.raises(InputError, match=r"robust.json: field 'seed' holds '0'; expected a whole number"):
        read_robust_json(path)
