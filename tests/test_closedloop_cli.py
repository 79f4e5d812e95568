"""Bad inputs and contracts of ``samii closedloop`` and of ``samii design place|cancel --save``.

Every bad-input case runs in-process through ``samii.cli.main`` from an empty working folder
and must: exit 2, print exactly one line on stderr naming the option, file or field and what
was expected, print no traceback, and write nothing (an existing ``--out`` folder, a
``--rerun`` or ``--save`` file stay exactly as they were). Cases that fail before simulating
are cheap; the few that run the simulator use ``--duration-s 3``.

The cases in ``FIXED_MALFORMED`` and a few tests below were bugs this battery found (each is
described where it is tested); they are fixed and stay as regression tests.
"""

from __future__ import annotations

import contextlib
import copy
import errno
import io
import json
import math
import os

import numpy as np
import pytest

from samii.cli import main

RUN_FIGURES = ("theta.png", "base_accel.png", "linear_vs_nonlinear.png")
RUN_FILES = ("timeseries.csv", "run.json", *RUN_FIGURES)


# ---------------------------------------------------------------------------- helpers


def _snapshot(folder) -> dict:
    """Every entry (dotfiles too): a file with its size, mtime and bytes, a subfolder by its name only (the
    output checks create and remove a probe file in a folder, which changes the folder's own mtime)."""
    out = {}
    for name in sorted(os.listdir(folder)):
        p = os.path.join(folder, name)
        if os.path.isdir(p) and not os.path.islink(p):
            out[name] = "folder"
        else:
            out[name] = (os.path.getsize(p), os.path.getmtime(p), open(p, "rb").read())
    return out


def _needle_in(needle, text: str) -> bool:
    """``needle``: a string, or a tuple of alternatives (any one will do); case-insensitive."""
    alts = needle if isinstance(needle, tuple) else (needle,)
    return any(a.lower() in text.lower() for a in alts)


def _run_bad(argv, capsys, needles=(), *, code=2, path=None, watch=()):
    """Run ``samii ARGV``; check exit ``code``, one stderr line, no traceback, every needle; nothing in ``watch`` changes.

    ``path``: a file the message must name in full (it is then removed from the line before
    the needles are looked for, so a needle cannot match inside the path).
    """
    before = [_snapshot(w) for w in watch]
    rc = main([str(a) for a in argv])
    cap = capsys.readouterr()
    lines = [ln for ln in cap.err.splitlines() if ln.strip()]
    assert rc == code, (argv, rc, cap.err)
    assert "Traceback" not in cap.err, cap.err
    assert len(lines) == 1, (argv, cap.err)
    line = lines[0]
    assert "internal error" not in line, line
    assert "np.float64" not in line, line
    if path is not None:
        assert str(path) in line, (str(path), line)
        line = line.replace(str(path), "<FILE>")
    for n in needles:
        assert _needle_in(n, line), (argv, n, lines[0])
    assert cap.out == "", (argv, cap.out)  # a refused run prints no result
    for w, b in zip(watch, before):
        assert _snapshot(w) == b, (argv, sorted(os.listdir(w)))
    return lines[0]


@pytest.fixture(scope="module")
def base_doc():
    """A valid controller file's content (notebook-cancel: 6 states, inputs theta_ref and theta)."""
    from samii.closedloop.controllers import controller_json, notebook_cancel

    doc = controller_json(notebook_cancel())
    assert len(doc["A"]) == 6 and doc["inputs"] == ["theta_ref", "theta"]
    return doc


@pytest.fixture(scope="module")
def ctrl_2ms(tmp_path_factory):
    """A valid controller file sampled at 2 ms (two physics steps per sample)."""
    from samii.closedloop.controllers import notebook_cancel, write_controller

    return str(write_controller(notebook_cancel(sample_time_s=2e-3), tmp_path_factory.mktemp("ctrl") / "cancel_2ms.json"))


# ---------------------------------------------------------------------------- closedloop: options

