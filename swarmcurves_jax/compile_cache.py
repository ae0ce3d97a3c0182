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

JAX has one cache per process, so the user's own programs that take
:data:`MIN_COMPILE_SECONDS` or more to compile are kept there too.  An unreadable or stale
entry is not fatal: JAX warns and compiles again.

A cached compilation still pays the Python tracing that builds the program (about 2 s of
``fit(f4)``'s first call).  So the swarm and the polish are also kept as exported
programs (:mod:`jax.export`, in ``exported/`` beside JAX's entries), keyed by everything
that shapes their trace (this package's source, JAX's version and settings, the backend,
the static arguments and the arguments' shapes and types): a later process deserialises
and calls them without tracing (:func:`program`).  An exported program computes exactly
what the traced one computes (same curves, bit for bit: ``tests/test_compile_cache.py``).
They are small (60-150 KB each) and kept to :data:`EXPORTED_SHARE` of JAX's bound, the
least recently used removed first (:func:`_trim`): every edit of this package and every
JAX upgrade makes new keys, and the old programs would otherwise stay for good.
"""

from __future__ import annotations

import contextlib
import enum
import functools
import gc
import hashlib
import os
import threading
import time
import warnings
from pathlib import Path

import jax

__all__ = [
    "ENV",
    "MAX_BYTES",
    "EXPORTED_SHARE",
    "MIN_COMPILE_SECONDS",
    "default_dir",
    "use_cache",
    "cache_dir",
    "program",
]

#: The environment variable that moves the cache (a folder) or turns it off (``off``).
ENV = "SWARMCURVES_CACHE_DIR"

#: The cache's size bound when this package sets it up: about a thousand programs.
MAX_BYTES = 1 << 30

#: The exported programs take at most this fraction of JAX's cache bound: with
#: :data:`MAX_BYTES`, 128 MiB, a thousand programs or more.
EXPORTED_SHARE = 1 / 8

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
    a small call's programs, e.g. a polygon's swarm)."""
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
        warnings.warn(
            f"swarmcurves_jax: no persistent compilation cache ({exc}); set {ENV} to a "
            "writable folder, or to 'off'",
            RuntimeWarning,
            stacklevel=3,
        )


#: Exported programs loaded or made in this process, by key.
_programs: dict[tuple, object] = {}


def program(jitted, compiler_options: dict, *args, compile_now: bool = False, **static):
    """``functools.partial(jitted, **static)`` for arguments like ``args`` (arrays or
    :class:`jax.ShapeDtypeStruct`), traced and lowered now; ``compile_now``: compiled too,
    so that its first run does not compile (e.g. made in a thread while other work runs).

    With a cache folder, it is the exported program: read from the folder, or exported
    there once (atomically); the call is then ``jax.jit(exported.call, ...)``, whose
    compilation JAX's cache keeps.  On one device, or on a ``mesh`` of this process's
    devices (a mesh over several processes keeps the traced program).  Made with Python's
    cyclic garbage collector held off (:func:`collector_off`).
    """
    with collector_off():
        return _program(jitted, compiler_options, *args, compile_now=compile_now, **static)


_collector = {"holders": 0, "was_on": False}
_collector_lock = threading.Lock()


@contextlib.contextmanager
def collector_off():
    """Python's cyclic garbage collector held off inside, and back as it was after.

    Tracing a program allocates hundreds of thousands of short-lived objects, and CPython
    collects every 700 allocations, now and then walking every object JAX holds: 300
    collections, 0.33 s of a fresh process's first ``fit(f4)`` (cache off), against 17 and
    0.02 s held off.  Reference counting frees the tracer's objects as it goes; the cycles
    it leaves are collected once the collector is back.  Counted, as two threads may make
    programs at once: the last one out turns it back on, if it was on."""
    with _collector_lock:
        if _collector["holders"] == 0:
            _collector["was_on"] = gc.isenabled()
            gc.disable()
        _collector["holders"] += 1
    try:
        yield
    finally:
        with _collector_lock:
            _collector["holders"] -= 1
            if _collector["holders"] == 0 and _collector["was_on"]:
                gc.enable()


def _program(jitted, compiler_options: dict, *args, compile_now: bool = False, **static):
    folder = cache_dir()
    mesh = static.get("mesh")
    if folder is None or (mesh is not None and mesh.is_multi_process):
        _prepare(jitted.trace(*args, **static), compile_now)
        return functools.partial(jitted, **static)
    key = _key(jitted, args, static)
    where = _device(args) if mesh is None else mesh
    call = _programs.get((key, where))
    if call is None:
        from jax import export

        _register_trees()
        path = folder / "exported" / f"{jitted.__name__}-{key}.jaxexport"
        exported = _read(path)
        if exported is None:
            shapes = jax.tree_util.tree_map(
                lambda a: jax.ShapeDtypeStruct(a.shape, a.dtype, sharding=_sharding(a, mesh)),
                args,
            )
            exported = export.export(jitted)(*shapes, **static)
            _write(path, exported.serialize())
        run = functools.wraps(jitted)(lambda *a: exported.call(*a))  # logs name the program
        if mesh is None:
            # One placement for every call: arguments made on the host and a previous
            # call's results (committed to the device) then lower alike, and compile once.
            on = jax.sharding.SingleDeviceSharding(where)
            shardings = dict(in_shardings=on, out_shardings=on)
        else:  # the arguments are placed on the mesh already, as its results are
            shardings = {}
        call = jax.jit(run, compiler_options=compiler_options, **shardings)
        _programs[key, where] = call
    _prepare(call.trace(*args), compile_now)
    return call


def _sharding(a, mesh):
    """How an argument is split over ``mesh`` (None without one, where the call places
    it, or for a host scalar, which every device takes whole)."""
    return None if mesh is None else getattr(a, "sharding", None)


def _prepare(traced, compile_now: bool) -> None:
    """Lower a trace (JAX keeps the lowering for the call), and compile it if asked."""
    lowered = traced.lower()
    if compile_now:
        lowered.compile()


def _key(jitted, args, static) -> str:
    """What shapes the trace: this package's source, JAX (version, backend and the
    settings a trace reads), the program, its static arguments, its arguments' types."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    avals = [_aval(a if isinstance(a, jax.ShapeDtypeStruct) else jax.typeof(a)) for a in leaves]
    mesh = static.get("mesh")
    if mesh is not None:  # how each argument is split over it
        avals = [(*aval, str(_sharding(a, mesh))) for aval, a in zip(avals, leaves, strict=True)]
    settings = [v for v in _trace_settings() if isinstance(v, (bool, int, float, str, enum.Enum))]
    parts = [
        _source_hash(),
        jax.__version__,
        jax.default_backend(),
        repr(settings),
        f"{jitted.__module__}.{jitted.__name__}",
        repr(sorted(static.items())),
        str(tree),
        repr(avals),
    ]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:40]


def _device(args) -> jax.Device:
    """The device the arguments are placed on (JAX's default one if none is)."""
    for a in jax.tree_util.tree_leaves(args):
        sharding = getattr(a, "sharding", None)
        if isinstance(sharding, jax.sharding.SingleDeviceSharding):
            return next(iter(sharding.device_set))
    return jax.devices()[0]


def _aval(a) -> tuple:
    """Shape, type and weakness: what a trace sees of an argument (not its placement)."""
    return tuple(a.shape), str(a.dtype), bool(getattr(a, "weak_type", False))


def _trace_settings():
    from jax._src import config

    return config.trace_context()


@functools.lru_cache(maxsize=1)
def _source_hash() -> str:
    """This package's source: an edited module never reads an older program."""
    digest = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode() + path.read_bytes())
    return digest.hexdigest()


@functools.lru_cache(maxsize=1)
def _register_trees() -> None:
    """The NamedTuples our programs take and return, by name, for serialisation."""
    from jax import export

    from .excursions import Polyline
    from .pso import Box, PSOInfo, PSOParams, PSOState
    from .span_basis import SpanBasis

    for cls in (PSOState, PSOParams, PSOInfo, Box, SpanBasis, Polyline):
        export.register_namedtuple_serialization(
            cls, serialized_name=f"swarmcurves_jax.{cls.__name__}"
        )


def _read(path: Path):
    """The exported program at ``path``, or None (absent or unreadable: made again); a
    program read is marked used (its time), so that :func:`_trim` keeps it longest."""
    from jax import export

    try:
        data = path.read_bytes()
        with contextlib.suppress(OSError):  # a folder this process may not write
            os.utime(path)
        return export.deserialize(bytearray(data))
    except FileNotFoundError:
        return None
    except Exception as exc:  # damaged (a disk filled while writing), unreadable: made again
        warnings.warn(
            f"swarmcurves_jax: unreadable exported program {path} ({type(exc).__name__}: "
            f"{exc}); exporting it again",
            RuntimeWarning,
            stacklevel=2,
        )
        return None


def _write(path: Path, data: bytes) -> None:
    """Write ``data`` atomically (another process reads it whole or not at all), then
    :func:`_trim` the folder.  A folder that cannot take it (full, read-only) costs a
    warning, not the fit: the program runs all the same, a later process exports it again."""
    temporary = path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        temporary.write_bytes(data)
        os.replace(temporary, path)
    except OSError as exc:
        warnings.warn(
            f"swarmcurves_jax: could not keep the exported program {path} ({exc}); a later "
            "process will trace it again",
            RuntimeWarning,
            stacklevel=3,
        )
        _remove(temporary)
        return
    _trim(path.parent, keep=path.name)


def _remove(path) -> None:
    """Remove ``path`` if this process can; gone already (another process) is fine."""
    with contextlib.suppress(OSError):
        os.unlink(path)


#: A temporary file this old is a killed process's, never to be completed.
STALE_SECONDS = 3600


def _trim(folder: Path, keep: str) -> None:
    """Remove the least recently used exported programs (by their time: written or last
    read) beyond :data:`EXPORTED_SHARE` of JAX's cache bound (none if JAX's is
    unbounded), never ``keep``, and the temporary files of writes a killed process left
    (an hour old).  Another process may be trimming too: a file already gone is skipped."""
    bound = jax.config.jax_compilation_cache_max_size
    programs, total, now = [], 0, time.time()
    for entry in os.scandir(folder):
        with contextlib.suppress(OSError):  # gone meanwhile
            stat = entry.stat()
            if entry.name.startswith(".") and now - stat.st_mtime > STALE_SECONDS:
                _remove(entry.path)
            elif entry.name.endswith(".jaxexport"):
                total += stat.st_size
                if entry.name != keep:
                    programs.append((stat.st_mtime, stat.st_size, entry.path))
    if bound < 0:
        return
    for _, size, path in sorted(programs):
        if total <= bound * EXPORTED_SHARE:
            break
        _remove(path)
        total -= size
