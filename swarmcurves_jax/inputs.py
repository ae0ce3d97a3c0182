"""The command line's inputs: point files, multi-curve files, folders, globs and the
built-in datasets, each a :class:`Source` (label, closed, reader); errors name the file and
line.

A batch's curves are listed first (:func:`list_sources`: labels and readers, no points) and
read one at a time as the run needs them, so a corpus is never held whole.
"""

from __future__ import annotations

import fnmatch
import glob
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np

from .config import ConfigError

__all__ = ["Source", "read_points", "list_sources", "is_batch"]


class Source(NamedTuple):
    """One curve of an input: its label, whether it is closed, and ``read()`` for its
    points (read when called, checked; a bad file raises :class:`ConfigError`)."""

    label: str
    closed: bool
    read: Callable[[], np.ndarray]


def read_points(path: Path) -> np.ndarray:
    """Points from a text (.csv/.txt/.xyz, optional header) or .npy file; errors name the line."""
    if not path.is_file():
        raise ConfigError(f"input: no such file '{path}'")
    if path.suffix == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except Exception as exc:
            raise ConfigError(f"input: cannot read '{path}' as .npy: {exc}") from None
        return _checked_array(arr, f"{path}")
    rows, width = [], None
    try:
        with open(path, encoding="utf-8") as fh:
            for lineno, line in enumerate(fh, 1):
                text = line.strip()
                if not text or text.startswith("#"):
                    continue
                fields = text.replace(",", " ").split()
                try:
                    values = [float(f) for f in fields]
                except ValueError:
                    if not rows and width is None:  # a header line
                        width = -1
                        continue
                    raise ConfigError(f"input: {path}:{lineno}: not a number in {text!r}") from None
                if width not in (None, -1) and len(values) != width:
                    raise ConfigError(
                        f"input: {path}:{lineno}: {len(values)} columns, expected "
                        f"{width} like the rows before"
                    )
                if len(values) not in (2, 3):
                    raise ConfigError(
                        f"input: {path}:{lineno}: {len(values)} columns, expected 2 or 3 (x y [z])"
                    )
                if not np.all(np.isfinite(values)):
                    raise ConfigError(f"input: {path}:{lineno}: NaN or inf in {text!r}")
                width = len(values)
                rows.append(values)
    except UnicodeDecodeError:
        raise ConfigError(f"input: '{path}' is not a text file") from None
    if not rows:
        raise ConfigError(f"input: '{path}' holds no points")
    return np.array(rows)


POINT_SUFFIXES = (".csv", ".txt", ".xyz", ".npy")


def is_batch(name: str) -> bool:
    """Whether ``input`` names many curves: a folder, a glob, an .npz, outline:PATTERN."""
    if name.startswith("outline:"):
        return any(c in name for c in "*?[")
    return Path(name).is_dir() or name.endswith(".npz") or any(c in name for c in "*?[")


def list_sources(cfg) -> list[Source]:
    """Every curve the config's ``input`` names, as a :class:`Source` (nothing read yet but
    a multi-curve file's index).

    Files of a folder or glob are taken in sorted order; their ``closed`` is the config's
    (default open), an outline's its own.  Labels are file stems (names, if stems clash),
    an .npz's array names, or outline names."""
    from .datasets import BUILTIN_NAMES, builtin, outlines_path, read_outlines

    name = cfg["input"]
    closed = bool(cfg["closed"])
    if name in BUILTIN_NAMES:
        pts, own = builtin(name)
        return [Source(name, own, lambda: pts)]
    if name.startswith("outline:"):
        pattern = name.split(":", 1)[1]
        try:
            outlines = read_outlines(cfg["data_dir"])
        except FileNotFoundError as err:
            raise ConfigError(str(err)) from None
        chosen = [c for c in outlines if fnmatch.fnmatchcase(c, pattern)]
        if not chosen:
            raise ConfigError(
                f"input: no outline '{pattern}' in {outlines_path(cfg['data_dir'])}; "
                f"have {', '.join(outlines)}"
            )
        label = (lambda c: c) if is_batch(name) else (lambda c: name)
        return [
            Source(label(c), outlines[c]["closed"], lambda c=c: outlines[c]["points"])
            for c in chosen
        ]
    if name.endswith(".npz"):
        return _npz_sources(Path(name), closed)
    if not is_batch(name):
        return [Source(name, closed, lambda: read_points(Path(name)))]
    if Path(name).is_dir():
        files = sorted(f for f in Path(name).iterdir() if f.suffix in POINT_SUFFIXES)
        where = f"folder '{name}' holds no point files ({', '.join(POINT_SUFFIXES)})"
    else:
        files = sorted(Path(f) for f in glob.glob(name) if Path(f).is_file())
        where = f"no files match '{name}'"
    if not files:
        raise ConfigError(f"input: {where}")
    stems = [f.stem for f in files]
    labels = stems if len(set(stems)) == len(stems) else [f.name for f in files]
    return [Source(label, closed, lambda f=f: read_points(f)) for f, label in zip(files, labels)]


def _npz_sources(path: Path, closed: bool) -> list[Source]:
    """A multi-curve .npz's arrays as sources, read from the open file one at a time."""
    npz = _open_npz(path)

    def read(key):
        try:
            arr = np.asarray(npz[key])
        except Exception as exc:
            raise ConfigError(f"input: cannot read '{path}['{key}']': {exc}") from None
        return _checked_array(arr, f"{path}['{key}']")

    return [Source(key, closed, lambda key=key: read(key)) for key in npz.files]


def _open_npz(path: Path):
    if not path.is_file():
        raise ConfigError(f"input: no such file '{path}'")
    try:
        npz = np.load(path, allow_pickle=False)
    except Exception as exc:
        raise ConfigError(f"input: cannot read '{path}' as .npz: {exc}") from None
    if not npz.files:
        raise ConfigError(f"input: '{path}' holds no arrays")
    return npz


def _checked_array(arr: np.ndarray, where: str) -> np.ndarray:
    """A loaded array as float points, or a ConfigError naming ``where`` and the fault."""
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or not np.issubdtype(arr.dtype, np.number):
        raise ConfigError(
            f"input: {where}: expected a numeric (N, 2) or (N, 3) array, got "
            f"{arr.dtype} {arr.shape}"
        )
    bad = np.flatnonzero(~np.all(np.isfinite(arr), axis=1))
    if len(bad):
        raise ConfigError(f"input: {where}: row {bad[0]} holds NaN or inf")
    return arr.astype(float)
