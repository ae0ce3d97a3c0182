"""Command line: ``python -m swarmcurves_jax.run [CONFIG.yaml] [overrides]``.

Runs one fitting job: reads points (a file or a built-in dataset), fits every requested
(degree, control-point count), prints the table of solutions with the best and the
sparsest-within-tolerance marked, and writes solutions, figures and CAD exports into the
output folder.  An ``input`` that names many curves (a folder, a glob, an ``.npz`` of
arrays, or ``outline:*``) is fitted as one batch (:func:`swarmcurves_jax.fit_many`): one
sub-folder of results per curve and a ``summary.csv``.  With no config it fits the
built-in example (the paper's f4 curve) and only prints.  Bad configs and bad files stop
the run before any work with exit code 2 and one line that names the key.  Ctrl-C (or
SIGTERM) stops the swarm cleanly and still writes the best solutions found so far (in a
batch: the curves finished by then); every file is written atomically.
"""

from __future__ import annotations

import argparse
import csv
import difflib
import fnmatch
import glob
import re
import signal
import sys
import time
from pathlib import Path

import numpy as np

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
    "cps": ("4-10", "counts", "control-point counts: an int, a list, or a range 'A-B'"),
    "degrees": (3, "counts", "degrees: an int, a list, or a range 'A-B' (1 = polygon)"),
    "rational": (False, "bool", "optimise NURBS weights too"),
    "fix_ends": (
        True,
        "bool",
        "pin an open curve's end control points to the first and last point",
    ),
    "init": ("lsq", ("lsq", "uniform"), "'lsq': one particle seeded by least squares; 'uniform'"),
    "refine": (
        "lm",
        ("lm", "lbfgs", "none"),
        "local polish after the swarm: 'lm' (Levenberg-Marquardt), 'lbfgs' (optax), 'none'",
    ),
    "free_knots": (False, "bool", "let the swarm and the polish move the interior knots"),
    "particles": (64, "int>=1", "particles per swarm"),
    "iterations": (2000, "int>=1", "iteration limit (the paper: 2000)"),
    "tol": (
        None,
        "float>=0?",
        "stop once every swarm's fitness (mean distance plus excursions, normalised frame) "
        "<= tol",
    ),
    "inertia": (0.7298, "float", "PSO inertia (the paper's psi)"),
    "cognitive": (1.49618, "float", "PSO weight of the personal best (phi_l)"),
    "social": (1.49618, "float", "PSO weight of the swarm's best (phi_g)"),
    "v_max": (0.1, "float>0", "velocity clamp per coordinate (normalised frame)"),
    "patience": (
        100,
        "int>=1?",
        "restart a swarm after this many steps without progress (null: never)",
    ),
    "search_every": (
        1,
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
    "out": (None, "str?", "output folder (nothing is written without one)"),
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


def load_input(cfg) -> tuple[np.ndarray, bool, str]:
    """``(points, closed, label)`` for a config whose ``input`` is one curve."""
    (one,) = load_inputs(cfg)
    return one


def is_batch(name: str) -> bool:
    """Whether ``input`` names many curves: a folder, a glob, an .npz, outline:PATTERN."""
    if name.startswith("outline:"):
        return any(c in name for c in "*?[")
    return Path(name).is_dir() or name.endswith(".npz") or any(c in name for c in "*?[")


def load_inputs(cfg) -> list[tuple[np.ndarray, bool, str]]:
    """``(points, closed, label)`` of every curve the config's ``input`` names.

    Files of a folder or glob are read in sorted order; their ``closed`` is the config's
    (default open), an outline's its own.  Labels are file stems (names, if stems clash),
    an .npz's array names, or outline names."""
    from .datasets import BUILTIN_NAMES, builtin, outlines_path, read_outlines

    name = cfg["input"]
    closed = bool(cfg["closed"])
    if name in BUILTIN_NAMES:
        pts, own = builtin(name)
        return [(pts, own, name)]
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
        batch = is_batch(name)
        return [
            (outlines[c]["points"], outlines[c]["closed"], c if batch else name) for c in chosen
        ]
    if name.endswith(".npz"):
        return [(pts, closed, label) for label, pts in read_point_arrays(Path(name))]
    if not is_batch(name):
        return [(read_points(Path(name)), closed, name)]
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
    return [(read_points(f), closed, label) for f, label in zip(files, labels)]


def read_point_arrays(path: Path) -> list[tuple[str, np.ndarray]]:
    """``(name, points)`` of every array of a multi-curve .npz, in the file's order."""
    if not path.is_file():
        raise ConfigError(f"input: no such file '{path}'")
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = [(key, np.asarray(npz[key])) for key in npz.files]
    except Exception as exc:
        raise ConfigError(f"input: cannot read '{path}' as .npz: {exc}") from None
    if not arrays:
        raise ConfigError(f"input: '{path}' holds no arrays")
    return [(key, _checked_array(arr, f"{path}['{key}']")) for key, arr in arrays]


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


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="python -m swarmcurves_jax.run",
        description="Fit B-spline / NURBS curves to ordered points with particle swarms. "
        "A YAML config holds any of the keys below; command-line options override it.",
        epilog="config keys (YAML):\n"
        + "\n".join(f"  {k:15s} {h} [default: {d!r}]" for k, (d, _, h) in SCHEMA.items())
        + "\n\nexit codes: 0 done (also after Ctrl-C, with the best so far), 2 bad config or input",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("config", nargs="?", help="YAML config file (default: the built-in example)")
    ap.add_argument("--input", help="point file or dataset (overrides 'input')")
    ap.add_argument("--cps", help="e.g. 4-12 or 5,8,11")
    ap.add_argument("--degrees", help="e.g. 2,3 or 1-3")
    ap.add_argument("--closed", action=argparse.BooleanOptionalAction, default=None)
    ap.add_argument("--rational", action=argparse.BooleanOptionalAction, default=None)
    ap.add_argument("--iterations", type=int)
    ap.add_argument("--particles", type=int)
    ap.add_argument("--tol", type=float)
    ap.add_argument("--seed", type=int)
    ap.add_argument("--out", help="output folder")
    ap.add_argument("--force", action="store_true", help="replace an earlier run's files in --out")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


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
        "out",
    ):
        value = getattr(args, key)
        if value is not None:
            raw[key] = value
    return check_config(raw)


