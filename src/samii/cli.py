"""The ``samii`` command: a thin layer over the library.

Each subcommand lives in its stage's ``cli`` module, which defines
``add_arguments(parser)`` and ``run(args) -> int`` and imports nothing heavy at
module level. With no subcommand, ``samii`` runs the main job on the embedded
default model.
"""

from __future__ import annotations

import argparse
import importlib
import sys

import samii

# subcommand -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "modes": ("samii.sim.cli_modes", "linearise the simulator at the nominal pose and print its modes"),
    "params": ("samii.sim.cli_params", "list the model parameters --set accepts, with values and units"),
    "measure": ("samii.measure.cli", "swept- or stepped-sine Bode measurement in the simulator"),
    "fit": ("samii.identify.cli", "fit the notebook's transfer-function models to an FRF file"),
    "frf": ("samii.measure.cli_frf", "closed-loop frequency response of a measured time series (records of r found from the data)"),
    "calibrate": ("samii.calibrate.cli", "calibrate the simulator's physical parameters to FRF data"),
    "design": ("samii.design.cli", "control design: root loci, pole placement, pole cancellation, seed report"),
    "closedloop": ("samii.closedloop.cli", "run a controller in the nonlinear simulator: step, Loper and release tests"),
    "diagnose": ("samii.diagnose.cli", "find what a model lacks in measured data: delays, modes, sensor and actuator dynamics"),
    "robust": (
        "samii.robust.cli",
        "Monte Carlo robustness of a controller: plants drawn from spreads or a calibration's covariance, in-process or on Dask",
    ),
    "report": ("samii.report.cli", "write a main job's report.html again from its folder, with a browser screenshot if asked"),
    "run": ("samii.main_job", "the main job on a model: measure, fit, design, closed loop, diagnose, into one folder with a summary"),
}


def _closest(word: str, options: list[str]) -> str | None:
    """The valid option or choice a misspelling most likely meant (difflib's ratio >= 0.6), or None."""
    import difflib

    close = difflib.get_close_matches(word, options, n=1, cutoff=0.6)
    return close[0] if close else None


class _Parser(argparse.ArgumentParser):
    """An argparse parser whose errors are one line (``samii CMD: error: argument --x: why``), no usage dump.

    Options are never abbreviated (``--amplitude`` is not taken for ``--amplitude-v``), and an option
    the command does not have is named with the closest one it has, before any complaint about a
    missing required option (``--scenerio step`` is a misspelling, not a missing ``--scenario``).
    """

    def __init__(self, *args, **kwargs):
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str):  # noqa: D401 - argparse API
        import re

        message = " ".join(message.split())
        choice = re.search(r"invalid choice: '([^']*)' \(choose from (.*)\)", message)
        if choice:  # a misspelt subcommand or choice: name the closest
            close = _closest(choice.group(1), re.findall(r"'([^']*)'", choice.group(2)))
            if close:
                message = message.replace(
                    choice.group(0), f"invalid choice: '{choice.group(1)}': did you mean '{close}'? (choose from {choice.group(2)})"
                )
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")

    def _reject_unknown_options(self, args: list[str]) -> None:
        """Stop at the first ``--option`` this parser does not know, naming the closest it does know.

        A parser with subcommands checks only what comes before the subcommand: the rest is its
        subcommand's to check."""
        has_subcommands = any(isinstance(a, argparse._SubParsersAction) for a in self._actions)
        known = [o for o in self._option_string_actions if o.startswith("--")]
        for token in args:
            if token == "--" or (has_subcommands and not token.startswith("-")):
                return
            if not token.startswith("--"):
                continue
            name = token.split("=", 1)[0]
            if name in self._option_string_actions:
                continue
            close = _closest(name, known)
            self.error(f"unrecognized option {name}" + (f": did you mean {close}?" if close else ""))

    def parse_known_args(self, args=None, namespace=None):
        args = sys.argv[1:] if args is None else list(args)
        self._reject_unknown_options(args)
        # an option of another subcommand (e.g. `design seed-report --out`) is reported by the
        # subcommand that got it, not by the top-level parser
        ns, extras = super().parse_known_args(args, namespace)
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        return ns, extras


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="samii",
        description="SAMII: a hydraulic arm on a flexible cantilevered beam, simulated in MuJoCo. "
        "With no subcommand, runs the main job on the embedded default model.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {samii.__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module, help_text) in SUBCOMMANDS.items():
        mod = importlib.import_module(module)
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split())


