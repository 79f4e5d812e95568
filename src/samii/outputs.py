"""An output folder that is all-or-nothing.

Every command that writes files stages them in a hidden folder inside its
``--out`` (same file system, so the final moves are renames) and moves them into
place together only when the whole run succeeded::

    with OutputFolder(out, ["frf.csv", "bode.png"], overwrite=args.overwrite) as folder:
        write_frf_csv(frf, folder.path("frf.csv"))
        ...

- The folder is checked before any work (``OutputFolder(...)`` raises
  :class:`~samii.errors.InputError` at once): an empty name, a path that is a
  file, a parent that is not a writable folder, outputs that exist without
  ``overwrite``.
- On any exception, Ctrl-C or a handled signal (``samii.cli`` turns SIGTERM and
  SIGHUP into exceptions) the staging folder is removed, and ``--out`` too when
  this run created it and it is still empty: nothing half-written survives.
- A run killed outright (SIGKILL, power loss) leaves its staging folder
  ``.samii-stage-<pid>-<token>``; the next run into the same folder removes
  those whose process is gone. Nothing else ever reads them.
- The moves into place hold an exclusive lock (``flock``) on the ``--out`` folder itself, so two
  concurrent runs into one folder never mix their files: the folder ends with
  the whole set of one of them (with ``--overwrite``, the later), and a run
  without ``--overwrite`` that finds its names taken fails and writes nothing.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import secrets
import shutil
import tempfile
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from samii.errors import InputError, mark_outputs_started, raise_if_signalled, uninterrupted

__all__ = [
    "LaterOutput",
    "OutputFolder",
    "check_output_file",
    "create_parent",
    "make_folder",
    "parent_made_for",
    "remove_empty",
    "remove_stale_runs",
    "remove_stale_stages",
    "with_size",
    "shown_path",
    "written_beside",
    "write_whole",
]

_STAGE_PREFIX = ".samii-stage-"


def _describe(path: Path) -> str:
    return str(path) if str(path) else "''"


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists():
        if p.parent == p:
            break
        p = p.parent
    return p


def _can_create_in(folder: Path) -> bool:
    """Whether a file can really be created in ``folder`` (permission bits say yes to root on /proc, a
    read-only mount or a full quota; creating and removing a probe file asks the file system itself)."""
    if not os.access(folder, os.W_OK | os.X_OK):
        return False
    try:
        fd, probe = tempfile.mkstemp(prefix=".samii-probe-", dir=folder)
    except OSError:
        return False
    os.close(fd)
    os.unlink(probe)
    return True


def _check_creatable_dir(path: Path, option: str) -> None:
    if path.is_symlink() and not path.exists():
        raise InputError(f"{option} {_describe(path)}: is a symbolic link to {os.readlink(path)}, which does not exist")
    if path.exists():
        if not path.is_dir():
            raise InputError(f"{option} {_describe(path)}: exists and is not a folder")
        if not _can_create_in(path):
            raise InputError(f"{option} {_describe(path)}: folder is not writable")
        return
    base = _nearest_existing(path)
    if not base.is_dir():
        raise InputError(f"{option} {_describe(path)}: cannot create a folder under {base}, which is a file")
    if not _can_create_in(base):
        raise InputError(f"{option} {_describe(path)}: cannot create it, {base} is not writable")


def check_output_file(path, *, overwrite: bool, option: str, beside: OutputFolder | None = None) -> Path:
    """Check, before any work, that a single output file (``--rerun FILE``, ``--save FILE``) can be written,
    and, given the run's ``beside`` folder, that it is not one of that folder's outputs or staging folders."""
    text = os.fspath(path)
    if not text.strip():
        raise InputError(f"{option}: expected a file name, got an empty string")
    p = Path(text)
    if p.exists() and p.is_dir():
        raise InputError(f"{option} {p}: is a folder, expected a file name")
    if p.exists() and not overwrite:
        raise InputError(f"{option} {p}: exists; pass --overwrite to replace it")
    parent = p.parent if str(p.parent) else Path(".")
    if parent.is_dir():
        if not _can_create_in(parent):
            raise InputError(f"{option} {p}: folder {parent} is not writable")
    else:  # created when the file is written (create_parent), as a run's --out folder is
        _check_creatable_dir(parent, f"{option} {p}: folder")
    if beside is not None and p.absolute().parent == beside.root.absolute() and (p.name in beside.names or p.name.startswith(_STAGE_PREFIX)):
        raise InputError(f"{option} {p}: would replace the run's own output {p.name}; give it another name")
    return p


def make_folder(folder) -> list[Path]:
    """Create ``folder`` with its missing parents; return those this call created, innermost first (for
    :func:`remove_empty`)."""
    missing = []
    p = Path(folder).absolute()
    while not p.exists():
        missing.append(p)
        p = p.parent
    Path(folder).mkdir(parents=True, exist_ok=True)
    return missing


def remove_empty(created: list[Path]) -> None:
    """Remove the folders :func:`make_folder` created, innermost first, as long as they are empty."""
    for folder in created:
        try:
            folder.rmdir()
        except OSError:
            break


@contextlib.contextmanager
def parent_made_for(path):
    """Create the folder of output file ``path`` for the block; on any failure in it (Ctrl-C included) remove
    the folders this created again, when empty: a file that could not be written leaves no folder either."""
    created = make_folder(Path(path).parent)
    try:
        yield Path(path)
    except BaseException:
        remove_empty(created)
        raise


def create_parent(path) -> Path:
    """Create the folder of a single output file that :func:`check_output_file` accepted, just before
    the file is written (so a run refused or failed before then leaves no empty folder)."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    return p


