"""The options of a fit: one type holds their defaults and checks them.

:func:`swarmcurves_jax.fit`, :func:`swarmcurves_jax.fit_many` and the command line all
build a :class:`FitOptions`; every curve of a batch shares one.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from . import pso
from . import refine as local
from ._validation import (
    check_bool,
    check_no_unknown,
    check_params,
    check_positive_int,
    check_tol,
    check_weight_bounds,
)

__all__ = ["FitOptions", "MAX_SAMPLES"]

#: The most fitness samples a curve may have (the search packs their index into a float).
MAX_SAMPLES = 4096


@dataclasses.dataclass(frozen=True)
class FitOptions:
    """How to fit: every keyword of :func:`~swarmcurves_jax.fit` but the points, ``closed``,
    ``seed`` and ``callback``.  Built checked: a bad value raises ``ValueError`` naming it.

    Parameters
    ----------
    cps : int or iterable of int
        Control-point counts.  Every count must be ``>= degree + 1`` (checked per curve,
        where open or closed is known).
    degrees : int or iterable of int
        Degrees (1 is a polygon).
    rational : bool
        Optimise NURBS weights too, inside ``weight_bounds``; reported scaled to max 1.
    free_knots : bool
        Let the swarm (and the polish) move the interior knots too, kept sorted with every
        span at least 10 % of a uniform one (:mod:`swarmcurves_jax.knots`), so knots gather
        where the curvature is high.  Default: the paper's fixed uniform knots.
    fix_ends : bool
        Pin an open curve's first and last control points to the first and last point.
    init : {"lsq", "uniform"}
        ``"lsq"`` puts one particle per swarm on the least-squares fit (with parameter
        correction); ``"uniform"`` starts every particle in U[-1, 1] as the paper does.
    refine : bool or {"lm", "lbfgs"}
        Polish every swarm's solution locally after the swarm (:mod:`swarmcurves_jax.polish`):
        ``True`` or ``"lm"`` is Levenberg–Marquardt on the orthogonal distances,
        ``"lbfgs"`` optax's L-BFGS, ``False`` the paper's pure PSO.  A polished solution
        replaces the swarm's only if its two-sided ``mean_deviation`` is lower.
    particles : int
        Particles per swarm.
    iterations : int
        Iteration limit (the paper: 2000).  Each iteration evaluates every particle once.
    tol : float, optional
        Stop a swarm once its best fitness (mean distance plus the excursion term,
        normalised frame) is ``<= tol``; the call returns as soon as every swarm has.
    params : PSOParams, optional
        Inertia, cognitive and social coefficients, velocity clamp and restart patience
        (default :func:`swarmcurves_jax.pso.default_params`).
    weight_bounds : (float, float)
        Bounds of the rational weights during the search.
    num_samples : int, optional
        Curve samples per particle in the fitness's search (default: 4 per knot span,
        :func:`swarmcurves_jax.prepare.default_num_samples`).
    search_every : int
        The swarm searches each point's nearest curve sample (most of the fitness's work)
        every ``search_every`` iterations (polygons: every iteration); in between, a
        particle's Newton steps start from its last search's samples.  8 is faster, but the
        swarm finds exact curves less often (docs/method.md, "Reusing the search").
    chunk_size : int
        Iterations per compiled chunk; between chunks the host checks ``tol`` and calls
        ``callback``.  Results do not depend on it.
    progress : bool
        Show a progress bar (tqdm).  Ctrl-C stops the run cleanly: the result holds the
        best solutions found so far and ``stop_reason == "interrupted"``.
    max_fitness_points : int
        The swarm's fitness uses at most this many of the points, evenly spread along
        their order; the reported errors always use every point.
    stage_timings : bool
        Wait for the swarm before queuing the polish, to time each in
        ``FitResult.timings`` (``"swarm"``, ``"refine"``).  Off, the polish compiles while
        the swarm runs, and ``timings`` has the whole ``"call"``.
    dtype : jnp.float32 or jnp.float64
        Precision of the swarm (float64 needs ``jax_enable_x64``).
    """

    cps: object = range(4, 11)
    degrees: object = 3
    rational: bool = False
    free_knots: bool = False
    fix_ends: bool = True
    init: str = "lsq"
    refine: bool | str = True
    particles: int = 64
    iterations: int = 2000
    tol: float | None = None
    params: pso.PSOParams | None = None
    weight_bounds: tuple[float, float] = (1e-2, 1e2)
    num_samples: int | None = None
    search_every: int = 1
    chunk_size: int = 200
    progress: bool = False
    max_fitness_points: int = 2000
    stage_timings: bool = False
    dtype: object = jnp.float32

    def __post_init__(self):
        for name, value in _checked(self).items():
            object.__setattr__(self, name, value)

    @classmethod
    def from_keywords(cls, keywords: dict, caller: str = "fit") -> FitOptions:
        """``FitOptions(**keywords)``, an unknown name raising the ``TypeError`` Python
        raises for one (with a close match: "did you mean")."""
        fields = [f.name for f in dataclasses.fields(cls)]
        check_no_unknown({k: v for k, v in keywords.items() if k not in fields}, fields, caller)
        return cls(**keywords)

    @property
    def method(self) -> str | None:
        """The polish's method: ``"lm"``, ``"lbfgs"`` or None (no polish)."""
        if self.refine is True:
            return "lm"
        return None if self.refine is False else self.refine


def _checked(opts: FitOptions) -> dict:
    """Every option but the counts checked (exact errors that name it), some normalised."""
    if opts.init not in ("lsq", "uniform"):
        raise ValueError(f"init must be 'lsq' or 'uniform', got {opts.init!r}")
    refine = opts.refine
    if refine is None:
        refine = False
    if not (isinstance(refine, bool) or (isinstance(refine, str) and refine in local.METHODS)):
        raise ValueError(f"refine must be True, False, 'lm' or 'lbfgs', got {refine!r}")
    num_samples = opts.num_samples
    if num_samples is not None:
        num_samples = check_positive_int(num_samples, "num_samples")
        if num_samples > MAX_SAMPLES:
            raise ValueError(f"num_samples must be <= {MAX_SAMPLES}, got {num_samples}")
    dtype = jnp.dtype(opts.dtype)
    if dtype not in (jnp.float32, jnp.float64):
        raise ValueError(f"dtype must be float32 or float64, got {dtype}")
    if dtype == jnp.float64 and not jax.config.jax_enable_x64:
        raise ValueError("dtype float64 needs jax.config.update('jax_enable_x64', True)")
    return dict(
        rational=check_bool(opts.rational, "rational"),
        free_knots=check_bool(opts.free_knots, "free_knots"),
        fix_ends=check_bool(opts.fix_ends, "fix_ends"),
        refine=refine,
        particles=check_positive_int(opts.particles, "particles"),
        iterations=check_positive_int(opts.iterations, "iterations"),
        tol=check_tol(opts.tol),
        params=check_params(pso.default_params() if opts.params is None else opts.params),
        weight_bounds=check_weight_bounds(opts.weight_bounds),
        num_samples=num_samples,
        search_every=check_positive_int(opts.search_every, "search_every"),
        chunk_size=check_positive_int(opts.chunk_size, "chunk_size"),
        progress=check_bool(opts.progress, "progress"),
        max_fitness_points=check_positive_int(opts.max_fitness_points, "max_fitness_points"),
        stage_timings=check_bool(opts.stage_timings, "stage_timings"),
        dtype=dtype,
    )
