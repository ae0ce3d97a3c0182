"""Command line: ``python -m swarmcurves_jax.run [CONFIG.yaml] [overrides]``.

Runs one fitting job and prints its table of solutions.  With no config it fits the
built-in example (the paper's f4 curve, cubic, 4-10 control points).  With an output
folder (``out:`` or ``--out``) it writes ``solutions.json`` there, refusing to write over
an earlier run unless ``--force``.  Bad configs stop with exit code 2 and one line that
names the key.  This is the only module that reads or writes files.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

DEFAULTS = {
    "input": "f4",
    "cps": "4-10",
    "degrees": 3,
    "closed": None,
    "rational": False,
    "fix_ends": True,
    "init": "lsq",
    "particles": 64,
    "iterations": 2000,
    "tol": None,
    "seed": 0,
    "out": None,
}

KEY_HELP = {
    "input": "a point file (.csv/.txt/.xyz text, or .npy; one point per row) or a built-in "
             "dataset: f1..f5, random_open, random_closed",
    "cps": "control-point counts: an int, a list, or a range 'A-B'",
    "degrees": "degrees: an int, a list, or a range 'A-B'",
    "closed": "true for a closed curve (default: the dataset's own, else false)",
    "rational": "optimise NURBS weights too",
    "fix_ends": "pin an open curve's end control points to the first and last data points",
    "init": "'lsq' (one particle seeded by least squares) or 'uniform'",
    "particles": "particles per swarm",
    "iterations": "iteration limit",
    "tol": "stop once every swarm's mean distance (normalised frame) is <= tol",
    "seed": "random seed",
    "out": "output folder for solutions.json (nothing is written without one)",
}


class ConfigError(ValueError):
    """A bad config key or value; the CLI prints it and exits with code 2."""


def parse_counts(value, key: str) -> list[int]:
    if isinstance(value, bool):
        raise ConfigError(f"{key}: expected an int, a list of ints or a range 'A-B', got {value!r}")
    if isinstance(value, int):
        return [value]
    if isinstance(value, str):
        parts = [p.strip() for p in value.split(",") if p.strip()]
        out = []
        try:
            for p in parts:
                if "-" in p:
                    a, b = (int(x) for x in p.split("-", 1))
                    out.extend(range(a, b + 1))
                else:
                    out.append(int(p))
        except ValueError:
            raise ConfigError(f"{key}: expected an int, a list or a range 'A-B', got {value!r}") from None
        return out
    if isinstance(value, list) and all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        return list(value)
    raise ConfigError(f"{key}: expected an int, a list of ints or a range 'A-B', got {value!r}")


def check_config(raw: dict) -> dict:
    """Merge ``raw`` over the defaults; unknown keys and wrong types raise ConfigError."""
    if not isinstance(raw, dict):
        raise ConfigError(f"config: expected a mapping of keys to values, got {type(raw).__name__}")
    for key in raw:
        if key not in DEFAULTS:
            near = difflib.get_close_matches(str(key), DEFAULTS, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            raise ConfigError(f"unknown config key '{key}'{hint}; known keys: {', '.join(DEFAULTS)}")
    cfg = {**DEFAULTS, **raw}
    cfg["cps"] = parse_counts(cfg["cps"], "cps")
    cfg["degrees"] = parse_counts(cfg["degrees"], "degrees")
    for key in ("rational", "fix_ends"):
        if not isinstance(cfg[key], bool):
            raise ConfigError(f"{key}: expected true or false, got {cfg[key]!r}")
    if cfg["closed"] is not None and not isinstance(cfg["closed"], bool):
        raise ConfigError(f"closed: expected true or false, got {cfg['closed']!r}")
    for key in ("particles", "iterations", "seed"):
        v = cfg[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < (0 if key == "seed" else 1):
            raise ConfigError(f"{key}: expected an integer >= {0 if key == 'seed' else 1}, got {v!r}")
    if cfg["tol"] is not None and (isinstance(cfg["tol"], bool) or not isinstance(cfg["tol"], (int, float))
                                   or cfg["tol"] < 0):
        raise ConfigError(f"tol: expected a number >= 0 or null, got {cfg['tol']!r}")
    if cfg["init"] not in ("lsq", "uniform"):
        raise ConfigError(f"init: expected 'lsq' or 'uniform', got {cfg['init']!r}")
    if not isinstance(cfg["input"], str):
        raise ConfigError(f"input: expected a file path or a dataset name, got {cfg['input']!r}")
    return cfg


def read_points(path: Path) -> np.ndarray:
    """Points from a text (.csv/.txt/.xyz, optional header) or .npy file."""
    if not path.is_file():
        raise ConfigError(f"input: no such file '{path}'")
    if path.suffix == ".npy":
        try:
            return np.load(path, allow_pickle=False)
        except Exception as exc:
            raise ConfigError(f"input: cannot read '{path}' as .npy: {exc}") from None
    rows, width = [], None
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
                    continue
                raise ConfigError(f"input: {path}:{lineno}: not a number in {text!r}") from None
            if width is not None and len(values) != width:
                raise ConfigError(
                    f"input: {path}:{lineno}: {len(values)} columns, expected {width} like the rows before"
                )
            if not np.all(np.isfinite(values)):
                raise ConfigError(f"input: {path}:{lineno}: NaN or inf in {text!r}")
            width = len(values)
            rows.append(values)
    if not rows:
        raise ConfigError(f"input: '{path}' holds no points")
    return np.array(rows)


def _write_atomic(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m swarmcurves_jax.run",
        description="Fit B-spline / NURBS curves to ordered points with particle swarms.",
        epilog="config keys:\n" + "\n".join(f"  {k:11s} {v}" for k, v in KEY_HELP.items()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("config", nargs="?", help="YAML config file (default: the built-in example)")
    ap.add_argument("--input", help=KEY_HELP["input"])
    ap.add_argument("--cps", help=KEY_HELP["cps"])
    ap.add_argument("--degrees", help=KEY_HELP["degrees"])
    ap.add_argument("--iterations", type=int, help=KEY_HELP["iterations"])
    ap.add_argument("--particles", type=int, help=KEY_HELP["particles"])
    ap.add_argument("--seed", type=int, help=KEY_HELP["seed"])
    ap.add_argument("--out", help=KEY_HELP["out"])
    ap.add_argument("--force", action="store_true", help="write over an earlier run's files")
    return ap


def load_config(args) -> dict:
    raw = {}
    if args.config:
        import yaml

        path = Path(args.config)
        if not path.is_file():
            raise ConfigError(f"config: no such file '{path}'")
        try:
            raw = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"config: '{path}' is not valid YAML: {exc}".splitlines()[0]) from None
    for key in ("input", "cps", "degrees", "iterations", "particles", "seed", "out"):
        value = getattr(args, key)
        if value is not None:
            raw[key] = value
    return check_config(raw)


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(args)
        from .datasets import BUILTIN_NAMES, builtin

        if cfg["input"] in BUILTIN_NAMES:
            points, closed = builtin(cfg["input"])
        else:
            points, closed = read_points(Path(cfg["input"])), False
        if cfg["closed"] is not None:
            closed = cfg["closed"]
        out = Path(cfg["out"]) if cfg["out"] else None
        if out is not None and (out / "solutions.json").exists() and not args.force:
            raise ConfigError(f"out: '{out}' already holds solutions.json; pass --force to replace it")
        from . import fit

        result = fit(points, cps=cfg["cps"], degrees=cfg["degrees"], closed=closed,
                     rational=cfg["rational"], fix_ends=cfg["fix_ends"], init=cfg["init"],
                     particles=cfg["particles"], iterations=cfg["iterations"], tol=cfg["tol"],
                     seed=cfg["seed"])
    except ValueError as exc:  # ConfigError and fit's own input errors
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{len(result.points)} points from {cfg['input']}, {'closed' if closed else 'open'}; "
          f"stopped on {result.stop_reason} after {result.wall_time:.1f} s")
    print(result.table())
    best = result.best
    print(f"best: degree {best.degree}, {best.n_ctrl} control points, mean error {best.error:.3e} "
          f"({best.error_pct_diag:.4f} % of the bounding-box diagonal)")
    if out is not None:
        from . import __version__

        out.mkdir(parents=True, exist_ok=True)
        doc = {"swarmcurves_jax": __version__, "config": cfg, "seed": result.seed,
               "solutions": [c.to_dict() for c in result.solutions]}
        _write_atomic(out / "solutions.json", json.dumps(doc, indent=1))
        print(f"wrote {out / 'solutions.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