def shown_path(path, relative_to=None) -> str:
    """``path`` as a run's files name it: as given, or relative to folder ``relative_to`` (the main job's folder, whose
    files name each other by paths inside it, so that the folder can be moved)."""
    return str(path) if relative_to is None else os.path.relpath(Path(path).absolute(), Path(relative_to).absolute())


@contextlib.contextmanager
def written_beside(path, *, keep_suffix: bool = False):
    """A temporary name beside output file ``path`` (a recording: ``--rerun FILE.rrd``) for the block to write it under:
    moved onto ``path`` when the block ends without an error (after the run's folder, which the block commits), removed
    when it fails, so that ``path`` is the whole file or untouched. ``None`` in, ``None`` out (no such output).
    ``keep_suffix``: the temporary name ends as ``path`` does (a figure, whose format matplotlib reads from it)."""
    if path is None:
        yield None
        return
    path = Path(path)
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}" if keep_suffix else f".{path.name}.{os.getpid()}.tmp")
    try:
        yield tmp
        if tmp.exists():
            os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def write_whole(path, write: Callable[[Path], None]) -> None:
    """``write(tmp)`` under a temporary name beside ``path`` that ends as it does, then moved onto it
    (:func:`written_beside`): ``path`` is the whole file or untouched, whatever stops the writing."""
    with written_beside(path, keep_suffix=True) as tmp:
        write(tmp)


def with_size(path) -> str:
    """``path`` as printed after ``wrote``: a recording (``.rrd``) with its size, which a user keeps or not by it."""
    p = Path(path)
    if p.suffix == ".rrd" and p.is_file():
        return f"{p} ({p.stat().st_size / 1e6:.1f} MB)"
    return str(p)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _dead_runs(folder: Path, prefix: str) -> list[tuple[Path, str]]:
    """The folders ``PREFIX<pid>[-REST]`` in ``folder`` (no symlinks) whose process no longer exists, with their REST
    ("" without one); a live process's, and this one's, are not among them."""
    out = []
    if not folder.is_dir():
        return out
    for entry in folder.iterdir():
        if not entry.name.startswith(prefix) or not entry.is_dir() or entry.is_symlink():
            continue
        pid, _, rest = entry.name[len(prefix) :].partition("-")
        try:
            pid = int(pid)
        except ValueError:
            continue
        if pid != os.getpid() and not _pid_alive(pid):
            out.append((entry, rest))
    return out


def remove_stale_runs(folder: Path, prefix: str) -> list[Path]:
    """Remove the folders ``PREFIX<pid>[-...]`` in ``folder`` left by runs whose process no longer exists
    (killed outright: SIGKILL, power loss); a live process's, and this one's, are left alone."""
    removed = []
    for entry, _ in _dead_runs(folder, prefix):
        shutil.rmtree(entry, ignore_errors=True)
        removed.append(entry)
    return removed


def restore_replaced(out: Path, prefix: str) -> Path | None:
    """Move back a folder a killed run had moved aside to replace it and not yet replaced (``PREFIX<pid>-replaced``
    beside ``out``, its process gone, ``out`` missing: killed outright between its two renames); the newest if there
    are several. Returns the folder it came from, or None. Without this the next run's :func:`remove_stale_runs`
    removed it, and with it the user's previous output."""
    out = Path(out)
    if out.exists() or out.is_symlink():
        return None
    found = [entry for entry, rest in _dead_runs(out.absolute().parent, prefix) if rest == "replaced"]
    if not found:
        return None
    newest = max(found, key=lambda e: e.stat().st_mtime)
    os.replace(newest, out)
    return newest