_STEP = ["--scenario", "step"]
OPTIONS = [
    # (id, argv after "closedloop", needles)
    ("no-controller", ["--scenario", "step"], ["--controller", "required"]),
    ("no-scenario", ["--controller", "unity"], ["--scenario", "required"]),
    ("bad-scenario", ["--controller", "unity", "--scenario", "bogus"], ["--scenario", "bogus"]),
    ("unknown-controller", ["--controller", "bogus", *_STEP], ["--controller", "bogus", "unity", "notebook-cancel", ".json"]),
    ("controller-wrong-case", ["--controller", "Unity", *_STEP], ["--controller", "'Unity'"]),
    ("controller-blank", ["--controller", "  ", *_STEP], ["--controller"]),
    ("missing-file", ["--controller", "missing.json", *_STEP], ["missing.json", "does not exist"]),
    ("step-deg-0", ["--controller", "unity", *_STEP, "--step-deg", "0"], ["--step-deg", "nonzero"]),
    ("step-deg-minus-0", ["--controller", "unity", *_STEP, "--step-deg", "-0"], ["--step-deg", "nonzero"]),
    ("step-deg-31", ["--controller", "unity", *_STEP, "--step-deg", "31"], ["--step-deg", "30"]),
    ("step-deg--31", ["--controller", "unity", *_STEP, "--step-deg", "-31"], ["--step-deg", "30"]),
    ("step-deg-nan", ["--controller", "unity", *_STEP, "--step-deg", "nan"], ["--step-deg", "finite"]),
    ("step-deg-inf", ["--controller", "unity", *_STEP, "--step-deg", "inf"], ["--step-deg", "finite"]),
    ("step-deg-abc", ["--controller", "unity", *_STEP, "--step-deg", "abc"], ["--step-deg", "number"]),
    ("step-deg-release", ["--controller", "unity", "--scenario", "release", "--step-deg", "5"], ["--step-deg", "release"]),
    ("impulse-step", ["--controller", "unity", *_STEP, "--impulse-n-s", "1"], ["--impulse-n-s", "release"]),
    ("impulse-loper", ["--controller", "notebook-cancel", "--scenario", "loper", "--impulse-n-s", "1"], ["--impulse-n-s", "release"]),
    ("impulse-0", ["--controller", "unity", "--scenario", "release", "--impulse-n-s", "0"], ["--impulse-n-s", "> 0"]),
    ("impulse-neg", ["--controller", "unity", "--scenario", "release", "--impulse-n-s", "-1"], ["--impulse-n-s", "> 0"]),
    ("impulse-21", ["--controller", "unity", "--scenario", "release", "--impulse-n-s", "21"], ["--impulse-n-s", "20"]),
    ("impulse-nan", ["--controller", "unity", "--scenario", "release", "--impulse-n-s", "nan"], ["--impulse-n-s", "finite"]),
    ("duration-2", ["--controller", "unity", *_STEP, "--duration-s", "2"], ["--duration-s", ">= 3"]),
    ("duration-601", ["--controller", "unity", *_STEP, "--duration-s", "601"], ["--duration-s", "600"]),
    ("duration-nan", ["--controller", "unity", *_STEP, "--duration-s", "nan"], ["--duration-s", "finite"]),
    ("duration-3.5-loper", ["--controller", "unity", "--scenario", "loper", "--duration-s", "3.5"], ["--duration-s 3.5", "loper", "4 s"]),
    ("delay--1", ["--controller", "notebook-cancel", *_STEP, "--delay-samples", "-1"], ["--delay-samples", ">= 0"]),
    ("delay-nan", ["--controller", "notebook-cancel", *_STEP, "--delay-samples", "nan"], ["--delay-samples", "finite"]),
    ("delay-201", ["--controller", "notebook-cancel", *_STEP, "--delay-samples", "201"], ["--delay-samples", "200"]),
    ("delay-unity", ["--controller", "unity", *_STEP, "--delay-samples", "1"], ["--delay-samples", "unity"]),
    ("delay-0.5-unity", ["--controller", "unity", *_STEP, "--delay-samples", "0.5"], ["--delay-samples", "unity"]),
    ("noise-unity", ["--controller", "unity", *_STEP, "--noise"], ["--noise", "unity"]),
    ("seed-without-noise", ["--controller", "notebook-cancel", *_STEP, "--seed", "3"], ["--seed", "--noise"]),
    ("seed-0-without-noise", ["--controller", "notebook-cancel", *_STEP, "--seed", "0"], ["--seed", "--noise"]),
    ("seed-negative", ["--controller", "notebook-cancel", *_STEP, "--noise", "--seed", "-1"], ["--seed", ">= 0"]),
    ("seed-fraction", ["--controller", "notebook-cancel", *_STEP, "--noise", "--seed", "1.5"], ["--seed", "integer"]),
    ("no-plots-without-out", ["--controller", "unity", *_STEP, "--no-plots"], ["--no-plots", "--out"]),
    ("out-empty", ["--controller", "unity", *_STEP, "--out", ""], ["--out", "empty"]),
    ("rerun-empty", ["--controller", "unity", *_STEP, "--rerun", ""], ["--rerun", "empty"]),
    ("rerun-under-a-file", ["--controller", "unity", *_STEP, "--rerun", "/dev/null/x.rrd"], ["--rerun", "/dev/null", "not a folder"]),
    ("rerun-folder", ["--controller", "unity", *_STEP, "--rerun", "."], ["--rerun", "is a folder"]),
    ("bad-set", ["--controller", "unity", *_STEP, "--set", "beam.length_m=-1"], ["length_m"]),
    ("missing-model", ["--controller", "unity", *_STEP, "--model", "nope.xml"], ["nope.xml", "does not exist"]),
    ("unknown-option", ["--controller", "unity", *_STEP, "--bogus"], ["unrecognized", "--bogus"]),
]


@pytest.mark.parametrize("argv, needles", [(a, n) for _, a, n in OPTIONS], ids=[i for i, _, _ in OPTIONS])
def test_closedloop_bad_option(argv, needles, cwd, capsys):
    _run_bad(["closedloop", *argv], capsys, needles, watch=[cwd])


def test_closedloop_folder_as_controller(tmp_path, cwd, capsys):
    folder = tmp_path / "ctrl_dir"
    folder.mkdir()
    _run_bad(["closedloop", "--controller", folder, *_STEP], capsys, ["not a regular file"], path=folder, watch=[cwd, folder])
    named = tmp_path / "looks_like.json"  # a folder with a controller's name
    named.mkdir()
    _run_bad(["closedloop", "--controller", named, *_STEP], capsys, ["not a regular file"], path=named, watch=[cwd, named])


def test_closedloop_empty_controller(cwd, capsys):
    _run_bad(["closedloop", "--controller", "", *_STEP], capsys, ["--controller", "empty"], watch=[cwd])


def test_closedloop_delay_too_long_for_a_slow_controller(ctrl_2ms, cwd, out_dir, capsys):
    _run_bad(["closedloop", "--controller", ctrl_2ms, *_STEP, "--duration-s", "3", "--delay-samples", "150", "--out", out_dir],
             capsys, ["--delay-samples", "200"], watch=[cwd, out_dir])  # fmt: skip


