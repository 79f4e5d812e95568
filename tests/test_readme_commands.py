"""The README's example commands run as written (issue 32 item 4).

Every ``samii ...`` line in the README's code blocks that is a command rather than a synopsis (no
``[optional]`` parts, no ``...``) is parsed by the real parser (so a misspelt or abbreviated option
fails here), and read in order as a user would run them: each file it reads must have been written
by an earlier example (a folder a user does not have, like the old ``rig_run.csv``, fails), and
no example writes into a folder an earlier one filled unless it passes ``--overwrite``.

Which files a command writes into its ``--out`` (``WRITES``) was checked by running the chain
(the commands' own tests check the files themselves).
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path, PurePosixPath

import pytest

from samii.cli import build_parser

README = Path(__file__).resolve().parents[1] / "README.md"

#: files each command writes into its --out folder (that a later example may read)
WRITES = {
    "measure": {"timeseries.csv", "frf.csv", "run.json", "bode.png"},
    "fit": {"fit.json", "bode_fit.png"},
    "calibrate": {"calibration.json", "calibrated_params.json"},
    "frf": {"frf.csv", "bode.png"},
    "diagnose": {"diagnosis.json"},
    "robust": {"robust.json"},
}
#: inputs that are not files (built-in controllers, baselines and data)
BUILT_IN = {"eq9.4", "damping", "notebook-cancel", "notebook-place", "unity", "notebook", "sim"}


def _example_lines(text: str) -> list[tuple[int, str]]:
    """``(line number, command)`` for each ``samii`` line in a fenced or indented code block, with
    backslash continuations joined."""
    out, fenced, pending = [], False, None
    for no, line in enumerate(text.splitlines(), 1):
        if line.startswith("```"):
            fenced = not fenced
            continue
        if not (fenced or line.startswith("    ")):
            pending = None
            continue
        stripped = line.strip()
        if pending is not None:
            pending = (pending[0], pending[1] + " " + stripped.rstrip("\\"))
            if not stripped.endswith("\\"):
                out.append(pending)
                pending = None
            continue
        if stripped.startswith("samii ") or stripped == "samii":
            if stripped.endswith("\\"):
                pending = (no, stripped.rstrip("\\"))
            else:
                out.append((no, stripped))
    return out


def _commands() -> list[tuple[int, list[str]]]:
    cmds = []
    for no, line in _example_lines(README.read_text(encoding="utf-8")):
        code = line.split("  #", 1)[0]
        if "[" in code or "..." in code:  # a synopsis, not a command
            continue
        cmds.append((no, shlex.split(code, comments=True)[1:]))
    return cmds


COMMANDS = _commands()


def test_the_readme_has_runnable_examples():
    names = {argv[0] for _, argv in COMMANDS if argv}
    assert {"measure", "fit", "calibrate", "diagnose", "robust"} <= names, names


@pytest.mark.parametrize("no, argv", COMMANDS, ids=[f"line{no}" for no, _ in COMMANDS])
def test_readme_example_parses(no, argv, capsys):
    try:
        build_parser().parse_args(argv)
    except SystemExit as exc:  # pragma: no cover - the failure's message is the point
        pytest.fail(f"README line {no}: samii {' '.join(argv)}: {capsys.readouterr().err.strip()} (exit {exc.code})")


def _inputs(args) -> list[str]:
    found = []
    for name in ("frf", "timeseries", "data", "model", "covariance", "baseline", "controller"):
        value = getattr(args, name, None)
        for v in value if isinstance(value, list) else [value]:
            if isinstance(v, str) and v not in BUILT_IN:
                found.append(v)
    return found


def test_readme_examples_read_only_what_earlier_ones_wrote():
    parser = build_parser()
    written: dict[str, set[str]] = {}  # folder -> files an earlier example wrote there
    for no, argv in COMMANDS:
        args = parser.parse_args(argv)
        for path in _inputs(args):
            p = PurePosixPath(path)
            folder = str(p.parent)
            assert folder in written and p.name in written[folder], (
                f"README line {no}: samii {' '.join(argv)} reads {path}, which no earlier example writes "
                f"(written so far: { {k: sorted(v) for k, v in written.items()} })"
            )
        out = getattr(args, "out", None)
        if out and args.command in WRITES:
            assert out not in written or args.overwrite, (
                f"README line {no}: --out {out} was filled by an earlier example; this one would be refused without --overwrite"
            )
            written.setdefault(out, set()).update(WRITES[args.command])


def test_the_old_unrunnable_examples_are_gone():
    text = README.read_text(encoding="utf-8")
    assert not re.search(r"samii \w+ (rig_run\.csv|frf\.csv)\b", text)
