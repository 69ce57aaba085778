"""Folders on disk: written atomically, reserved before any work, recognised by their marker.

Every result folder (``hinfnn run``, ``compare``, ``gallery``, ``reproduce``) is written as a
whole: every file goes to a hidden temporary sibling folder first, and only a complete folder is
renamed into place (:class:`OutputFolder`); an interrupted or failed command (exception, SIGINT,
SIGTERM) leaves the target as it was. A folder is reserved before anything runs
(:func:`reserve_output`): a lock file beside it (:class:`FolderLock`) that no second hinfnn process
can take, for results and sweeps alike. ``.hinfnn-result`` marks a folder hinfnn wrote (and which
files), so that ``--force`` replaces only such a folder.

The same contract holds for every command that writes (results, sweeps, ``plot``, ``export``):
reserve and check first (:func:`check_writable`: a read-only disk or a broken link is refused
before any work), write aside, commit in one step, never touch a file hinfnn did not write
(:func:`foreign_files`, :func:`owns`). Where a folder cannot be renamed, a mount point or a
symbolic link to a folder (:func:`commits_inside`), the result is written in a hidden folder
inside it and committed there (:func:`replace_folder`).
"""

from __future__ import annotations

import contextlib
import datetime
import errno
import itertools
import json
import os
import re
import shutil
import signal
import socket
import tempfile
import time
from pathlib import Path
from typing import Callable

from .._signals import check as _check_signals


def version() -> str:
    from .. import __version__

    return __version__


# --- atomic files and folders ------------------------------------------------------------------


def atomic_write(path: Path, write: Callable[[Path], None], *, replace: bool = True) -> Path:
    """Call ``write(tmp)`` for a temporary file beside ``path``, then rename it to ``path``.
    ``replace=False``: ``path`` must not exist when the file is put in place (FileExistsError if
    one appeared meanwhile: it is never overwritten)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".part", dir=path.parent)
    os.close(fd)
    tmp = Path(tmp)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the file the usual mode
        if replace:
            os.replace(tmp, path)
        else:
            _link_new(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _link_new(tmp: Path, path: Path) -> None:
    """Put ``tmp`` at ``path`` only if nothing is there (a hard link fails on an existing name);
    where the file system has no hard links, a rename after a last look."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise
    except OSError:
        if os.path.lexists(path):
            raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), os.fspath(path)) from None
        os.replace(tmp, path)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write_text(path: Path, text: str) -> Path:
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"))


def atomic_write_bytes(path: Path, data: bytes) -> Path:
    return atomic_write(path, lambda p: p.write_bytes(data))


def _is_empty_dir(p: Path) -> bool:
    return p.is_dir() and not any(p.iterdir())


# --- result folders: names, the marker, reservation ---------------------------------------------

#: The file hinfnn writes into every result folder (JSON: format, version, command, the files it
#: wrote). ``--force`` replaces only a folder that has it and no other files (or an empty one).
MARKER = ".hinfnn-result"
MARKER_FORMAT = "hinfnn-result-1"
#: Longest folder name hinfnn makes from a scenario name, and accepts as the last part of --out.
MAX_NAME = 80
_MAX_OUT_NAME = 200
#: Prefix of the temporary folder hinfnn writes into inside a folder it cannot rename (a mount
#: point, a symbolic link): see :func:`replace_folder`.
INSIDE_PREFIX = ".hinfnn-partial-"
#: Files a result folder written before the marker existed may hold (recognised by metrics.json).
_LEGACY_FILES = re.compile(r"(metrics\.json|trajectory\.npz|scenario\.toml|report\.md|[^/]+\.png)\Z")


def safe_name(name: str, *, fallback: str = "scenario") -> str:
    """A folder name made from a scenario name: letters, digits, ``_``, ``-`` and single dots only
    (no path separators, no ``..``, no leading dot), at most :data:`MAX_NAME` characters."""
    s = re.sub(r"[^\w.-]+", "_", str(name))
    s = re.sub(r"\.{2,}", "_", s)
    s = re.sub(r"_{2,}", "_", s).strip("._-")
    s = s[:MAX_NAME].rstrip("._-")
    return s or fallback