# ---------------------------------------------------------------------------- closedloop: outputs


def test_closedloop_out_is_a_file(tmp_path, cwd, capsys):
    f = tmp_path / "a_file.txt"
    f.write_text("the user's")
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--out", f], capsys, ["--out", "not a folder"], watch=[cwd, tmp_path])
    assert f.read_text() == "the user's"
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--out", f / "sub"], capsys, ["--out", "file"], watch=[cwd, tmp_path])


@pytest.mark.parametrize("existing", ["run.json", "timeseries.csv", "theta.png"])
def test_closedloop_out_existing_outputs_need_overwrite(existing, out_dir, cwd, capsys):
    (out_dir / existing).write_text("the user's earlier result")
    line = _run_bad(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--out", out_dir], capsys,
                    ["--out", "--overwrite"], watch=[cwd, out_dir])  # fmt: skip
    assert existing in line
    assert (out_dir / existing).read_text() == "the user's earlier result"


def test_closedloop_rerun_into_an_existing_file(tmp_path, out_dir, cwd, capsys):
    rec = tmp_path / "rec.rrd"
    rec.write_bytes(b"the user's recording")
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--rerun", rec], capsys, ["--rerun", "--overwrite"],
             path=rec, watch=[cwd, tmp_path])  # fmt: skip
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--rerun", rec, "--out", out_dir], capsys,
             ["--rerun", "--overwrite"], path=rec, watch=[cwd, tmp_path, out_dir])  # fmt: skip
    assert rec.read_bytes() == b"the user's recording"


def test_closedloop_rerun_into_a_new_folder_creates_it(tmp_path, cwd, capsys):
    """A single-file output's folder is created as every --out folder is, and only once the file is written."""
    rec = tmp_path / "new" / "sub" / "rec.rrd"
    assert main(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--rerun", str(rec), "--rerun-fps", "5"]) == 0
    assert rec.is_file() and rec.stat().st_size > 0
    assert sorted(p.name for p in rec.parent.iterdir()) == ["rec.rrd"]
    capsys.readouterr()
    refused = tmp_path / "other" / "rec.rrd"  # refused before any work: no folder left behind
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "2", "--rerun", refused], capsys, ["--duration-s"],
             watch=[cwd, tmp_path])  # fmt: skip
    assert not refused.parent.exists()


@pytest.mark.parametrize("name", ["run.json", "theta.png", "timeseries.csv"])
def test_closedloop_rerun_into_its_own_outputs(name, out_dir, cwd, capsys):
    """--rerun D/<one of the run's outputs> with --out D: refused before any work, even with --overwrite."""
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--out", out_dir, "--overwrite", "--rerun", out_dir / name],
             capsys, ["--rerun", "own output"], watch=[cwd, out_dir])  # fmt: skip


# ---------------------------------------------------------------------------- closedloop: malformed controller files


def _mod(**changes):
    """A change to the valid document: a value, or ``...`` to delete the field."""

    def apply(doc):
        for k, v in changes.items():
            if v is ...:
                doc.pop(k)
            else:
                doc[k] = v(doc) if callable(v) else v
        return doc

    return apply


def _token(field: str, token: str):
    """The valid document with the first entry of matrix ``field`` replaced by a raw JSON token (NaN, a huge integer)."""

    def text(doc):
        doc[field] = [[1234.5678] + r[1:] for r in doc[field]]
        return json.dumps(doc).replace("1234.5678", token, 1)

    return text


def _scalar_token(field: str, token: str):
    def text(doc):
        doc[field] = 1234.5678
        return json.dumps(doc).replace("1234.5678", token, 1)

    return text


def _scale_token(token: str):
    def text(doc):
        doc["input_scale"] = {"theta": 1234.5678}
        return json.dumps(doc).replace("1234.5678", token, 1)

    return text


_NOT_CONTROLLER = ['"format"', "samii-controller"]