def planned_files(cfg, pairs) -> list[str]:
    """Every file the run may write, to refuse a clash before any work starts."""
    files = [EXPORT_FILES[e] for e in cfg["exports"]]
    for fig in cfg["figures"]:
        if fig == "all":
            files += [f"solution_d{k}_n{n}.png" for k, n in pairs]
        else:
            files.append(f"{fig}.png")
    return files


def _sparsest(cfg, result):
    """The config's 'sparsest': by ``select_tolerance`` (points' units) if given, else by
    ``select_pct_diag``."""
    if cfg["select_tolerance"] is not None:
        return result.sparsest(cfg["select_tolerance"])
    return result.sparsest(pct_diag=cfg["select_pct_diag"])


def _tolerance_text(cfg) -> str:
    if cfg["select_tolerance"] is not None:
        return f"{cfg['select_tolerance']} (points' units)"
    return f"{cfg['select_pct_diag']} % of the diagonal"


def format_table(result, sparsest) -> str:
    lines = str(result.table()).splitlines()
    marks = [""] + [
        "  <- best" * (c is result.best) + "  <- sparsest within tolerance" * (c is sparsest)
        for c in result.solutions
    ]
    return "\n".join(line + mark for line, mark in zip(lines, marks))


def write_outputs(cfg, result, points, out: Path) -> list[Path]:
    from . import __version__
    from .export import write_dxf, write_json, write_npz, write_svg

    import jax

    out.mkdir(parents=True, exist_ok=True)
    curves = result.solutions
    writers = {
        "json": lambda path: write_json(
            path,
            curves,
            swarmcurves_jax=__version__,
            jax=jax.__version__,
            config=cfg,
            seed=result.seed,
            stop_reason=result.stop_reason,
            wall_time=result.wall_time,
            num_points=len(points),
        ),
        "npz": lambda path: write_npz(path, curves, points),
        "dxf": lambda path: write_dxf(path, curves, points),
        "svg": lambda path: write_svg(path, curves, points),
    }
    written = []
    for name in cfg["exports"]:
        if name == "svg" and points.shape[1] != 2:
            print("note: no SVG for 3D points (SVG is 2D)")
            continue
        writers[name](out / EXPORT_FILES[name])
        written.append(out / EXPORT_FILES[name])
    if cfg["figures"]:
        written += _write_figures(cfg, result, points, out)
    return written