def remove_stale_stages(folder: Path) -> list[Path]:
    """Remove staging folders left in ``folder`` by runs whose process no longer exists."""
    return remove_stale_runs(folder, _STAGE_PREFIX)


@dataclass(frozen=True)
class LaterOutput:
    """An output a stage left for its caller to write (``later=True``): a figure or a recording that no later stage
    reads, which the main job writes beside the next stages' work instead of before it. The stage's folder names it
    as written (its run.json's outputs) and has no file of that name until the caller calls :attr:`write` (an earlier
    run's is removed when the folder is committed); :attr:`write` writes :attr:`path` whole (a temporary name, then a
    rename)."""

    path: Path
    write: Callable[[], None]
    #: it may be written in a forked worker (a matplotlib figure); False: in this process (a Rerun recording: rerun
    #: runs threads of its own, whose locks a forked process may find held)
    forks: bool


class OutputFolder:
    """Stage a run's outputs and move them into ``path`` together on success (see the module docstring).

    ``names`` are the files this run will write; the check for existing ones is
    made at construction, before any work, and again under the lock at commit.
    ``option`` names the command-line option in messages.
    """

    def __init__(self, path, names: Iterable[str], *, overwrite: bool, option: str = "--out", overwrite_option: str = "--overwrite"):
        text = os.fspath(path)
        if not text.strip():
            raise InputError(f"{option}: expected a folder name, got an empty string")
        self.root = Path(text)
        self.names = list(dict.fromkeys(names))
        self.overwrite = overwrite
        self.option = option
        self.overwrite_option = overwrite_option
        _check_creatable_dir(self.root, option)
        self._check_existing()
        self._stage: Path | None = None
        self._created: list[Path] = []
        self._omitted: list[str] = []
        self.written: list[Path] = []

    def _check_existing(self) -> None:
        if not self.root.is_dir():
            return
        folders = [n for n in self.names if (self.root / n).is_dir()]
        if folders:  # never replaced, --overwrite or not
            raise InputError(f"{self.option} {self.root}: {', '.join(folders)} is a folder; this run writes a file of that name")
        if self.overwrite:
            return
        existing = [n for n in self.names if (self.root / n).exists()]
        if existing:
            shown = ", ".join(existing[:4]) + (", ..." if len(existing) > 4 else "")
            raise InputError(f"{self.option} {self.root} already holds {shown}; pass {self.overwrite_option} to replace")

    def path(self, name: str) -> Path:
        """Where to write output ``name`` during the run (inside the staging folder)."""
        if self._stage is None:
            raise RuntimeError("OutputFolder.path() outside its with-block")
        if name not in self.names:
            self.names.append(name)
        return self._stage / name

    def omit(self, name: str) -> None:
        """This run does not write output ``name`` after all (a run with nothing to put in it): a file of that
        name an earlier run left in the folder is removed at the commit, so the folder never mixes two runs."""
        if name in self.names:
            self.names.remove(name)
        if name not in self._omitted:
            self._omitted.append(name)
        if self._stage is not None and (self._stage / name).exists():
            (self._stage / name).unlink()

    def final(self, name: str) -> Path:
        """Where output ``name`` will be once the run succeeds."""
        return self.root / name

    def __enter__(self) -> OutputFolder:
        mark_outputs_started(self.root)
        self._created = make_folder(self.root)  # removed again (when empty) if the run fails
        remove_stale_stages(self.root)
        self._stage = self.root / f"{_STAGE_PREFIX}{os.getpid()}-{secrets.token_hex(4)}"
        self._stage.mkdir()
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        committed = False
        try:
            if exc_type is None:
                raise_if_signalled()  # interrupted, though the exception was swallowed on the way: keep nothing
                self._commit()
                committed = True
        finally:
            if self._stage is not None:
                shutil.rmtree(self._stage, ignore_errors=True)
                self._stage = None
            if not committed:
                remove_empty(self._created)
        return False

    def _commit(self) -> None:
        staged = [n for n in self.names if (self._stage / n).exists()]
        fd = os.open(self.root, os.O_RDONLY)  # the folder itself is the lock: no lock file left behind
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            self._check_existing()  # again, under the lock: another run may have written meanwhile

            with uninterrupted(done=self.root):  # a signal waits for the moves: never half of the files replaced
                for name in staged:
                    os.replace(self._stage / name, self.root / name)
                    self.written.append(self.root / name)
                for name in self._omitted:
                    old = self.root / name
                    if old.is_file() or old.is_symlink():
                        old.unlink()
        finally:
            os.close(fd)  # releases the lock