# (id, content, needles): content is bytes, text, or a function of a copy of the valid document returning
# the document (dict, written as JSON) or the file's text (str)
MALFORMED = [
    ("not-json", "{not json", ["not valid JSON", "line 1"]),
    ("empty", "", ["not valid JSON"]),
    ("binary", b"\x00\xff\xfe\x00garbage\x89PNG", ["not a text file"]),
    ("json-list", "[1, 2]", _NOT_CONTROLLER),
    ("json-string", '"samii-controller"', _NOT_CONTROLLER),
    ("missing-format", _mod(format=...), _NOT_CONTROLLER),
    ("wrong-format", _mod(format="samii-frf"), _NOT_CONTROLLER),
    ("version-2", _mod(version=2), ["'version'", "2", "version 1"]),
    ("version-missing", _mod(version=...), ["'version'"]),
    ("sample-time-0", _mod(sample_time_s=0), ["'sample_time_s'", "positive"]),
    ("sample-time-negative", _mod(sample_time_s=-1e-3), ["'sample_time_s'", "positive"]),
    ("sample-time-string", _mod(sample_time_s="x"), ["'sample_time_s'", "'x'"]),
    ("sample-time-true", _mod(sample_time_s=True), ["'sample_time_s'", "True"]),
    ("sample-time-missing", _mod(sample_time_s=...), ["'sample_time_s'"]),
    ("sample-time-NaN", _scalar_token("sample_time_s", "NaN"), ["'sample_time_s'"]),
    ("inputs-empty", _mod(inputs=[]), ["'inputs'", "non-empty"]),
    ("inputs-not-list", _mod(inputs="theta"), ["'inputs'"]),
    ("inputs-unknown", _mod(inputs=["theta_ref", "foo"], input_scale={"theta_ref": 57.29577951308232}), ["inputs", "'foo'"]),
    ("inputs-duplicated", _mod(inputs=["theta", "theta"], input_scale={"theta": 57.29577951308232}), ["inputs", "distinct"]),
    ("servo-loop-missing", _mod(servo_loop=...), ["'servo_loop'", "replaced", "kept"]),
    ("servo-loop-maybe", _mod(servo_loop="maybe"), ["'servo_loop'", "'maybe'"]),
    ("A-not-square", _mod(A=lambda d: [r[:5] for r in d["A"]]), ["A (6, 5)", "expected A (6, 6)"]),
    ("A-ragged", _mod(A=lambda d: [d["A"][0][:5]] + d["A"][1:]), ["'A'", "rows of different lengths"]),
    ("A-missing", _mod(A=...), ["'A'", "missing"]),
    ("A-object", _mod(A={"a": 1}), ["'A'", "list of rows"]),
    ("A-flat-list", _mod(A=lambda d: d["A"][0]), ["'A'", "list of rows"]),
    ("B-wrong-shape", _mod(B=lambda d: [r[:1] for r in d["B"]]), ["B (6, 1)", "B (6, 2)"]),
    ("B-too-many-rows", _mod(B=lambda d: d["B"] + d["B"][:1]), ["B (7, 2)", "B (6, 2)"]),
    ("C-wrong-shape", _mod(C=lambda d: d["C"] * 2), ["C (2, 6)", "C (1, 6)"]),
    ("C-too-short", _mod(C=lambda d: [d["C"][0][:5]]), ["C (1, 5)", "C (1, 6)"]),
    ("D-wrong-shape", _mod(D=lambda d: [d["D"][0] + [0.0]]), ["'D'", "(1, 3)", "(1, 2)"]),
    ("D-two-rows", _mod(D=lambda d: d["D"] * 2), ["'D'", "(2, 2)", "(1, 2)"]),
    ("A-NaN", _token("A", "NaN"), ["'A'", "nan", "finite"]),
    ("B-NaN", _token("B", "NaN"), ["'B'", "nan", "finite"]),
    ("A-string", _mod(A=lambda d: [["x"] + r[1:] for r in d["A"]]), ["'A'", "'x'", "finite"]),
    ("C-null", _mod(C=lambda d: [[None] + d["C"][0][1:]]), ["'C'", "None", "finite"]),
    ("D-bool", _mod(D=lambda d: [[True] + d["D"][0][1:]]), ["'D'", "True", "finite"]),
    ("A-overflow-float", _token("A", "1e400"), ["'A'", "finite"]),
    ("input-scale-zero", _mod(input_scale={"theta_ref": 0, "theta": 57.29577951308232}), ["'input_scale'", "nonzero"]),
    ("input-scale-string", _mod(input_scale={"theta": "57.3"}), ["'input_scale'"]),
    ("input-scale-not-object", _mod(input_scale=[1, 2]), ["'input_scale'"]),
    ("input-scale-not-an-input", _mod(input_scale={"accel": 3.28}), ["input_scale", "'accel'", "not among the field 'inputs'"]),
    ("provenance-list", _mod(provenance=[1]), ["'provenance'", "object"]),
    ("provenance-string", _mod(provenance="notebook"), ["'provenance'", "object"]),
    ("name-not-string", _mod(name=3), ["'name'", "string"]),
    ("model-units-not-string", _mod(model_units=["deg"]), ["'model_units'", "string"]),
]

