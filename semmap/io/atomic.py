"""Output folders appear whole or not at all, and never replace what they should not.

:func:`atomic_dir` checks the output path before any work starts (so a build fails in its
first second, not after an hour), writes into a hidden ``.NAME.*.partial`` folder beside it,
and renames that into place when everything is written. ``force`` replaces only an empty
folder or one that carries the given marker file (a semmap map folder's ``summary.json``,
a tour folder's ``tour.yaml``), never a regular file, and never a path that holds one of the
command's inputs. A ``.partial`` folder left by a process that was killed is removed by the
next run that writes beside it.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import socket
import tempfile
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from ..errors import OutputError, OutputExistsError

__all__ = ["COMMITTED", "atomic_dir", "atomic_file", "check_output", "check_output_file"]

_OWNER = ".semmap-owner"

#: every output path this process has put in place, in order (the CLI reads it: an interrupt that
#: arrives once the command's output is complete does not make the command fail)
COMMITTED: list[Path] = []


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def check_output(out: str | Path, force: bool = False, marker: str | None = None,
                 inputs: Sequence[str | Path] = (), what: str = "output folder") -> Path:
    """Refuse an output path that must not be written, before any work; returns it resolved.

    * an existing path without ``force``;
    * with ``force``: a path that is not a folder, or a non-empty folder without ``marker``;
    * a path that is, or holds, one of ``inputs`` (the bag being read must survive ``--force``).
    """
    out = Path(out).expanduser()
    target = out.resolve()
    for src in inputs:
        s = Path(src).expanduser().resolve()
        if _inside(s, target):
            raise OutputError(f"{out}: {'is' if s == target else 'holds'} the input {src}; "
                              f"write the {what} somewhere else")
    if out.exists() or out.is_symlink():
        if not force:
            raise OutputExistsError(f"{out}: already exists (use --force to replace it)")
        if not out.is_dir() or out.is_symlink():
            raise OutputError(f"{out}: is not a folder; --force replaces only a {what}")
        if marker is not None and not (out / marker).is_file() and any(out.iterdir()):
            raise OutputError(f"{out}: is not a {what} (no {marker}); --force replaces only a {what}, "
                              "so move or delete it yourself")
    parent = out.parent
    probe = parent
    while not probe.exists():  # the nearest folder that exists must let us create the rest
        probe = probe.parent
    if not probe.is_dir():
        raise OutputError(f"{out}: cannot be created ({probe} is not a folder)")
    if not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: cannot write in {probe} (permission denied)")
    return target


def check_output_file(out: str | Path, force: bool = False, inputs: Sequence[str | Path] = (),
                      what: str = "file") -> Path:
    """Refuse a file path that must not be written, before any work: an existing file without
    ``force``, a folder, one of ``inputs``, or a place that cannot be written."""
    out = Path(out).expanduser()
    for src in inputs:
        if Path(src).expanduser().resolve() == out.resolve():
            raise OutputError(f"{out}: is the input {src}; write the {what} somewhere else")
    if out.is_dir():
        raise OutputError(f"{out}: is a folder, not a {what}")
    if out.exists() and not force:
        raise OutputExistsError(f"{out}: already exists (use --force to replace it)")
    probe = out.parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir() or not os.access(probe, os.W_OK | os.X_OK):
        raise OutputError(f"{out}: cannot write in {probe}")
    return out


def _remove_stale_partials(parent: Path, name: str) -> None:
    """``.NAME.*.partial`` folders whose writer on this host has ended (killed mid-write)."""
    host = socket.gethostname()
    for p in parent.glob(f".{name}.*.partial"):
        try:
            owner = json.loads((p / _OWNER).read_text(encoding="utf-8"))
            pid, their_host = int(owner["pid"]), str(owner["host"])
        except (OSError, ValueError, KeyError, TypeError):
            continue  # not ours to judge
        if their_host != host or pid == os.getpid():
            continue
        try:
            os.kill(pid, 0)
            continue  # still running: another build writing here
        except ProcessLookupError:
            pass
        except PermissionError:
            continue
        shutil.rmtree(p, ignore_errors=True)


def _write_error(out: Path, tmp: Path, exc: OSError) -> OutputError:
    """An error writing inside the hidden folder, told in terms of the user's path."""
    name = str(exc.filename or "")
    rel = name[len(str(tmp)):].lstrip("/") if name.startswith(str(tmp)) else ""
    where = f"{out / rel}" if rel else str(out)
    return OutputError(f"{where}: cannot write ({exc.strerror or exc})")


@contextmanager
def atomic_dir(out: str | Path, force: bool = False, marker: str | None = None,
               inputs: Sequence[str | Path] = (), what: str = "output folder") -> Iterator[Path]:
    """Yield a hidden folder beside ``out``; move it to ``out`` when the block succeeds.

    ``out`` is checked first (:func:`check_output`); enter this before the work, so a bad
    ``--out`` fails at once. An existing ``out`` is replaced only after the new folder is
    complete. On any exception, including Ctrl-C and SIGTERM raised as exceptions, the hidden
    folder is removed and ``out`` is left as it was.
    """
    from ..runtime import raise_if_stopped, signals_held

    out = Path(out).expanduser()
    check_output(out, force, marker, inputs, what)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        _remove_stale_partials(out.parent, out.name)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".partial", dir=out.parent))
    except OSError as exc:
        raise OutputError(f"{out}: cannot create the {what} ({exc.strerror or exc})") from None
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes it private; the result should not be
        (tmp / _OWNER).write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname()}), encoding="utf-8")
        try:
            yield tmp
        except OSError as exc:
            if str(exc.filename or "").startswith(str(tmp)):
                raise _write_error(out, tmp, exc) from None
            raise
        (tmp / _OWNER).unlink()
        with signals_held():  # the old folder goes and the new one arrives, or neither
            raise_if_stopped()  # (a stop signal whose exception a finalizer swallowed: nothing is committed)
            trash = None
            if out.exists():
                check_output(out, force, marker, inputs, what)  # it may have appeared meanwhile
                trash = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
                os.replace(out, trash / "old")
            try:
                os.replace(tmp, out)
            except OSError:
                if trash is not None:
                    os.replace(trash / "old", out)
                raise
            COMMITTED.append(out.resolve())
            if trash is not None:
                shutil.rmtree(trash, ignore_errors=True)
    except BaseException:
        with signals_held():
            shutil.rmtree(tmp, ignore_errors=True)
        raise


@contextmanager
def atomic_file(out: str | Path, force: bool = False, inputs: Sequence[str | Path] = (),
                what: str = "file") -> Iterator[Path]:
    """Yield a hidden path beside the file ``out``; rename it to ``out`` when the block succeeds."""
    from ..runtime import raise_if_stopped, signals_held

    out = check_output_file(out, force, inputs, what)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".partial" + out.suffix, dir=out.parent)
        os.close(fd)
    except OSError as exc:
        raise OutputError(f"{out}: cannot write ({exc.strerror or exc})") from None
    tmp = Path(name)
    try:
        yield tmp
        with signals_held():
            raise_if_stopped()
            os.chmod(tmp, 0o666 & ~_umask())
            os.replace(tmp, out)
            COMMITTED.append(out.resolve())
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