#: Signals received (set by the handlers): an exception raised while one was being handled (an
#: import cut short by Ctrl-C raises ImportError) is reported as the interruption it is.
from samii.errors import OUTPUTS_DONE as _OUTPUTS_DONE  # noqa: E402
from samii.errors import OUTPUTS_STARTED as _OUTPUTS_STARTED  # noqa: E402
from samii.errors import SIGNALS_RECEIVED as _SIGNALLED  # noqa: E402  (samii.errors is light: no numpy)


def _install_signal_handlers() -> dict:
    """SIGINT raises KeyboardInterrupt and SIGTERM/SIGHUP :class:`samii.errors.Interrupted`, so staged
    outputs are cleaned up; each is remembered in ``_SIGNALLED``."""
    import signal

    from samii.errors import Interrupted, holding

    def stopping(signum) -> None:
        _SIGNALLED.append(signum)
        # what libraries log while the run is torn down (Dask's scheduler on workers gone, asyncio's unretrieved
        # futures) is a consequence of the stop, not news: the command's one line says it
        import logging

        logging.disable(logging.CRITICAL)

    def handler(signum, _frame):
        if _FINISHED[0]:
            _stop_finished(signum)
        stopping(signum)
        if not holding():  # (outputs being put in place: raised when that is done)
            raise KeyboardInterrupt if signum == signal.SIGINT else Interrupted(signum)

    previous = {}
    for sig in _stop_signals():
        try:
            previous[sig] = signal.signal(sig, handler)
        except (ValueError, OSError):  # not the main thread
            pass
    return previous


def _stop_signals() -> list:
    """SIGINT, SIGTERM and SIGHUP, those the platform has."""
    import signal

    return [getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)]


#: The command has finished (its outputs and its report printed): a signal now ends the process at once, with its line.
_FINISHED = [False]
#: The command's name for its messages ("samii run"), once the command line is parsed.
_PROG = ["samii"]


def _stop_finished(signum: int) -> None:
    """A signal after the command finished, while the program winds down (its library threads, atexit callbacks): one
    line and exit 128 + N at once, not a KeyboardInterrupt traceback from interpreter shutdown or a silent death."""
    import os

    if _SIGNALLED:  # the command was stopped, and said so: one line is enough (a second contradicted it)
        _flush_and_exit(128 + _SIGNALLED[0])
    _flush()
    try:
        os.write(2, f"{_PROG[0]}: stopped by signal {signum} after the command had finished; its outputs are as it reported them\n".encode())
    except OSError:
        pass
    os._exit(128 + signum)


def _restore_signal_handlers(previous: dict) -> None:
    import signal

    for sig, fn in previous.items():
        try:
            signal.signal(sig, fn)
        except (ValueError, OSError, TypeError):
            pass


def _one_line_warnings(prog: str) -> None:
    """Warnings (numpy's, scipy's, ours) as one line each, once per message, never a source-line dump."""
    import warnings

    seen: set[str] = set()

    def show(message, category, filename, lineno, file=None, line=None):
        text = f"{prog}: warning: {category.__name__}: {' '.join(str(message).split())}"
        if text not in seen:
            seen.add(text)
            print(text, file=sys.stderr)

    warnings.showwarning = show


def _report(prog: str, kind: str, exc: BaseException) -> None:
    print(f"{prog}: {kind}: {_one_line(exc)}", file=sys.stderr)