FIXED_MALFORMED = {  # id: (file, expected text, what went wrong before the fix)
    "version-true": (
        _mod(version=True),
        ["'version'"],
        '`"version": true` is accepted as version 1 (True == 1 in Python) and the run goes ahead (exit 0); '
        "it should be refused like `\"sample_time_s\": true` is (exit 2, field 'version')",
    ),
    "A-empty-B-C-full": (
        _mod(A=[]),
        ["shape"],
        '`"A": []` with the 6-row B and C of a 6-state controller is accepted (exit 0): read_controller '
        "replaces B and C by empty matrices and runs a static D-only controller, silently dropping them; "
        "the inconsistent shapes should be refused (exit 2, naming A/B/C)",
    ),
    "A-Infinity": (
        _token("A", "Infinity"),
        ["'A'", ("inf",)],
        'the `Infinity` token in a matrix is reported as "has the entry nan" (parse_constant maps Infinity and '
        "-Infinity to NaN): the message misreports what the file holds; it should say inf/Infinity",
    ),
    "sample-time-huge-int": (
        _scalar_token("sample_time_s", "1" + "0" * 400),
        ["'sample_time_s'"],
        "a 401-digit integer sample_time_s exits 1 with 'internal error: OverflowError: int too large "
        "to convert to float' (math.isfinite on a huge int); it should exit 2 naming the field",
    ),
    "A-huge-int": (
        _token("A", "1" + "0" * 400),
        ["'A'", "finite"],
        "a 401-digit integer in A exits 1 with 'internal error: OverflowError: int too large to convert to float'; it should exit 2 naming the field",
    ),
    "input-scale-huge-int": (
        _scale_token("1" + "0" * 400),
        ["'input_scale'"],
        "a 401-digit integer in input_scale exits 1 with 'internal error: OverflowError'; it should exit 2 naming the field",
    ),
    "int-over-4300-digits": (
        _scalar_token("sample_time_s", "1" + "0" * 5000),
        [],
        "a 5001-digit integer exits 2 with Python's 'Exceeds the limit (4300 digits) for integer string "
        "conversion ... use sys.set_int_max_str_digits()' (a ValueError json.loads raises, not caught as "
        "JSONDecodeError): the message names neither the file nor the field",
    ),
    "nested-too-deeply": (
        lambda d: '{"format": "samii-controller", "x": ' + "[" * 100000 + "]" * 100000 + "}",
        [("nested", "deep", "not valid JSON")],
        "a deeply nested JSON array exits 1 with 'internal error: RecursionError: maximum recursion depth "
        "exceeded while decoding a JSON array'; it should exit 2 naming the file (as samii params "
        "--model does: 'nested too deeply')",
    ),
    "65-states": (
        _mod(A=[[0.0] * 65 for _ in range(65)], B=[[0.0, 0.0]] * 65, C=[[0.0] * 65]),
        ["64"],
        "a 65-state controller file is refused by the card with \"controller '<its name>' has 65 states; the card "
        'holds at most 64": the message does not name the file',
    ),
    "sample-time-not-whole-steps": (
        _mod(sample_time_s=0.0015),
        ["'sample_time_s'", "physics"],
        "sample_time_s 0.0015 is refused by the card with 'controller sample time 0.0015 s is not "
        "a whole number of physics steps (0.001 s)': the message names neither the file nor the "
        "field",
    ),
    "sample-time-below-step": (
        _mod(sample_time_s=1e-4),
        ["'sample_time_s'", "physics"],
        "sample_time_s 1e-4 (under one physics step) is refused by the card without naming the file or the field",
    ),
    "sample-time-1e300": (
        _mod(sample_time_s=1e300),
        ["'sample_time_s'"],
        'sample_time_s 1e300 reaches MuJoCo and exits 2 with "Error: engine error: plugin->init failed '
        "for plugin id 0 samii.hydraulic (actuator 'joint2'): config attribute 'controller_steps' = 1e+303 "
        'is out of range (expected 1...1e+06) ..." (the text twice): internal names, not the file or field',
    ),
}

MALFORMED_CASES = [pytest.param(c, n, id=i) for i, c, n in MALFORMED] + [pytest.param(c, n, id=i) for i, (c, n, _why) in FIXED_MALFORMED.items()]


def _write_case(content, base, path):
    if callable(content):
        content = content(copy.deepcopy(base))
    if isinstance(content, dict):
        content = json.dumps(content, indent=1)
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


@pytest.mark.parametrize("content, needles", MALFORMED_CASES)
def test_closedloop_malformed_controller_file(content, needles, base_doc, tmp_path, cwd, out_dir, capsys):
    """Exit 2, one line naming the file (its full path) and the field; the --out folder untouched."""
    f = _write_case(content, base_doc, tmp_path / "ctrl.json")
    _run_bad(["closedloop", "--controller", f, *_STEP, "--duration-s", "3", "--out", out_dir, "--no-plots"], capsys, needles, path=f,
             watch=[cwd, out_dir])  # fmt: skip


def test_closedloop_controller_file_without_json_suffix_is_read(base_doc, tmp_path, cwd, out_dir, capsys):
    """An existing file is read as a controller file whatever its suffix, so its defects are reported as such."""
    f = _write_case(_mod(servo_loop="maybe"), base_doc, tmp_path / "ctrl.txt")
    _run_bad(["closedloop", "--controller", f, *_STEP, "--out", out_dir], capsys, ["'servo_loop'"], path=f, watch=[cwd, out_dir])


def test_valid_base_document_is_accepted(base_doc, tmp_path):
    """The malformed cases above are one defect away from a file that reads."""
    from samii.closedloop.controllers import read_controller

    f = _write_case(copy.deepcopy(base_doc), base_doc, tmp_path / "ctrl.json")
    saved = read_controller(f)
    assert saved.controller.n_states == 6 and saved.replaces_servo


# ---------------------------------------------------------------------------- design place|cancel --save


def _cancel_reference(loop: str, sample_time_s: float):
    from samii import notebook as nb
    from samii.closedloop.controllers import NOTEBOOK_INPUT_SCALE, NOTEBOOK_UNITS_SI
    from samii.design.cancel import design_pole_cancel

    names = ("theta_ref", "theta") if loop == "theta" else ("theta_ref", "theta", "accel")
    d = design_pole_cancel(nb.EQ9_4, loop=loop)
    return d.controller(sample_time_s=sample_time_s, input_scale={k: NOTEBOOK_INPUT_SCALE[k] for k in names}, model_units=NOTEBOOK_UNITS_SI)


def _place_reference(sample_time_s: float, zeta: float):
    from samii import notebook as nb
    from samii.closedloop.controllers import NOTEBOOK_INPUT_SCALE, NOTEBOOK_UNITS_SI
    from samii.design import canonical as cc
    from samii.design import placement as pl

    model = cc.numeric_statespace(cc.derive_canonical_form(2, "accel"), nb.EQ1_4_OPTIMIZED)
    d = pl.design_placement(model, sample_time_s=sample_time_s, zeta=zeta, observer="placement")
    scale = {k: NOTEBOOK_INPUT_SCALE[k] for k in ("theta_ref", "theta", "accel")}
    return d.controller(input_scale=scale, model_units=NOTEBOOK_UNITS_SI)


