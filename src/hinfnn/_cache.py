"""A persistent compilation cache, so that a new process reuses the XLA programs of earlier ones.

Each new process would otherwise compile the simulator's programs again.
:func:`hinfnn.configure` (which the ``hinfnn`` command calls; importing hinfnn does not) turns on
JAX's own persistent compilation cache through its public options
(``jax_compilation_cache_dir``, ``jax_persistent_cache_min_compile_time_secs``,
``jax_persistent_cache_min_entry_size_bytes``) in a folder chosen as follows:

1. ``$HINFNN_CACHE_DIR`` if set; ``off``, ``0``, ``none``, ``false``, ``no`` (any case) or the
   empty string disable the cache;
2. else ``$XDG_CACHE_HOME/hinfnn/jax`` if ``XDG_CACHE_HOME`` is set;
3. else ``~/.cache/hinfnn/jax``.

What hinfnn adds to JAX's cache is only at the edges: the folder is created private to the user
(mode 0700: an entry is machine code that gets executed) and probed before JAX is told about it,
so that an unusable folder (a file in the way, read-only, another user's) turns the cache off
with one :class:`CacheWarning` instead of JAX's two warnings per compiled program; and
``hinfnn cache`` shows or empties it. JAX writes an entry in place (not through a temporary
file), so a process killed in the middle of a write can leave a truncated entry: JAX then warns
("Error reading persistent compilation cache entry") and compiles that program again each time,
and ``hinfnn cache --clear`` removes it. Deleting the folder at any time is safe.

JAX has one persistent cache per process, so after :func:`hinfnn.configure` the user's own
jit-compiled programs are cached in the same folder too (``HINFNN_CACHE_DIR=off`` or
``enable_cache(None)`` turns that off).
"""

from __future__ import annotations

import os
import re
import tempfile
import threading
import warnings
from pathlib import Path

#: Environment variable that sets the cache folder or disables the cache.
ENV_VAR = "HINFNN_CACHE_DIR"
#: Values of ``HINFNN_CACHE_DIR`` (compared case-insensitively, spaces stripped) that disable it.
DISABLE_VALUES = frozenset({"", "off", "0", "none", "false", "no"})
#: Programs that compile faster than this are not written (JAX's default is 1 s). 0: every
#: program is cached: besides the simulator's chunk program, a run compiles
#: about 20 small programs (start pose, checks, design), each quick to compile.
MIN_COMPILE_TIME_SECS = 0.0

_ENTRY_SUFFIX = "-cache"  # JAX's LRUCache naming: <module name>-<sha256>-cache
_TMP_PREFIX = ".tmp-"     # the write probe
#: The files the cache owns, the only ones cache_size/clear_cache look at: entries (and the
#: "-atime" files JAX writes when its size limit is on), probe leftovers.
_OWNED = re.compile(r"(.+-[0-9a-f]{64}-(cache|atime)|\.tmp-(probe-)?[a-z0-9_]{8}"
                    r"|hinfnn-program-.+-[0-9a-f]{64}-export(\.tmp-[0-9]+)?)\Z")

_lock = threading.Lock()
_active: Path | None = None       # the folder in use, None when the cache is off
_reason: str = "not set up (hinfnn.configure() turns it on)"  # why the cache is off
_warned = False                   # at most one CacheWarning per process


class CacheWarning(UserWarning):
    """The compilation cache could not be used; runs go on, compiling from scratch."""


def _warn_once(message: str) -> None:
    global _warned
    with _lock:
        if _warned:
            return
        _warned = True
    warnings.warn(message, CacheWarning, stacklevel=3)


def default_cache_dir(environ=None) -> Path | None:
    """The folder the environment asks for (see the module docstring), None if disabled.

    Only reads the environment; creates nothing.
    """
    env = os.environ if environ is None else environ
    value = env.get(ENV_VAR)
    if value is not None:
        if value.strip().lower() in DISABLE_VALUES:
            return None
        return Path(value).expanduser()
    xdg = env.get("XDG_CACHE_HOME")
    if xdg:  # the XDG spec: an empty value counts as unset
        return Path(xdg).expanduser() / "hinfnn" / "jax"
    return Path("~").expanduser() / ".cache" / "hinfnn" / "jax"


def cache_dir() -> Path | None:
    """The folder the compilation cache of this process uses, or None when it is off."""
    return _active


def cache_disabled_reason() -> str | None:
    """Why the cache is off (None when it is on): disabled by the user, or the folder is unusable."""
    return None if _active is not None else _reason


def _prepare(path: Path) -> None:
    """Create ``path`` (private to the user) and check that a file can be written there."""
    if not path.is_dir():
        # parents with the default mode, the cache folder itself private: entries are executed
        path.parent.mkdir(parents=True, exist_ok=True)
        path.mkdir(mode=0o700, exist_ok=True)
    if not path.is_dir():
        raise NotADirectoryError(f"not a folder: {path}")
    st = path.stat()
    # An entry is machine code this process will run: refuse a folder others can write to
    # (they could plant entries under predictable names) or that belongs to someone else.
    if st.st_mode & 0o002:
        raise PermissionError(f"{path} is writable by every user; the cache must be private")
    if hasattr(os, "getuid") and st.st_uid != os.getuid():
        raise PermissionError(f"{path} belongs to another user (uid {st.st_uid})")
    fd, probe = tempfile.mkstemp(prefix=_TMP_PREFIX + "probe-", dir=path)
    try:
        os.write(fd, b"hinfnn")
    finally:
        os.close(fd)
        os.unlink(probe)