def _write_figures(cfg, result, points, out: Path) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .export import atomic_write
    from .plotting import plot_error_vs_cps, plot_solution

    def save(fig, name):
        with atomic_write(out / name, "wb") as fh:
            fig.savefig(fh, format="png", dpi=120)
        plt.close(fig)
        return out / name

    written = []
    chosen = {"best": result.best, "sparsest": _sparsest(cfg, result)}
    for fig_name in cfg["figures"]:
        if fig_name in chosen and chosen[fig_name] is not None:
            written.append(save(plot_solution(chosen[fig_name], points), f"{fig_name}.png"))
        elif fig_name == "all":
            for c in result.solutions:
                written.append(
                    save(plot_solution(c, points), f"solution_d{c.degree}_n{c.n_ctrl}.png")
                )
        elif fig_name == "error_vs_cps":
            fig = plt.figure()
            plot_error_vs_cps(result, ax=fig.add_subplot())
            written.append(save(fig, "error_vs_cps.png"))
    return written


def _sigterm_to_interrupt(signum, frame):
    raise KeyboardInterrupt


def fit_options(cfg, progress: bool) -> dict:
    """The keyword arguments of ``fit`` / ``fit_many`` that the config sets."""
    from . import PSOParams

    params = PSOParams(
        cfg["inertia"],
        cfg["cognitive"],
        cfg["social"],
        cfg["v_max"],
        float("inf") if cfg["patience"] is None else float(cfg["patience"]),
    )
    return dict(
        cps=cfg["cps"],
        degrees=cfg["degrees"],
        rational=cfg["rational"],
        fix_ends=cfg["fix_ends"],
        init=cfg["init"],
        refine=False if cfg["refine"] == "none" else cfg["refine"],
        free_knots=cfg["free_knots"],
        particles=cfg["particles"],
        iterations=cfg["iterations"],
        search_every=cfg["search_every"],
        tol=cfg["tol"],
        seed=cfg["seed"],
        params=params,
        progress=progress,
    )


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = load_config(args)
        curves = load_inputs(cfg)
        if cfg["closed"] is not None:
            curves = [(pts, cfg["closed"], label) for pts, _, label in curves]
        out = Path(cfg["out"]) if cfg["out"] else None
        pairs = [(k, n) for k in sorted(cfg["degrees"]) for n in sorted(cfg["cps"])]
        batch = is_batch(cfg["input"])
        if out is not None and not args.force:
            planned = planned_files(cfg, pairs)
            if batch:
                planned = [SUMMARY] + [f"{slug(c[2])}/{f}" for c in curves for f in planned]
            clash = [f for f in planned if (out / f).exists()]
            if clash:
                raise ConfigError(
                    f"out: '{out}' already holds {', '.join(clash[:3])} from an earlier "
                    "run; pass --force to replace, or choose another folder"
                )
        if batch:
            return run_batch(cfg, curves, out, fit_options(cfg, not args.quiet))
        from . import fit

        ((points, closed, label),) = curves
        previous = signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
        try:
            result = fit(points, closed=closed, **fit_options(cfg, not args.quiet))
        finally:
            signal.signal(signal.SIGTERM, previous)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:  # fit's own checks of the points and settings
        print(f"error: input '{cfg['input']}': {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted before the first iterations finished; nothing written", file=sys.stderr)
        return 130
    why = {
        "iterations": f"the iteration limit ({cfg['iterations']})",
        "tol": f"every swarm reaching tol = {cfg['tol']}",
        "interrupted": "an interrupt (best solutions so far)",
    }[result.stop_reason]
    print(
        f"{len(result.points)} points from {label}, {'closed' if closed else 'open'}; "
        f"stopped on {why} after {result.wall_time:.1f} s"
    )
    sparsest = _sparsest(cfg, result)
    print(format_table(result, sparsest))
    best = result.best
    print(
        f"best: degree {best.degree}, {best.n_ctrl} control points, mean deviation "
        f"{best.mean_deviation:.3e}, largest deviation {best.max_deviation * result.scale:.4g} "
        f"in the points' units ({best.max_deviation_pct_diag:.4f} % of the bounding-box "
        f"diagonal); mean error {best.error:.3e}"
    )
    if sparsest is None:
        print(f"sparsest within {_tolerance_text(cfg)}: none")
    if out is not None:
        for path in write_outputs(cfg, result, np.asarray(result.points), out):
            print(f"wrote {path}")
    return 0