def _assert_same_controller(saved, ref):
    c = saved.controller
    for m in "ABCD":
        got, want = np.asarray(getattr(c, m)), np.asarray(getattr(ref, m))
        assert got.shape == want.shape, (m, got.shape, want.shape)
        assert np.array_equal(got, want), (m, np.max(np.abs(got - want)))  # bit for bit, not approximately
    assert c.sample_time_s == ref.sample_time_s
    assert c.inputs == ref.inputs
    assert dict(c.input_scale) == dict(ref.input_scale)
    assert (c.name, c.method, c.model_units) == (ref.name, ref.method, ref.model_units)
    assert saved.replaces_servo is True


ROUND_TRIPS = [
    ("cancel-default", ["design", "cancel"], lambda: _cancel_reference("theta", 1e-3)),
    ("cancel-accel-2ms", ["design", "cancel", "--loop", "accel", "--sample-time-s", "0.002"], lambda: _cancel_reference("accel", 2e-3)),
    ("place-default", ["design", "place"], lambda: _place_reference(1e-3, 1 / np.sqrt(2))),
    ("place-0.5ms-zeta-0.5", ["design", "place", "--sample-time-s", "0.0005", "--zeta", "0.5"], lambda: _place_reference(5e-4, 0.5)),
]


@pytest.mark.parametrize("argv, reference", [(a, r) for _, a, r in ROUND_TRIPS], ids=[i for i, _, _ in ROUND_TRIPS])
def test_design_save_round_trip(argv, reference, tmp_path, capsys):
    from samii.closedloop.controllers import read_controller

    f = tmp_path / "f.json"
    assert main([*argv, "--save", str(f)]) == 0
    cap = capsys.readouterr()
    assert cap.err == "" and str(f) in cap.out
    assert sorted(os.listdir(tmp_path)) == ["f.json"]  # no temporary file left beside it
    json.loads(f.read_text(), parse_constant=lambda s: pytest.fail(f"non-strict JSON token {s} in the controller file"))
    _assert_same_controller(read_controller(f), reference())


def test_design_save_json_names_the_file(tmp_path, capsys):
    f = tmp_path / "f.json"
    assert main(["design", "cancel", "--json", "--save", str(f)]) == 0
    assert json.loads(capsys.readouterr().out)["saved"] == str(f)
    assert f.is_file()


@pytest.mark.parametrize("action", ["place", "cancel"])
def test_design_save_into_an_existing_file_needs_force(action, tmp_path, cwd, capsys):
    f = tmp_path / "f.json"
    f.write_text("the user's controller")
    _run_bad(["design", action, "--save", f], capsys, ["--save", ("--force", "--overwrite")], path=f, watch=[cwd, tmp_path])
    assert f.read_text() == "the user's controller"


def test_design_save_force_replaces(tmp_path, capsys):
    from samii.closedloop.controllers import read_controller

    f = tmp_path / "f.json"
    f.write_text("the user's controller")
    assert main(["design", "cancel", "--save", str(f), "--force"]) == 0
    capsys.readouterr()
    _assert_same_controller(read_controller(f), _cancel_reference("theta", 1e-3))
    assert sorted(os.listdir(tmp_path)) == ["f.json"]


@pytest.mark.parametrize("action", ["place", "cancel"])
@pytest.mark.parametrize("flag", ["--force", "--overwrite"])
def test_design_force_without_save(action, flag, cwd, capsys):
    _run_bad(["design", action, flag], capsys, [flag, "--save"], watch=[cwd])


@pytest.mark.parametrize("action", ["place", "cancel"])
def test_design_save_bad_paths(action, tmp_path, cwd, capsys):
    _run_bad(["design", action, "--save", tmp_path], capsys, ["--save", "is a folder"], watch=[cwd, tmp_path])
    (tmp_path / "a_file").write_text("")
    _run_bad(["design", action, "--save", tmp_path / "a_file" / "f.json"], capsys, ["--save", "is not a folder"], watch=[cwd, tmp_path])
    _run_bad(["design", action, "--save", ""], capsys, ["--save", "empty"], watch=[cwd])
    new = tmp_path / "new" / "f.json"  # a folder that does not exist is created, as every --out is
    assert main(["design", action, "--save", str(new)]) == 0 and new.is_file()
    capsys.readouterr()


def test_design_save_nothing_when_the_design_is_refused(cwd, capsys):
    """An unstable cancel design and a too-long place sample time: exit 2, no file."""
    _run_bad(["design", "cancel", "--gain", "-1", "--save", "f.json"], capsys, ["--save", "unstable"], watch=[cwd])
    _run_bad(["design", "place", "--sample-time-s", "0.01", "--save", "f.json"], capsys, ["--sample-time-s"], watch=[cwd])
    _run_bad(["design", "place", "--observer", "kalman", "--save", "f.json"], capsys, ["--observer kalman", "--input-noise-std"], watch=[cwd])


def test_saved_controller_runs_in_closedloop(tmp_path, capsys):
    """The file written by `design cancel --save` is what `closedloop --controller FILE` runs."""
    f = tmp_path / "f.json"
    assert main(["design", "cancel", "--save", str(f)]) == 0
    capsys.readouterr()
    assert main(["closedloop", "--controller", str(f), *_STEP, "--duration-s", "3", "--json"]) == 0
    cap = capsys.readouterr()
    assert cap.err == ""
    rep = json.loads(cap.out)
    assert rep["controller"] == str(f) and rep["scenario"] == "step" and rep["stable"] is True


# ---------------------------------------------------------------------------- closedloop: the contract of a run


