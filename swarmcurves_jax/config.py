"""The command line's config: its keys, their defaults and checks, and the fit options
they give.

Every key a YAML config may hold is in :data:`SCHEMA` with its default, its kind and its
help; the defaults of the fit's own options come from
:class:`~swarmcurves_jax.options.FitOptions`.  A bad key or value raises
:class:`ConfigError` naming the key.
"""

from __future__ import annotations

import dataclasses
import difflib
from pathlib import Path

import numpy as np

from .options import FitOptions
from .pso import PSOParams, default_params

__all__ = ["SCHEMA", "ConfigError", "parse_counts", "check_config", "load_config", "fit_options"]

#: The fit's defaults, which the config's keys of the same names share.
DEFAULTS = FitOptions()
PSO_DEFAULTS = default_params()


FIGURES = ("best", "sparsest", "all", "error_vs_cps")

EXPORT_FILES = {
    "json": "solutions.json",
    "npz": "solutions.npz",
    "dxf": "curves.dxf",
    "svg": "curves.svg",
}

EXPORTS = tuple(EXPORT_FILES)

# key: (default, kind, help).  Kinds are checked by ``check_config``.
SCHEMA = {
    "input": (
        "f4",
        "str",
        "point file (.csv/.txt/.xyz text with or without a header, or .npy; "
        "one point per row, 2 or 3 columns) or a built-in dataset: f1..f5, random_open, "
        "random_closed, or outline:NAME (a curve of the benchmark outlines in data_dir). "
        "Many curves, fitted as one batch: a folder of point files, a glob ('scans/*.csv'), "
        "an .npz with one (N, D) array per curve, or outline:PATTERN ('outline:*')",
    ),
    "data_dir": (
        None,
        "str?",
        "folder holding outlines/outlines.npz (default: $SWARMCURVES_DATA, else ../shared/data "
        "from the working folder or beside the repository)",
    ),
    "closed": (None, "bool?", "closed curve (default: the dataset's own; false for files)"),
    "cps": (
        f"{min(DEFAULTS.cps)}-{max(DEFAULTS.cps)}",
        "counts",
        "control-point counts: an int, a list, or a range 'A-B'",
    ),
    "degrees": (
        DEFAULTS.degrees,
        "counts",
        "degrees: an int, a list, or a range 'A-B' (1 = polygon)",
    ),
    "rational": (DEFAULTS.rational, "bool", "optimise NURBS weights too"),
    "fix_ends": (
        DEFAULTS.fix_ends,
        "bool",
        "pin an open curve's end control points to the first and last point",
    ),
    "init": (
        DEFAULTS.init,
        ("lsq", "uniform"),
        "'lsq': one particle seeded by least squares; 'uniform'",
    ),
    "refine": (
        "lm" if DEFAULTS.refine is True else DEFAULTS.refine or "none",
        ("lm", "lbfgs", "none"),
        "local polish after the swarm: 'lm' (Levenberg-Marquardt), 'lbfgs' (optax), 'none'",
    ),
    "free_knots": (
        DEFAULTS.free_knots,
        "bool",
        "let the swarm and the polish move the interior knots",
    ),
    "particles": (DEFAULTS.particles, "int>=1", "particles per swarm"),
    "iterations": (DEFAULTS.iterations, "int>=1", "iteration limit (the paper: 2000)"),
    "tol": (
        DEFAULTS.tol,
        "float>=0?",
        "stop once every swarm's fitness (mean distance plus excursions, normalised frame) <= tol",
    ),
    "inertia": (PSO_DEFAULTS.inertia, "float", "PSO inertia (the paper's psi)"),
    "cognitive": (PSO_DEFAULTS.cognitive, "float", "PSO weight of the personal best (phi_l)"),
    "social": (PSO_DEFAULTS.social, "float", "PSO weight of the swarm's best (phi_g)"),
    "v_max": (PSO_DEFAULTS.v_max, "float>0", "velocity clamp per coordinate (normalised frame)"),
    "patience": (
        int(PSO_DEFAULTS.patience),
        "int>=1?",
        "restart a swarm after this many steps without progress (null: never)",
    ),
    "search_every": (
        DEFAULTS.search_every,
        "int>=1",
        "search each point's nearest curve sample every this many iterations (8: faster, "
        "finds exact curves less often; docs/method.md)",
    ),
    "seed": (0, "int>=0", "random seed"),
    "select_pct_diag": (
        1.0,
        "float>0",
        "tolerance for 'sparsest': largest deviation between curve and data (both ways) "
        "as % of the bounding-box diagonal",
    ),
    "select_tolerance": (
        None,
        "float>0?",
        "tolerance for 'sparsest' in the points' units instead (largest deviation)",
    ),
    "batch_size": (
        None,
        "int>=1?",
        "a batch's curves per program call (default: 32 per device); results do not depend "
        "on it",
    ),
    "scheduler": (
        None,
        "str?",
        "a Dask scheduler's address ('tcp://host:8786'): fit a batch on its workers "
        "(needs the dask extra; docs/many_curves.md)",
    ),
    "out": (None, "str?", "output folder (nothing is written without one)"),
    "cache_dir": (
        None,
        "str?",
        "folder keeping compiled programs across runs ('off': keep none; default: "
        "$SWARMCURVES_CACHE_DIR, else the per-user cache folder; docs/performance.md)",
    ),
    "figures": (["best", "error_vs_cps"], FIGURES, "PNG figures to write: " + ", ".join(FIGURES)),
    "exports": (list(EXPORTS), EXPORTS, "files to write: " + ", ".join(EXPORTS)),
}