def main(argv: list[str] | None = None, *, program: bool = False) -> int:
    """Run the command; map errors to one line on stderr and an exit code (see :mod:`samii.errors`). ``program``: this
    is the process's own command (:func:`program`): its signal handlers stay for the exit (a signal after the command
    finished ends the process with one line), not restored."""
    _SIGNALLED.clear()
    _OUTPUTS_STARTED.clear()
    _OUTPUTS_DONE.clear()
    _FINISHED[0] = False
    _PROG[0] = "samii"
    previous = _install_signal_handlers()  # first: a signal during start-up is reported like any other
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _quiet_interrupts(previous_hook)
    try:
        return _main(argv)
    finally:
        if not _SIGNALLED:  # stopped by a signal: the hook stays for the exit's own clean-up (atexit callbacks)
            sys.unraisablehook = previous_hook
        _FINISHED[0] = program  # (in a program, its handlers stay for the exit; a caller's are restored)
        if not program:
            _restore_signal_handlers(previous)
            # and the signals this command received and reported are its own: a caller's later work (a library call
            # committing a folder) was stopped by them as if it had been signalled
            _SIGNALLED.clear()


def program() -> None:
    """The ``samii`` program (its console script): :func:`main` on the command line, then exit with its code.

    A signal after the command finished ends the process with one line (:func:`_stop_finished`) while Python can still
    run a handler: through the libraries' exit callbacks. The interpreter's last clean-up resets such handlers to the
    default, and a signal then killed the finished process without a word (exit -2 or -15, 7 of 8 signals sent just
    after a main job's summary): the stop signals are ignored from the last exit callback on (registered first, it
    runs last), and the process exits with the command's code."""
    import atexit

    atexit.register(_ignore_stop_signals)
    code = main(program=True)
    if _SIGNALLED:  # interrupted: its one line is said and its outputs are cleaned up; the libraries' exit callbacks are
        # skipped (Dask's close of a local cluster already stopped waited 10 s, and a signal meanwhile added a second line),
        # and multiprocessing's child processes still there are ended first (samii.forkmap's workers are not among them:
        # their parent ended them as the signal came, and the kernel ends any left when it exits)
        mp = sys.modules.get("multiprocessing")
        children = mp.active_children() if mp is not None else []
        for child in children:
            child.kill()
        for child in children:
            child.join(timeout=5)
        _flush_and_exit(code)
    sys.exit(code)


def _flush() -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass


def _flush_and_exit(code: int) -> None:
    import os

    _flush()
    os._exit(code)


def _ignore_stop_signals() -> None:
    import signal

    for sig in _stop_signals():
        try:
            signal.signal(sig, signal.SIG_IGN)
        except (ValueError, OSError):
            pass


def _quiet_interrupts(fallback):
    """An unraisable-exception hook that, once a stop signal was received, drops what finalisers and atexit callbacks
    raise while the run is torn down: the handler's KeyboardInterrupt inside a weakref callback ("Exception ignored in:
    <WeakKeyDictionary ...> KeyboardInterrupt", about 1 run in 10 stopped mid-job), a parser's half-built object
    (pyparsing's Forward.__del__), Dask's atexit close of a cluster stopped while starting (AssertionError:
    Status.init). The signal is reported once, by the command. Without a signal everything goes to ``fallback``."""

    def hook(unraisable) -> None:
        if _SIGNALLED:
            return
        fallback(unraisable)

    return hook