def _strict(text: str):
    def refuse(token):
        raise AssertionError(f"non-strict JSON token {token}")

    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def step_run(tmp_path_factory):
    """One run: `closedloop --controller notebook-cancel --scenario step --duration-s 3 --json --out DIR` (DIR new)."""
    out = tmp_path_factory.mktemp("run") / "new" / "deeper"
    o, e = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(o), contextlib.redirect_stderr(e):
        rc = main(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--json", "--out", str(out)])
    return rc, o.getvalue(), e.getvalue(), out


def _finite_or_none(x) -> bool:
    return x is None or (isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x))


def test_closedloop_json_contract(step_run):
    rc, out, err, _ = step_run
    assert rc == 0, err
    assert err == ""
    assert out.count("\n") == 1 and out.endswith("\n")  # one JSON object on one line, nothing else
    rep = _strict(out)
    assert isinstance(rep, dict)
    assert set(rep) == {"controller", "scenario", "stable", "unstable_mode_hz", "growth_rate_1_s", "instability", "runaway", "theta",
                        "base", "modes", "linear_prediction"}  # fmt: skip
    assert rep["controller"] == "notebook-cancel" and rep["scenario"] == "step"
    assert rep["stable"] is True and rep["unstable_mode_hz"] is None and rep["growth_rate_1_s"] is None
    assert rep["instability"] is None and rep["runaway"] is None
    assert set(rep["theta"]) == {"rise_s", "overshoot_pct", "settle_s", "final_pct"}
    assert set(rep["base"]) == {"peak_m_s2", "residual_rms_m_s2", "settle_s", "decay_rate_1_s", "free_decay_rate_1_s"}
    assert all(_finite_or_none(v) for v in [*rep["theta"].values(), *rep["base"].values()])
    assert rep["theta"]["rise_s"] is not None and rep["base"]["peak_m_s2"] > 0  # a step has a rise and shakes the base
    assert isinstance(rep["modes"], list) and rep["modes"]
    for m in rep["modes"]:
        assert set(m) == {"freq_hz", "zeta"} and all(_finite_or_none(v) for v in m.values())
    lp = rep["linear_prediction"]
    assert set(lp) == {"stable", "marginal", "rms_error_pct"} and isinstance(lp["stable"], bool) and lp["marginal"] is False
    assert set(lp["rms_error_pct"]) == {"theta", "accel"} and all(_finite_or_none(v) for v in lp["rms_error_pct"].values())