def timestamp(now: datetime.datetime | None = None) -> str:
    """UTC time as ``20261129T170102Z`` (sorts in time order, no characters a shell or a file
    system minds)."""
    now = now or datetime.datetime.now(datetime.timezone.utc)
    return now.astimezone(datetime.timezone.utc).strftime("%Y%m%dT%H%M%SZ")


def default_output(command: str, name: str, now: datetime.datetime | None = None) -> Path:
    """Where a command writes when ``--out`` is not given: ``results/paper`` for ``reproduce``,
    ``results/gallery`` for ``gallery``, ``results/<command>s/<safe name>-<UTC time>`` for every
    other command (``results/runs/...`` for ``run``), so that no two commands share a default
    folder (a second reproduce or gallery goes to ``-2``, ``-3`` ...)."""
    if command == "reproduce":
        return Path("results") / "paper"
    if command == "gallery":
        return Path("results") / "gallery"
    return Path("results") / f"{command}s" / f"{safe_name(name)}-{timestamp(now)}"


def read_marker(folder: Path) -> dict | None:
    """The marker of a result folder (None when there is none or it is not hinfnn's)."""
    try:
        doc = json.loads((Path(folder) / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(doc, dict) or doc.get("format") != MARKER_FORMAT or not isinstance(doc.get("files"), list):
        return None
    return doc


def _entries(folder: Path) -> list[str]:
    return sorted(p.name + ("/" if p.is_dir() and not p.is_symlink() else "") for p in Path(folder).iterdir())


def _legacy_result(folder: Path) -> bool:
    try:
        doc = json.loads((folder / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False
    return isinstance(doc, dict) and str(doc.get("format", "")).startswith("hinfnn-metrics")


def marker_damaged(folder: Path) -> bool:
    """Whether ``folder`` has a marker file that hinfnn cannot read (cut, or not hinfnn's)."""
    folder = Path(folder)
    return (folder / MARKER).is_file() and read_marker(folder) is None


def _temporary(name: str) -> bool:
    """hinfnn's own temporary entries inside a folder it commits into (:func:`replace_folder`)."""
    return name.rstrip("/").startswith(INSIDE_PREFIX)


def foreign_files(folder: Path) -> list[str]:
    """The entries of ``folder`` that hinfnn did not write (folders end with ``/``): all of them
    for a folder without a marker, those the marker does not list otherwise. A result folder
    written before markers existed, or whose marker is damaged (cut), is recognised by its
    metrics.json and hinfnn's file names. The marker itself and hinfnn's temporary folders of
    an interrupted commit are hinfnn's."""
    folder = Path(folder)
    names = [n for n in _entries(folder) if not _temporary(n)]
    marker = read_marker(folder)
    if marker is not None:
        owned = {str(f) for f in marker["files"]} | {MARKER}
        return [n for n in names if n not in owned]
    if _legacy_result(folder):
        return [n for n in names if not _LEGACY_FILES.match(n) and not (n == MARKER and marker_damaged(folder))]
    return names


def owns(path: Path) -> bool:
    """Whether the file ``path`` is one hinfnn wrote: listed in its folder's marker (or, in a
    result folder written before markers, one of hinfnn's file names)."""
    path = Path(path)
    return path.parent.is_dir() and path.name not in foreign_files(path.parent)


def write_marker(folder: Path, *, kind: str, command: str, files=None) -> Path:
    """Write (or rewrite, keeping ``created``) the marker of a result folder; ``files``: what
    hinfnn wrote there (default: every entry but the marker)."""
    folder = Path(folder)
    old = read_marker(folder) or {}
    doc = {"format": MARKER_FORMAT, "hinfnn_version": version(), "kind": old.get("kind", kind),
           "command": old.get("command", command),
           "created": old.get("created", datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")),
           "files": sorted(files if files is not None else (n for n in _entries(folder) if n != MARKER))}
    return atomic_write_text(folder / MARKER, json.dumps(doc, indent=2) + "\n")


def add_to_marker(folder: Path, names) -> None:
    """Record files hinfnn added to an existing result folder (``plot``, ``export``) so that
    ``--force`` still recognises the folder as hinfnn's."""
    folder = Path(folder)
    marker = read_marker(folder)
    if marker is None:
        if not _legacy_result(folder):
            return  # not a result folder (e.g. plot --out FOLDER): nothing to keep up to date
        files = [n for n in _entries(folder) if _LEGACY_FILES.match(n)]
        write_marker(folder, kind="run", command="", files=set(files) | set(names))
        return
    write_marker(folder, kind=marker.get("kind", "run"), command=marker.get("command", ""),
                 files=set(marker["files"]) | set(names))


def _out_error(message: str) -> Exception:
    from ..errors import ConfigError

    return ConfigError(message, key="--out")


def check_writable(path, *, key: str = "--out") -> None:
    """Refuse, before any work, a place hinfnn could not write to (:class:`~hinfnn.errors.ConfigError`
    keyed ``key``): a broken symbolic link, a path inside a file, a folder on a read-only disk or
    without write permission. ``path`` is a folder that will be written into (if it exists) or
    created (its nearest existing parent is checked then)."""
    from ..errors import ConfigError

    path = Path(os.path.expanduser(os.fspath(path)))
    p = path
    while not p.exists():
        if p.is_symlink():
            raise ConfigError(f"{p} is a broken symbolic link (it points to {os.readlink(p)}, which does not "
                              "exist); give an existing folder or a new path", key=key)
        p = p.parent
    if not p.is_dir():
        raise ConfigError(f"{p} is a file, not a folder" + (f" (in {path})" if p != path else ""), key=key)
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".hinfnn-probe-", dir=p))  # made and removed: we can write there
    except OSError as err:
        raise ConfigError(f"cannot write in {p}: {err.strerror or err}; give a folder hinfnn may write to",
                          key=key) from None


def commits_inside(target: Path) -> bool:
    """Whether a complete folder is put at ``target`` by moving its files into it rather than by
    renaming the folder: ``target`` is a mount point (a rename over it fails with EBUSY, one
    into it with EXDEV) or a symbolic link to a folder (the link is kept, its folder written)."""
    target = Path(target)
    return target.is_dir() and (target.is_symlink() or os.path.ismount(target))


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class FolderLock:
    """The lock that reserves a folder for one hinfnn process: a file beside it
    (``.NAME.hinfnn-lock``) created with O_EXCL, holding the owner's pid and host. A lock whose
    process is gone (killed, even by SIGKILL) is stale and taken over; one held by a live process
    (or by another machine's, which cannot be checked) is not. Used by every command that writes a
    folder: results (:func:`reserve_output`) and sweeps."""

    def __init__(self, target: Path):
        self.target = Path(target)
        self.path = self.target.with_name(f".{self.target.name}.hinfnn-lock")
        self.held = False

    def owner(self) -> int | None:
        """The pid of the live process that holds the lock (-1: being written this moment, or
        unknown), or None when nobody holds it (no file, or a stale one)."""
        try:
            doc = json.loads(self.path.read_text(encoding="utf-8"))
            pid, host = int(doc["pid"]), str(doc.get("host", ""))
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError):
            try:  # being written right now (created, not yet filled): give it a moment
                if time.time() - self.path.stat().st_mtime < 5.0:
                    return -1
            except OSError:
                return None
            return None
        if host and host != socket.gethostname():
            return pid  # another machine's process: cannot tell, assume it is alive
        return pid if _pid_alive(pid) else None

    def acquire(self) -> int | None:
        """Take the lock (returns None), or return the pid of the process holding it (-1: unknown).
        OS errors other than an existing lock propagate."""
        for _ in range(3):
            try:
                fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                owner = self.owner()
                if owner is not None:
                    return owner
                with contextlib.suppress(FileNotFoundError):
                    self.path.unlink()  # stale: its process is gone
                continue
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump({"pid": os.getpid(), "host": socket.gethostname(), "target": str(self.target),
                           "since": time.time()}, f)
            self.held = True
            return None
        return -1

    def release(self) -> None:
        if self.held:
            with contextlib.suppress(FileNotFoundError):
                self.path.unlink()
            self.held = False


class Reservation:
    """An output folder reserved for this process: ``target`` is where the result goes,
    ``note`` says why it is not where the user asked (or None). Held by its :class:`FolderLock`,
    released by :meth:`release` (the :class:`OutputFolder` that writes the result releases it)."""

    def __init__(self, target: Path, lock: FolderLock, note: str | None, created: list[Path], requested: Path):
        self.target = target
        self.lock = lock
        self.note = note
        self.requested = requested
        self._created = created  # parent folders this reservation made (removed again if unused)

    def release(self, *, keep_parents: bool = False) -> None:
        self.lock.release()
        if not keep_parents:
            for p in reversed(self._created):
                with contextlib.suppress(OSError):
                    p.rmdir()
        self._created = []

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        self.release()
        return False


def _make_parents(parent: Path, shown: Path) -> list[Path]:
    missing = []
    p = parent
    while not p.exists():
        if p.is_symlink():  # a dangling link
            raise _out_error(f"{p} is a broken symbolic link")
        missing.append(p)
        p = p.parent
    if not p.is_dir():
        where = p if shown.is_absolute() else Path(os.path.relpath(p))
        raise _out_error(f"{where} is a file, not a folder (in {shown})")
    created = []
    try:
        for d in reversed(missing):
            d.mkdir()
            created.append(d)
    except OSError as err:
        for d in reversed(created):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise _out_error(f"cannot create folder {err.filename or d}: {err.strerror or err}") from None
    return created


def reserve_output(out, *, command: str = "run", name: str = "result", force: bool = False) -> Reservation:
    """Decide and reserve the output folder of a command, before any work is done.

    ``out``: the folder the user asked for (``--out``; None: :func:`default_output` of
    ``command`` and the scenario ``name``). It may not be empty, the current folder or one
    containing it, a file, or inside a file; its parent is created if needed (and removed
    again if the command ends without a result). A missing or empty folder is used as is. A
    folder that already holds something is kept: the result goes to ``OUT-2``, ``OUT-3`` …
    (said in ``note``), unless ``force``: then a folder hinfnn wrote (its marker and nothing
    else) is replaced when the result is complete, and any other is refused naming the files
    hinfnn did not write. Two processes never get the same folder: the reservation is a lock
    file created atomically beside it; a folder another live process is writing is skipped
    (or, with ``force``, refused).

    Every problem is a :class:`~hinfnn.errors.ConfigError` with key ``--out`` (exit 2).
    """
    if out is None:
        out = default_output(command, name)
    text = os.fspath(out)
    if text.strip() == "":
        raise _out_error("is empty; give the folder to write to (default: a new folder under results/)")
    if "\0" in text:
        raise _out_error("contains a NUL character")
    shown = Path(text)
    path = Path(os.path.abspath(os.path.expanduser(text)))
    cwd = Path.cwd()
    if path == Path(path.anchor) or path == cwd or path in cwd.parents:
        raise _out_error(f"{text!r} is {'the current folder' if path == cwd else 'a folder that contains the current one'}; "
                         "give a new folder's name")
    if len(path.name) > _MAX_OUT_NAME:
        raise _out_error(f"the folder name is {len(path.name)} characters long; at most {_MAX_OUT_NAME}")
    if path.exists() and not path.is_dir():
        raise _out_error(f"output path {shown} exists and is not a folder")
    if path.is_symlink() and not path.exists():
        check_writable(shown)  # says it is a broken link
    created = _make_parents(path.parent, shown)
    note = None
    res = None
    try:
        for i in itertools.count(1):
            cand = path if i == 1 else path.with_name(f"{path.name}-{i}")
            cand_shown = shown if i == 1 else Path(f"{shown}-{i}")
            lock = FolderLock(cand)
            try:
                owner = lock.acquire()
            except OSError as err:
                raise _out_error(f"cannot create {cand_shown}: {err.strerror or err} (in {path.parent})") from None
            if owner is not None:
                busy = f"{cand_shown} is being written by another hinfnn process" + (f" (pid {owner})" if owner > 0 else "")
                if force and i == 1:
                    raise _out_error(f"{busy}; wait for it to finish or choose another --out")
                note = note or busy + "; writing to {new} instead"
                continue
            res = Reservation(cand, lock, None, created, shown)
            if cand.exists() and not cand.is_dir():
                res.release(keep_parents=True)
                res = None
                continue
            try:
                if not cand.exists() or _is_empty_dir(cand):
                    break
                foreign = foreign_files(cand) if force and i == 1 else None
            except OSError as err:
                raise _out_error(f"cannot read {cand_shown}: {err.strerror or err}") from None
            if force and i == 1:
                if not foreign:
                    break
                res.release(keep_parents=True)
                res = None
                listed = ", ".join(foreign[:5]) + (f" and {len(foreign) - 5} more" if len(foreign) > 5 else "")
                damaged = (f" (its {MARKER}, which lists what hinfnn wrote, is damaged: only hinfnn's usual "
                           "file names count as hinfnn's)") if marker_damaged(cand) else ""
                raise _out_error(f"{shown} holds files hinfnn did not write ({listed}){damaged}; --force replaces "
                                 "only a folder hinfnn wrote: choose another --out, or move those files away")
            res.release(keep_parents=True)
            res = None
            if note is None:
                note = f"{shown} is not empty; writing to " + "{new} instead (use --force to replace it)"
        if commits_inside(cand):  # the result is written inside it: that must be possible
            check_writable(cand)
    except BaseException:
        if res is not None:
            res.release(keep_parents=True)
        for d in reversed(created):
            with contextlib.suppress(OSError):
                d.rmdir()
        raise
    res.note = note.replace("{new}", str(cand_shown)) if note and cand != path else None
    res.target = cand if text.startswith("~") else cand_shown
    return res


@contextlib.contextmanager
def _terminate_as_exception():
    """SIGTERM raises :class:`Terminated` in the block (as Ctrl-C raises KeyboardInterrupt), so
    that the temporary folder is removed; the ``hinfnn`` command has installed the same handler."""
    from .. import _signals

    try:
        previous = signal.signal(signal.SIGTERM, _signals.handler)
    except ValueError:  # not in the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE). False where unsupported."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        fn = libc.renameat2
    except (OSError, AttributeError):
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    fn.restype = ctypes.c_int
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(err, os.strerror(err), os.fspath(b))


class OutputFolder:
    """Context manager: files written into ``.path`` (a temporary folder) appear in the target
    only if the block completes; otherwise the target stays exactly as it was.

    ``target``: a :class:`Reservation` (from :func:`reserve_output`; released on exit) or a
    folder. On success the marker (``.hinfnn-result``: ``kind``, ``command`` and the files
    written) is added and the folder is put in place in one step: renamed in, or, over an
    existing result (``--force``), swapped with it atomically (the old one is then deleted),
    with SIGINT/SIGTERM blocked meanwhile. Should files hinfnn did not write appear in the
    target while the result is computed, it is kept and the result goes to the next free name
    (``moved_to`` says where).
    """

    def __init__(self, target, *, kind: str = "run", command: str = ""):
        self.reservation = target if isinstance(target, Reservation) else None
        self.target = Path(target.target if self.reservation else target)
        self.kind = kind
        self.command = command
        self.path: Path | None = None
        self.moved_to: Path | None = None

    def __enter__(self) -> "OutputFolder":
        try:
            self.target.parent.mkdir(parents=True, exist_ok=True)
            if commits_inside(self.target):
                self.path = Path(tempfile.mkdtemp(prefix=INSIDE_PREFIX, dir=self.target))
            else:
                self.path = Path(tempfile.mkdtemp(prefix=f".{self.target.name}.partial-", dir=self.target.parent))
        except OSError as err:
            if self.reservation is not None:
                self.reservation.release()
            raise _out_error(f"cannot write in {err.filename or self.target.parent}: {err.strerror or err}") from None
        except BaseException:
            if self.reservation is not None:
                self.reservation.release()
            raise
        os.chmod(self.path, 0o777 & ~_umask())  # mkdtemp makes 0700
        self._signals = _terminate_as_exception()
        self._signals.__enter__()
        return self

    def __exit__(self, exc_type, exc, tb):
        ok = exc_type is None
        try:
            if ok:
                _check_signals()  # a Ctrl-C whose exception Python swallowed: no result then
                write_marker(self.path, kind=self.kind, command=self.command)
                self._commit()
        except BaseException:
            ok = False
            raise
        finally:
            if self.path is not None and self.path.exists():
                shutil.rmtree(self.path, ignore_errors=True)
            self._signals.__exit__(None, None, None)
            if self.reservation is not None:
                self.reservation.release(keep_parents=ok)
        return False

    def _commit(self):
        if self.target.is_dir() and any(self.target.iterdir()) and foreign_files(self.target):
            # someone put files there while we computed: keep them, take the next free name
            res = reserve_output(self.target, force=False)
            try:
                _move_entry(self.path, Path(res.target))
            finally:
                res.release(keep_parents=True)
            self.moved_to = res.target
            return
        replace_folder(self.path, self.target)


def replace_folder(new: Path, target: Path) -> None:
    """Put the complete folder ``new`` at ``target`` in one step: renamed in, or over an existing
    folder swapped with it atomically (the old one is then deleted), with SIGINT and SIGTERM
    blocked meanwhile. Where the folder cannot be renamed (``target`` a mount point or a symbolic
    link, :func:`commits_inside`, or a rename that fails with EBUSY or EXDEV), the result is
    committed inside it instead (:func:`_commit_into`)."""
    new, target = Path(new), Path(target)
    blocked = {signal.SIGINT, signal.SIGTERM}
    old_mask = signal.pthread_sigmask(signal.SIG_BLOCK, blocked)
    try:
        if commits_inside(target) or new.parent.resolve() == target.resolve():
            _commit_into(new, target)
            return
        try:
            if not os.path.lexists(target):
                os.replace(new, target)
            elif _exchange(new, target):
                shutil.rmtree(new, ignore_errors=True)  # now the old one
            else:
                backup = Path(tempfile.mkdtemp(prefix=f".{target.name}.old-", dir=target.parent))
                backup.rmdir()
                os.replace(target, backup)
                os.replace(new, target)
                shutil.rmtree(backup, ignore_errors=True)
        except OSError as err:
            if err.errno not in (errno.EBUSY, errno.EXDEV) or not target.is_dir():
                raise
            _commit_into(new, target)  # a mount point os.path.ismount does not see (a bind mount)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old_mask)


def _commit_into(new: Path, dest: Path) -> None:
    """Commit the complete folder ``new`` inside the existing folder ``dest`` (which hinfnn holds
    the lock of, and whose entries are all hinfnn's): a marker listing the old and the new files
    first (so that an interruption leaves a folder ``--force`` still recognises), then the old
    entries removed, the new ones moved in, the new marker last."""
    dest = Path(dest)
    new = Path(new)
    names = sorted(p.name for p in new.iterdir() if p.name != MARKER)
    inside = new.parent.resolve() == dest.resolve()
    old = [p for p in dest.iterdir() if p.name != MARKER and not (inside and p.name == new.name)]
    marker = read_marker(new)
    if marker is not None and old:
        both = {n for n in _entries(dest) if n != MARKER and not _temporary(n)} | set(marker["files"])
        atomic_write_text(dest / MARKER, json.dumps({**marker, "files": sorted(both)}, indent=2) + "\n")
    for p in old:
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p)
        else:
            p.unlink()
    for name in names + ([MARKER] if marker is not None else []):
        _move_entry(new / name, dest / name)
    shutil.rmtree(new, ignore_errors=True)


def _move_entry(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst`` (which does not exist, or is a file); across file systems
    (EXDEV) a copy beside ``dst`` is renamed into place and ``src`` deleted."""
    try:
        os.replace(src, dst)
        return
    except OSError as err:
        if err.errno != errno.EXDEV:
            raise
    tmp = Path(tempfile.mkdtemp(prefix=INSIDE_PREFIX, dir=dst.parent))
    try:
        copy = tmp / dst.name
        if src.is_dir() and not src.is_symlink():
            shutil.copytree(src, copy, symlinks=True)
        else:
            shutil.copy2(src, copy, follow_symlinks=False)
        os.replace(copy, dst)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    if src.is_dir() and not src.is_symlink():
        shutil.rmtree(src)
    else:
        src.unlink()


__all__ = ["atomic_write", "atomic_write_text", "atomic_write_bytes", "safe_name", "timestamp", "default_output",
           "MARKER", "read_marker", "write_marker", "add_to_marker", "foreign_files", "FolderLock", "Reservation",
           "reserve_output", "OutputFolder", "replace_folder", "version", "check_writable", "commits_inside", "owns",
           "marker_damaged"]