def _main(argv: list[str] | None) -> int:
    import os

    from samii.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_UNSTABLE, InputError, Interrupted, SimulationUnstable, raise_if_signalled

    prog = "samii"
    try:
        parser = build_parser()
        try:
            args = parser.parse_args(argv)
        except SystemExit as exc:  # argparse: --help, --version (0) or a rejected option (2, its one-line reason printed)
            return exc.code if isinstance(exc.code, int) else EXIT_BAD_INPUT
        prog = "samii" + (f" {args.command}" if args.command else "")
        if getattr(args, "design_command", None):
            prog += f" {args.design_command}"
        _PROG[0] = prog
        _one_line_warnings(prog)
        raise_if_signalled()  # a Ctrl-C during the imports whose exception a library swallowed
        if args.command is None:
            from samii.main_job import run_main_job

            code = run_main_job()
        else:
            code = int(args._run(args) or 0)
        raise_if_signalled()
        return code
    except Interrupted as exc:
        print(f"{prog}: stopped by signal {exc.signum}; {_kept()}", file=sys.stderr)
        return 128 + exc.signum
    except KeyboardInterrupt:
        print(f"{prog}: interrupted; {_kept()}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # e.g. `samii modes | head`: the reader left, which is not an error
        try:
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
        except (OSError, ValueError):
            pass
        return 0
    except SimulationUnstable as exc:
        if _SIGNALLED:
            return _stopped(prog)
        _report(prog, "unstable", exc)
        return EXIT_UNSTABLE
    except InputError as exc:
        if _SIGNALLED:  # (a refusal that came after a Ctrl-C a library swallowed: the interruption is what happened)
            return _stopped(prog)
        _report(prog, "error", exc)
        return EXIT_BAD_INPUT
    except ValueError as exc:  # library validation; a LinAlgError is numerical trouble: a bug
        import numpy as np

        if isinstance(exc, np.linalg.LinAlgError) or _OUTPUTS_STARTED:  # the input was accepted: a failure of ours
            return _internal_error(prog, exc)
        _report(prog, "error", exc)
        return EXIT_BAD_INPUT
    except MemoryError:
        print(f"{prog}: error: out of memory; the requested run is too large for this machine", file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as exc:  # files: missing, unreadable, a folder, disk full
        import errno

        if exc.errno in (errno.ENOSPC, getattr(errno, "EDQUOT", errno.ENOSPC)):
            # the file the user named (a --rerun recording, marked so by samii.viz.recording.recording_failed), else the
            # command's own output (the first begun: --out), never a hidden staging folder or temporary file of ours
            named = getattr(exc, "user_path", False) and not any(
                part.startswith(".") and (".samii-" in part or part.endswith(".tmp")) for part in str(exc.filename).split("/")
            )
            target = exc.filename if named else _OUTPUTS_STARTED[0] if _OUTPUTS_STARTED else exc.filename
            where = f" writing {target}" if target else ""
            print(
                f"{prog}: error: no space left on device{where} (the disk or quota is full); nothing half-written was kept: "
                "free some space and run it again",
                file=sys.stderr,
            )
            return EXIT_BAD_INPUT
        where = f"{exc.filename}: " if getattr(exc, "filename", None) else ""
        print(f"{prog}: error: {where}{exc.strerror or _one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except Exception as exc:
        return _internal_error(prog, exc)


def _stopped(prog: str) -> int:
    """The one line and exit code of a command stopped by a signal received earlier (``_SIGNALLED``)."""
    from samii.errors import EXIT_INTERRUPTED

    signum = _SIGNALLED[0]
    print(f"{prog}: " + ("interrupted" if signum == 2 else f"stopped by signal {signum}") + f"; {_kept()}", file=sys.stderr)
    return EXIT_INTERRUPTED if signum == 2 else 128 + signum


def _kept() -> str:
    """What a stopped command leaves: its outputs whole, if it had put them in place, else nothing of this run."""
    if _OUTPUTS_DONE:
        return f"its outputs were complete before it ({', '.join(_OUTPUTS_DONE)})"
    return "nothing half-written was kept"


def _internal_error(prog: str, exc: Exception) -> int:
    """An unexpected exception (call inside its ``except``): one line by default, the traceback with
    ``SAMII_DEBUG=1``; cut short by a signal (an import interrupted half-way), it is that interruption."""
    import os

    from samii.errors import EXIT_INTERNAL

    if _SIGNALLED:
        return _stopped(prog)
    if os.environ.get("SAMII_DEBUG"):
        raise exc
    print(
        f"{prog}: internal error: {type(exc).__name__}: {_one_line(exc)} (run with SAMII_DEBUG=1 for the traceback; please report it)",
        file=sys.stderr,
    )
    return EXIT_INTERNAL


if __name__ == "__main__":
    program()