class ConfigError(ValueError):
    """A bad config key, value or input file; the CLI prints it and exits with code 2."""


def parse_counts(value, key: str) -> list[int]:
    """An int, a list of ints, or a string like '4-10' or '2,3'."""
    bad = ConfigError(f"{key}: expected an int, a list of ints or a range 'A-B', got {value!r}")
    if isinstance(value, bool):
        raise bad
    if isinstance(value, int):
        return [value]
    if (
        isinstance(value, list)
        and value
        and all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    ):
        return list(value)
    if isinstance(value, str):
        out = []
        try:
            for part in (p.strip() for p in value.split(",") if p.strip()):
                a, _, b = part.partition("-")
                out.extend(range(int(a), int(b) + 1) if b else [int(a)])
        except ValueError:
            raise bad from None
        if out:
            return out
    raise bad


def _check_value(key, value, kind):
    optional = isinstance(kind, str) and kind.endswith("?")
    if optional and value is None:
        return None
    kind = kind[:-1] if optional else kind
    allowed = " or null" if optional else ""
    if isinstance(kind, tuple):  # a choice, or a list of choices
        if key in ("figures", "exports"):
            items = [value] if isinstance(value, str) else value
            if isinstance(value, bool) and not value:
                return []
            if not isinstance(items, list) or any(v not in kind for v in items):
                raise ConfigError(f"{key}: expected a list from {', '.join(kind)}, got {value!r}")
            return list(dict.fromkeys(items))
        if value not in kind:
            raise ConfigError(f"{key}: expected one of {', '.join(kind)}, got {value!r}")
        return value
    if kind == "counts":
        return parse_counts(value, key)
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false{allowed}, got {value!r}")
        return value
    if kind == "str":
        if not isinstance(value, str) or not value:
            raise ConfigError(f"{key}: expected a non-empty string{allowed}, got {value!r}")
        return value
    if kind.startswith("int"):
        low = int(kind.split(">=")[1])
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ConfigError(f"{key}: expected an integer >= {low}{allowed}, got {value!r}")
        return value
    # floats
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value):
        raise ConfigError(f"{key}: expected a finite number{allowed}, got {value!r}")
    if kind == "float>0" and value <= 0:
        raise ConfigError(f"{key}: expected a number > 0{allowed}, got {value!r}")
    if kind == "float>=0" and value < 0:
        raise ConfigError(f"{key}: expected a number >= 0{allowed}, got {value!r}")
    return float(value)


def check_config(raw) -> dict:
    """Merge ``raw`` over the defaults; unknown keys and bad values raise ConfigError."""
    if not isinstance(raw, dict):
        raise ConfigError(f"config: expected a mapping of keys to values, got {type(raw).__name__}")
    for key in raw:
        if key not in SCHEMA:
            near = difflib.get_close_matches(str(key), SCHEMA, n=1)
            hint = f" (did you mean '{near[0]}'?)" if near else ""
            raise ConfigError(f"unknown config key '{key}'{hint}; known keys: {', '.join(SCHEMA)}")
    return {
        key: _check_value(key, raw[key] if key in raw else default, kind)
        for key, (default, kind, _) in SCHEMA.items()
    }


def load_config(args) -> dict:
    raw = {}
    if args.config:
        import yaml

        path = Path(args.config)
        if not path.is_file():
            raise ConfigError(f"config: no such file '{path}'")
        try:
            raw = yaml.safe_load(path.read_text(encoding="utf-8"))
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ConfigError(f"config: '{path}' is not valid YAML: {first}") from None
        raw = {} if raw is None else raw
        if not isinstance(raw, dict):
            raise ConfigError(
                f"config: '{path}' must hold a mapping of keys, got {type(raw).__name__}"
            )
    for key in (
        "input",
        "cps",
        "degrees",
        "closed",
        "rational",
        "iterations",
        "particles",
        "tol",
        "seed",
        "batch_size",
        "scheduler",
        "out",
    ):
        value = getattr(args, key)
        if value is not None:
            raw[key] = value
    return check_config(raw)


def fit_options(cfg, progress: bool) -> dict:
    """The keyword arguments of ``fit`` / ``fit_many`` that the config sets: its keys named
    like :class:`~swarmcurves_jax.options.FitOptions` fields as they are, ``refine: none``
    as False, the PSO keys as ``params``, and ``seed``."""
    fields = {f.name for f in dataclasses.fields(FitOptions)}
    params = PSOParams(
        cfg["inertia"],
        cfg["cognitive"],
        cfg["social"],
        cfg["v_max"],
        float("inf") if cfg["patience"] is None else float(cfg["patience"]),
    )
    options = {key: value for key, value in cfg.items() if key in fields}
    refine = False if cfg["refine"] == "none" else cfg["refine"]
    return dict(options, refine=refine, params=params, progress=progress, seed=cfg["seed"])