def test_closedloop_out_contract(step_run):
    from samii.formats import read_timeseries_csv

    rc, out, err, folder = step_run
    assert rc == 0, err
    assert sorted(os.listdir(folder)) == sorted(RUN_FILES)  # dotfiles count: no staging folder or temp file left
    assert sorted(os.listdir(folder.parent)) == [folder.name]
    ts = read_timeseries_csv(folder / "timeseries.csv")
    assert ts.theta_ref is not None and ts.r is not None
    assert ts.t.size == 3000 and ts.t[0] == 0.0
    assert ts.theta_ref[0] == 0.0 and ts.theta_ref[-1] == pytest.approx(math.radians(5.0), rel=1e-9)  # the default 5 deg step at 1 s
    assert np.all(ts.r == 0.0)
    assert "command" in ts.extra
    doc = _strict((folder / "run.json").read_text())
    assert {k: doc[k] for k in _strict(out)} == _strict(out)  # run.json holds the printed result and more
    assert doc["scenario_settings"]["duration_s"] == 3.0
    for png in RUN_FIGURES:
        assert (folder / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_closedloop_out_no_plots(tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["closedloop", "--controller", "unity", "--scenario", "release", "--duration-s", "3", "--out", str(out), "--no-plots"]) == 0
    capsys.readouterr()
    assert sorted(os.listdir(out)) == ["run.json", "timeseries.csv"]


def test_closedloop_failure_while_writing_leaves_nothing(out_dir, cwd, capsys, monkeypatch):
    """A full disk while drawing the last figure: exit 2, the --out folder exactly as it was, no staging left."""
    import samii.closedloop.plots as plots

    def full_disk(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device", "linear_vs_nonlinear.png")

    monkeypatch.setattr(plots, "plot_linear", full_disk)
    _run_bad(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--out", out_dir], capsys, ["space"],
             watch=[cwd, out_dir])  # fmt: skip


def test_closedloop_failure_in_a_new_out_folder_removes_it(tmp_path, cwd, capsys, monkeypatch):
    import samii.closedloop.plots as plots

    monkeypatch.setattr(plots, "plot_theta", lambda *a, **k: (_ for _ in ()).throw(OSError(errno.ENOSPC, "No space left on device")))
    target = tmp_path / "new" / "deeper"
    _run_bad(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--out", target], capsys, ["space"], watch=[cwd])
    assert not (tmp_path / "new").exists()


def test_closedloop_rerun_failure_leaves_out_untouched(tmp_path, out_dir, cwd, capsys, monkeypatch):
    import samii.viz.recording as recording

    def full_disk(*_a, **_k):
        raise RuntimeError("No space left on device (os error 28)")

    monkeypatch.setattr(recording, "write_recording", full_disk)
    rec = tmp_path / "rec.rrd"
    _run_bad(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--out", out_dir, "--no-plots", "--rerun", rec],
             capsys, ["--rerun", "could not be written"], watch=[cwd, out_dir])  # fmt: skip
    assert not rec.exists()
    assert sorted(os.listdir(tmp_path)) == sorted(["cwd", "out"])


def test_release_impulse_along_the_accelerometer_in_the_world(tmp_path, capsys):
    """The release scenario's tip impulse acts along the accelerometer's measuring axis in the world
    frame: a body-fixed accelerometer (``beam.accel_body_fixed``: its axis +x in the site's frame,
    -x in the world at home) gets the same impulse, and reads the same response, as the default
    world-frame one (it used the body-frame axis as a world one: the impulse flipped)."""
    from samii.formats import read_timeseries_csv

    reads = {}
    for name, extra in (("world", []), ("body", ["--set", "beam.accel_body_fixed=1"])):
        out = tmp_path / name
        assert main(["closedloop", "--controller", "unity", "--scenario", "release", "--duration-s", "3", *extra,
                     "--out", str(out), "--no-plots"]) == 0  # fmt: skip
        reads[name] = read_timeseries_csv(out / "timeseries.csv").accel
    capsys.readouterr()
    world, body = reads["world"], reads["body"]
    assert np.max(np.abs(world)) > 1.0  # m/s^2: the impulse rings the base
    assert np.sqrt(np.mean((body - world) ** 2)) < 0.05 * np.sqrt(np.mean(world**2))


def test_damping_controller_switches_on_without_a_transient(tmp_path, capsys):
    """The Loper test with the damping controller designed here (measure, fit, design): switched on
    at 2 s, bumplessly, the command stays off the valve's 10 V rail and joint 2 barely moves, while
    the base settles about twice as fast as under the servo loop alone (measured 1.48 s against 2.93 s).
    The bumpless state once took the acceleration sampled at the switch-on as a constant input: the
    command ran to 340 V, the valve sat on its rail for 0.3 s and joint 2 swung to 76 deg."""
    from samii.formats import read_timeseries_csv

    out = tmp_path / "o"
    assert main(["closedloop", "--controller", "damping", "--scenario", "loper", "--out", str(out), "--no-plots", "--json"]) == 0
    doc = _strict(capsys.readouterr().out)
    ts = read_timeseries_csv(out / "timeseries.csv")
    on = ts.extra["controller_on"] > 0.5
    assert np.max(np.abs(ts.extra["command"][on])) < 2.0  # V
    assert np.max(np.abs(ts.v)) < 10.0  # never on the rail
    assert np.max(np.abs(np.degrees(ts.theta[on]) - 5.0)) < 1.0  # deg about the 5 deg reference
    assert doc["stable"] and doc["base"]["settle_s"] < 0.6 * 2.93  # the servo loop alone settles in 2.93 s
    assert doc["theta"]["overshoot_pct"] < 20


def test_closedloop_says_the_sensors_the_controller_reads_through(tmp_path, capsys):
    """``--set sensor.*`` reaches the controller card: the summary and run.json say which options it read through; the
    servo amplifier alone (unity) reads the joint directly, so none; ``--antialias`` likewise."""
    sensors = ["--set", "sensor.accel_lowpass_hz=30", "--set", "sensor.theta_delay_s=0.002"]
    out_dir = tmp_path / "run"
    assert main(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", *sensors, "--out", str(out_dir), "--no-plots"]) == 0
    assert "the controller reads through the sensors: accel_lowpass_hz 30 Hz, theta_delay_s 0.002 s" in capsys.readouterr().out
    doc = json.loads((out_dir / "run.json").read_text())
    assert doc["sensors"] == {"accel_lowpass_hz": 30.0, "theta_delay_s": 0.002}
    assert doc["model"]["overrides"] == {"sensor.accel_lowpass_hz": 30.0, "sensor.theta_delay_s": 0.002}
    assert (
        main(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", *sensors, "--out", str(out_dir), "--no-plots", "--overwrite"]) == 0
    )
    assert "reads through the sensors" not in capsys.readouterr().out
    doc = json.loads((out_dir / "run.json").read_text())
    assert doc["sensors"] is None and doc["antialias_hz"] is None
    # --antialias: the card's data acquisition filter, at a quarter of the controller's rate or where asked
    assert main(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--antialias", "--out", str(out_dir),
                 "--no-plots", "--overwrite"]) == 0  # fmt: skip
    assert "filters theta and accel at 250 Hz (8th-order Butterworth)" in capsys.readouterr().out
    assert json.loads((out_dir / "run.json").read_text())["antialias_hz"] == 250.0
    assert main(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", "--antialias", "120", "--json"]) == 0
    assert '"stable": true' in capsys.readouterr().out
    for bad, needle in ((["--antialias", "600"], "below half the physics rate (500 Hz)"), (["--antialias", "-5"], "auto or a corner > 0 Hz")):
        assert main(["closedloop", "--controller", "notebook-cancel", *_STEP, "--duration-s", "3", *bad]) == 2
        assert needle in capsys.readouterr().err
    assert main(["closedloop", "--controller", "unity", *_STEP, "--duration-s", "3", "--antialias"]) == 2
    assert "--antialias: the unity servo loop samples no sensors" in capsys.readouterr().err


def test_a_trial_given_its_controller_resolved_runs_that_one_and_the_same(monkeypatch):
    """The main job designs the notebook's controllers in a worker beside its measurement and hands each trial its
    own (``run_trial(saved=...)``): the trial runs that controller, without designing it again, and its record is the
    one of a trial that designed it itself."""
    import samii.closedloop.trial as tr

    request = tr.TrialRequest("notebook-cancel", "step", duration_s=1.5)
    itself = tr.run_trial(request)
    given = tr.resolve_controller("notebook-cancel")
    monkeypatch.setattr(tr, "resolve_controller", lambda *a, **k: pytest.fail("designed again"))
    handed = tr.run_trial(request, saved=given)
    assert handed.record == itself.record
    assert np.array_equal(handed.result.signals.theta, itself.result.signals.theta)
