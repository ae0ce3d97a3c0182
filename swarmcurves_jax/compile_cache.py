"""Compiled programs kept across sessions: JAX's persistent compilation cache, on by default.

Most of a first call's wait is compilation (docs/performance.md).  JAX can keep compiled
programs on disk, keyed by the program, the JAX version and the machine, so that a later
process reads them back instead of compiling; it is off unless a folder is set.  The
first fit of a process turns it on in the per-user cache folder
(``platformdirs.user_cache_dir("swarmcurves_jax")``, e.g. ``~/.cache/swarmcurves_jax/xla``
on Linux), bounded to :data:`MAX_BYTES` (least recently used entries go first), unless:

* JAX already has a cache folder (``JAX_COMPILATION_CACHE_DIR`` or
  ``jax.config.update("jax_compilation_cache_dir", ...)``): it is used as it is;
* ``SWARMCURVES_CACHE_DIR`` names another folder, or is ``off`` (also ``0``, ``none``,
  ``false`` or empty) to keep nothing;
* :func:`use_cache` was called first (``use_cache(None)``: keep nothing).

JAX has one cache per process, so the user's own programs that take a second or more to
compile are kept there too.  An unreadable or stale entry is not fatal: JAX warns and
compiles again.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path

import jax

__all__ = ["ENV", "MAX_BYTES", "MIN_COMPILE_SECONDS", "default_dir", "use_cache", "cache_dir"]

#: The environment variable that moves the cache (a folder) or turns it off (``off``).
ENV = "SWARMCURVES_CACHE_DIR"

#: The cache's size bound when this package sets it up: about a thousand programs.
MAX_BYTES = 1 << 30

#: The shortest compilation worth keeping.
MIN_COMPILE_SECONDS = 0.2

_OFF = ("", "0", "off", "none", "false")
_lock = threading.Lock()
_decided = False


def default_dir() -> Path | None:
    """The folder the first fit uses: ``$SWARMCURVES_CACHE_DIR`` (None if it says off),
    else ``xla`` in the per-user cache folder."""
    env = os.environ.get(ENV)
    if env is not None:
        return None if env.strip().lower() in _OFF else Path(env).expanduser()
    import platformdirs

    return Path(platformdirs.user_cache_dir("swarmcurves_jax")) / "xla"


def cache_dir() -> Path | None:
    """The folder JAX keeps compiled programs in now (None: nothing is kept)."""
    path = jax.config.jax_compilation_cache_dir
    return None if not path or not jax.config.jax_enable_compilation_cache else Path(path)


def use_cache(path: str | os.PathLike | None = "default") -> Path | None:
    """Keep compiled programs in ``path`` (None or ``"off"``: keep nothing; ``"default"``:
    :func:`default_dir`) from now on in this process; returns the folder used.

    Call it before the first fit to take effect for that fit's programs; JAX reads the
    folder once, at its first compilation that consults the cache.  Programs that compile
    in :data:`MIN_COMPILE_SECONDS` or more are kept (JAX's default, 1 s, would leave out
    the initial draws' 0.3 s)."""
    global _decided
    with _lock:
        _decided = True
        folder = default_dir() if path == "default" else path
        if isinstance(folder, str) and folder.strip().lower() in _OFF:
            folder = None
        if folder is None:
            jax.config.update("jax_enable_compilation_cache", False)
            return None
        folder = Path(folder).expanduser()
        folder.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_enable_compilation_cache", True)
        jax.config.update("jax_compilation_cache_dir", str(folder))
        if jax.config.jax_compilation_cache_max_size == -1:
            jax.config.update("jax_compilation_cache_max_size", MAX_BYTES)
        if jax.config.jax_persistent_cache_min_compile_time_secs == 1.0:  # JAX's default
            jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_SECONDS)
        return folder


def ensure() -> None:
    """Set up the default cache once per process, unless JAX or the user has one."""
    global _decided
    if _decided:
        return
    if jax.config.jax_compilation_cache_dir:
        _decided = True
        return
    try:
        use_cache("default")
    except OSError as exc:  # an unwritable home: compile every time, and say so
        import warnings

        warnings.warn(
            f"swarmcurves_jax: no persistent compilation cache ({exc}); set {ENV} to a "
            "writable folder, or to 'off'",
            RuntimeWarning,
            stacklevel=3,
        )