SUMMARY = "summary.csv"
SUMMARY_COLUMNS = (
    "input",
    "points",
    "closed",
    "best_degree",
    "best_n",
    "best_mean_deviation",
    "best_max_deviation",
    "best_error",
    "best_pct_diag",
    "sparsest_degree",
    "sparsest_n",
    "sparsest_max_deviation",
    "sparsest_error",
    "stop_reason",
    "bucket",
    "call",
    "folder",
)


def slug(label: str) -> str:
    """A folder name for a curve's label: letters, digits, '-', '_' and '.' kept."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in label) or "curve"


def summary_row(cfg, label, closed, result) -> dict:
    best, sparsest = result.best, _sparsest(cfg, result)
    return {
        "input": label,
        "points": len(result.points),
        "closed": closed,
        "best_degree": best.degree,
        "best_n": best.n_ctrl,
        "best_mean_deviation": f"{best.mean_deviation:.6e}",
        "best_max_deviation": f"{best.max_deviation:.6e}",
        "best_error": f"{best.error:.6e}",
        "best_pct_diag": f"{best.error_pct_diag:.6f}",
        "sparsest_degree": "" if sparsest is None else sparsest.degree,
        "sparsest_n": "" if sparsest is None else sparsest.n_ctrl,
        "sparsest_max_deviation": "" if sparsest is None else f"{sparsest.max_deviation:.6e}",
        "sparsest_error": "" if sparsest is None else f"{sparsest.error:.6e}",
        "stop_reason": result.stop_reason,
        "bucket": result.batch["bucket"],
        "call": result.batch["call"],
        "folder": slug(label),
    }


def run_batch(cfg, curves, out: Path | None, options: dict) -> int:
    """Fit every curve as one batch; write each curve's results as soon as it is done,
    then ``summary.csv`` (also after Ctrl-C, for the curves finished by then)."""
    from . import fit_many
    from .batch import padding_waste

    labels = [label for _, _, label in curves]
    folders = [slug(label) for label in labels]
    dup = sorted({f for f in folders if folders.count(f) > 1})
    if dup:
        raise ConfigError(f"input: curves {', '.join(dup)} would share a result folder")
    rows: dict[int, dict] = {}
    results = {}

    def done(i, result):
        results[i] = result
        rows[i] = summary_row(cfg, labels[i], curves[i][1], result)
        if out is not None:
            write_outputs(cfg, result, np.asarray(result.points), out / folders[i])

    previous = signal.signal(signal.SIGTERM, _sigterm_to_interrupt)
    interrupted, start = False, time.perf_counter()
    try:
        fit_many(
            [pts for pts, _, _ in curves],
            closed=[c for _, c, _ in curves],
            on_result=done,
            **options,
        )
    except KeyboardInterrupt:
        interrupted = True
    except ValueError as exc:  # name the curve as the user knows it, not by its index
        message = re.sub(r"point_sets\[(\d+)\]", lambda m: f"'{labels[int(m[1])]}'", str(exc))
        raise ValueError(message) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    order = sorted(rows)
    table = [[str(rows[i][c]) for c in SUMMARY_COLUMNS[:-2]] for i in order]
    heads = list(SUMMARY_COLUMNS[:-2])
    widths = [max([len(h)] + [len(r[j]) for r in table]) for j, h in enumerate(heads)]
    for line in [heads] + table:
        print("  ".join(cell.rjust(w) for cell, w in zip(line, widths)))
    if results:
        waste = padding_waste([results[i] for i in order])
        print(
            f"{len(order)} of {len(curves)} curves in {time.perf_counter() - start:.1f} s; "
            f"padding: {100 * waste:.1f} % of the fitness's point slots"
        )
    if interrupted:
        print(f"interrupted: {len(order)} of {len(curves)} curves finished", file=sys.stderr)
    if out is not None and rows:
        from .export import atomic_write

        out.mkdir(parents=True, exist_ok=True)
        with atomic_write(out / SUMMARY, "w") as fh:
            writer = csv.DictWriter(fh, fieldnames=SUMMARY_COLUMNS, lineterminator="\n")
            writer.writeheader()
            writer.writerows(rows[i] for i in order)
        print(f"wrote {out / SUMMARY} and {len(order)} result folders")
    return 130 if interrupted and not rows else 0


if __name__ == "__main__":
    sys.exit(main())
