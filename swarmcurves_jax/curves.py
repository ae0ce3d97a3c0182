"""The ``Curve`` a fit hands back: geometry in the caller's frame plus its error report."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from .knots import check_degree_count, check_knots
from .projection import curve_derivatives

__all__ = ["Curve", "READABLE_SCHEMA_VERSIONS", "SCHEMA_VERSION"]

#: Version of the dictionary layout written by :meth:`Curve.to_dict` (2: the two-sided
#: measures; version 1 dictionaries still load, with those measures ``nan``).
SCHEMA_VERSION = 2
READABLE_SCHEMA_VERSIONS = (1, 2)

_METRICS = (
    "error",
    "max_error",
    "rms_error",
    "error_pct_diag",
    "mean_deviation",
    "max_deviation",
    "max_deviation_pct_diag",
)


@dataclasses.dataclass(frozen=True, eq=False)
class Curve:
    """A B-spline or NURBS curve on the parameter domain ``[0, 1]``.

    Attributes
    ----------
    degree : int
    control_points : ndarray, shape (n, D)
        In the caller's frame.  For a closed curve these are the ``n`` distinct control
        points; evaluation wraps the first ``degree`` of them around.
    weights : ndarray, shape (n,)
        Rational weights (all ones for a non-rational curve).
    knots : ndarray
        The full knot vector used for evaluation: clamped, length ``n + degree + 1``
        (open), or periodic with period 1, length ``n + 2 degree + 1`` (closed).  Uniform
        unless the fit freed the knots (``fit(free_knots=True)``).
    closed, rational : bool
    error, max_error, rms_error : float
        Mean, largest and RMS distance from the data points to the curve, by true
        projection, in the normalised frame (``nan`` if never measured).
    error_pct_diag : float
        ``error`` as a percentage of the data's bounding-box diagonal.
    mean_deviation, max_deviation : float
        The two-sided measures that judge a fit (:mod:`swarmcurves_jax.measures`), in the
        normalised frame: the mean of ``error`` and of the arc-length mean distance from
        the curve to the polyline through the data, and the Hausdorff distance between
        the curve and that polyline.  Unlike ``error`` they see a curve that leaves the
        data between or beyond the points.
    max_deviation_pct_diag : float
        ``max_deviation`` as a percentage of the data's bounding-box diagonal.
    residuals : ndarray, shape (N,) or None
        Per-point distances (normalised frame), in the order of the fitted points.
    info : dict
        JSON-safe extras of the fit (iterations run, seed, swarm fitness, ``source``:
        which candidate was kept, ``"swarm"``, ``"polish"``, ``"polish's last"`` (its last
        iterate), ``"shortened polish"`` (part of the way back to the swarm's),
        ``"polished seed"`` (the seed as the polish left it), or a least-squares fit,
        ``"seed"`` or ``"classic"``, ...).
    """

    degree: int
    control_points: np.ndarray
    weights: np.ndarray
    knots: np.ndarray
    closed: bool = False
    rational: bool = False
    error: float = math.nan
    max_error: float = math.nan
    rms_error: float = math.nan
    error_pct_diag: float = math.nan
    mean_deviation: float = math.nan
    max_deviation: float = math.nan
    max_deviation_pct_diag: float = math.nan
    residuals: np.ndarray | None = None
    info: dict = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        ctrl = np.array(self.control_points, dtype=np.float64)
        if ctrl.ndim != 2 or ctrl.shape[1] not in (2, 3):
            raise ValueError(f"control_points must have shape (n, 2) or (n, 3), got {ctrl.shape}")
        check_degree_count(self.degree, len(ctrl))
        w = np.array(self.weights, dtype=np.float64).reshape(-1)
        if w.shape != (len(ctrl),) or not np.all(np.isfinite(w)) or np.any(w <= 0):
            raise ValueError(
                f"weights must be {len(ctrl)} finite positive numbers, got shape {w.shape}"
            )
        t = check_knots(self.knots, len(ctrl), self.degree, bool(self.closed))
        object.__setattr__(self, "degree", int(self.degree))
        object.__setattr__(self, "control_points", ctrl)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "knots", t)
        object.__setattr__(self, "closed", bool(self.closed))
        object.__setattr__(self, "rational", bool(self.rational))
        if self.residuals is not None:
            object.__setattr__(self, "residuals", np.array(self.residuals, dtype=np.float64))
        for name in _METRICS:
            object.__setattr__(self, name, float(getattr(self, name)))

    @property
    def n_ctrl(self) -> int:
        """Number of (distinct) control points."""
        return len(self.control_points)

    @property
    def dim(self) -> int:
        return self.control_points.shape[1]

    def evaluate(self, t, nu: int = 0) -> np.ndarray:
        """Points (or the ``nu``-th derivative, ``nu <= 2``) at parameters ``t`` in [0, 1].

        Parameters
        ----------
        t : array_like, shape (m,) or scalar
        nu : int
            Derivative order: 0, 1 or 2.

        Returns
        -------
        ndarray, shape (m, D)

        Examples
        --------
        >>> import numpy as np
        >>> c = Curve(1, [[0, 0], [1, 0]], [1, 1], [0, 0, 1, 1])
        >>> c.evaluate([0.0, 0.25, 1.0])
        array([[0.  , 0.  ],
               [0.25, 0.  ],
               [1.  , 0.  ]])
        """
        u = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if u.ndim != 1:
            raise ValueError(f"t must be a scalar or a 1-D array, got shape {u.shape}")
        if not np.all(np.isfinite(u)) or np.any((u < 0) | (u > 1)):
            raise ValueError("t must hold finite parameters in [0, 1]")
        if nu not in (0, 1, 2):
            raise ValueError(f"nu must be 0, 1 or 2, got {nu!r}")
        return curve_derivatives(
            u, self.control_points, self.weights, self.knots, self.degree, self.closed, nu
        )[nu]

    __call__ = evaluate

    def to_clamped(self) -> "Curve":
        """The same curve on clamped knots: a closed curve becomes the open curve with
        ``n + degree`` control points whose ends meet (the form CAD formats expect)."""
        from .interop import clamped_form

        if not self.closed:
            return self
        t, ctrl, w = clamped_form(self)
        return dataclasses.replace(self, control_points=ctrl, weights=w, knots=t, closed=False)

    def to_scipy(self):
        """``scipy.interpolate.BSpline(t, c, k)``, ``c`` of shape (n, D).

        A closed curve keeps its periodic knots, with ``c`` the ``n + degree`` unwrapped
        control points (the first ``degree`` repeated) and ``extrapolate='periodic'``.
        Rational curves raise ``ValueError`` (scipy has no NURBS): see :meth:`to_geomdl`.
        """
        from .interop import to_scipy

        return to_scipy(self)

    @classmethod
    def from_scipy(cls, spline) -> "Curve":
        """A curve from a ``BSpline`` on clamped knots, or on periodic knots with the first
        ``k`` coefficients repeated at the end (what :meth:`to_scipy` makes); the knots may
        be non-uniform."""
        from .interop import from_scipy

        return from_scipy(spline, cls)

    def to_geomdl(self):
        """A geomdl ``NURBS.Curve`` / ``BSpline.Curve`` (clamped form; needs ``geomdl``)."""
        from .interop import to_geomdl

        return to_geomdl(self)

    def to_dict(self) -> dict[str, Any]:
        """A JSON-safe dictionary; :meth:`from_dict` restores the curve exactly."""
        out = {
            "schema_version": SCHEMA_VERSION,
            "degree": self.degree,
            "closed": self.closed,
            "rational": self.rational,
            "knots": self.knots.tolist(),
            "control_points": self.control_points.tolist(),
            "weights": self.weights.tolist(),
        }
        for name in _METRICS:
            value = getattr(self, name)
            out[name] = None if math.isnan(value) else value
        out["residuals"] = None if self.residuals is None else self.residuals.tolist()
        out["info"] = dict(self.info)
        return out

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Curve":
        """Rebuild a curve written by :meth:`to_dict`."""
        if not isinstance(d, dict):
            raise ValueError(f"Curve.from_dict expects a dict, got {type(d).__name__}")
        version = d.get("schema_version")
        if version not in READABLE_SCHEMA_VERSIONS:
            raise ValueError(
                f"schema_version {version!r} is not supported; this version of "
                f"swarmcurves_jax reads schema_version {' or '.join(map(str, READABLE_SCHEMA_VERSIONS))}"
            )
        required = ("degree", "closed", "rational", "knots", "control_points", "weights")
        missing = [key for key in required if key not in d]
        if missing:
            raise ValueError(f"curve dict is missing key(s): {', '.join(missing)}")
        known = set(required) | set(_METRICS) | {"schema_version", "residuals", "info"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"curve dict has unknown key(s): {', '.join(unknown)}")
        metrics = {m: math.nan if d.get(m) is None else d[m] for m in _METRICS}
        return cls(
            degree=d["degree"],
            control_points=d["control_points"],
            weights=d["weights"],
            knots=d["knots"],
            closed=d["closed"],
            rational=d["rational"],
            residuals=d.get("residuals"),
            info=dict(d.get("info") or {}),
            **metrics,
        )

    def __repr__(self) -> str:
        kind = "closed" if self.closed else "open"
        rat = " rational" if self.rational else ""
        return (
            f"Curve(degree={self.degree}, n_ctrl={self.n_ctrl}, {kind}{rat}, "
            f"dim={self.dim}, error={self.error:.3g}, max_deviation={self.max_deviation:.3g})"
        )
