"""swarmcurves_jax: smooth B-spline and NURBS curves from ordered points, by particle swarms.

Every (degree, control-point count) of a :func:`fit` call is one swarm, and all swarms run
as one jit-compiled JAX program (CPU by default, a GPU when JAX sees one).
"""

from .basis import design_matrix as design_matrix
from .batch import fit_many as fit_many
from .batch import fit_stream as fit_stream
from .curves import SCHEMA_VERSION as SCHEMA_VERSION
from .curves import Curve as Curve
from .fit import fit as fit
from .fit import normalise as normalise
from .knots import clamped_uniform_knots as clamped_uniform_knots
from .knots import make_knots as make_knots
from .knots import periodic_uniform_knots as periodic_uniform_knots
from .options import FitOptions as FitOptions
from .pso import PSOParams as PSOParams
from .pso import default_params as default_params
from .results import FitResult as FitResult

__version__ = "0.1.0"

__all__ = [
    "Curve",
    "FitOptions",
    "FitResult",
    "PSOParams",
    "SCHEMA_VERSION",
    "clamped_uniform_knots",
    "default_params",
    "design_matrix",
    "fit",
    "fit_many",
    "fit_stream",
    "make_knots",
    "normalise",
    "periodic_uniform_knots",
]