def enable_cache(path: str | os.PathLike | None) -> Path | None:
    """Use ``path`` as the persistent compilation cache of this process (None: turn it off).

    A string equal to one of :data:`DISABLE_VALUES` (``"off"``, ``"0"``, ``"none"``, ``""``, ...)
    also turns it off. A relative path is taken from the current folder. The folder is created if
    needed. If it cannot be created or written, the cache is turned off with one
    :class:`CacheWarning` (never an exception). Programs this process has already compiled stay
    in memory; only later compilations read and write the new folder.

    The folder must be private: one that every user can write to, or that belongs to another
    user, is refused (an entry is machine code this process runs). JAX's own switch
    ``jax_enable_compilation_cache=False`` keeps the cache off.

    Returns the folder now in use, or None. Raises ``TypeError`` for a ``path`` that is not a
    string, path or None.
    """
    global _active, _reason
    if path is not None and not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"enable_cache: path must be a str, a path or None, got {type(path).__name__}")
    if path is None or (isinstance(path, str) and path.strip().lower() in DISABLE_VALUES):
        _install(None)
        _active, _reason = None, "disabled by enable_cache"
        return None
    import jax

    if not jax.config.jax_enable_compilation_cache:  # JAX_ENABLE_COMPILATION_CACHE=false wins
        _install(None)
        _active, _reason = None, "disabled by JAX_ENABLE_COMPILATION_CACHE / jax_enable_compilation_cache"
        return None
    try:
        target = Path(os.fspath(path)).expanduser().absolute()
        _prepare(target)
    except (OSError, ValueError) as err:  # ValueError: e.g. a NUL byte in the path
        _install(None)
        _active = None
        _reason = f"unusable folder {os.fspath(path)!s} ({type(err).__name__}: {err})"
        _warn_once(f"hinfnn: compilation cache off: cannot use {os.fspath(path)!s} "
                   f"({type(err).__name__}: {err}); runs work but compile from scratch. Set "
                   f"{ENV_VAR} to a writable folder, or to 'off' to silence this.")
        return None
    _install(target)
    _active, _reason = target, ""
    return target


def setup_from_env() -> Path | None:
    """Turn the cache on or off as the environment says (:func:`hinfnn.configure` calls it).

    Never raises: whatever goes wrong, hinfnn still imports and runs, without the cache.
    """
    global _reason
    try:
        folder = enable_cache(default_cache_dir())
        if folder is None and _reason == "disabled by enable_cache":
            _reason = f"disabled by {ENV_VAR}={os.environ.get(ENV_VAR)!r}"
        return folder
    except Exception as err:  # noqa: BLE001 - the cache must never stop hinfnn from working
        _warn_once(f"hinfnn: compilation cache off: {type(err).__name__}: {err}")
        return None


def _entries(path: Path):
    """Regular files of ``path`` that the cache wrote (entries, stale temporaries): see _OWNED."""
    try:
        it = list(os.scandir(path))
    except (FileNotFoundError, NotADirectoryError):
        return []
    out = []
    for e in it:
        if not _OWNED.match(e.name):
            continue
        try:
            if e.is_file(follow_symlinks=False):
                out.append(e)
        except OSError:
            continue
    return out


def cache_size(path: str | os.PathLike | None = None) -> tuple[int, int]:
    """``(number of files, bytes)`` held by the cache folder (the active one by default).

    Only files the cache writes are counted; a missing folder or a disabled cache gives (0, 0).
    """
    folder = _active if path is None else Path(path)
    if folder is None:
        return 0, 0
    n = size = 0
    for e in _entries(folder):
        try:
            size += e.stat(follow_symlinks=False).st_size
            n += 1
        except FileNotFoundError:  # removed meanwhile (another process clearing it)
            continue
    return n, size


def clear_cache(path: str | os.PathLike | None = None) -> int:
    """Delete every cache entry of the folder (the active one by default); returns bytes removed.

    Only files the cache writes are removed (so a mistaken ``HINFNN_CACHE_DIR=$HOME`` cannot
    delete anything else); the folder itself is kept. Safe while other processes use the
    cache: they see misses and compile again. A disabled cache or a missing folder gives 0.
    Raises ``OSError`` if an entry exists but cannot be removed (e.g. a read-only folder).
    """
    folder = _active if path is None else Path(path)
    if folder is None:
        return 0
    removed = 0
    for e in _entries(folder):
        try:
            size = e.stat(follow_symlinks=False).st_size
            os.unlink(e.path)
        except FileNotFoundError:
            continue
        removed += size
    return removed


# --- the JAX side ----------------------------------------------------------------------------


def _install(folder: Path | None) -> None:
    """Point JAX's persistent cache at ``folder`` (None: off), through its public options."""
    import jax
    from jax.experimental.compilation_cache import compilation_cache as cc

    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_SECS)
    jax.config.update("jax_compilation_cache_dir", None if folder is None else str(folder))
    cc.reset_cache()  # JAX opens its cache on the next compilation, in the new folder
