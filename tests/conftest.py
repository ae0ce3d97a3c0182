import gc
import logging
import os
import shutil
import tempfile

# One compilation cache for the whole run: the workers, the command line's subprocesses
# and the notebooks' kernels (which inherit the variable) compile many of the same
# programs; a program read back from the cache is the same executable, so results do not
# change.  Keyed by the run, so a run never reads an older run's programs.
_RUN = os.environ.get("PYTEST_XDIST_TESTRUNUID", str(os.getpid()))
_OWN_CACHE = "JAX_COMPILATION_CACHE_DIR" not in os.environ
os.environ.setdefault(
    "JAX_COMPILATION_CACHE_DIR", os.path.join(tempfile.gettempdir(), f"swarmcurves-tests-{_RUN}")
)

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from hypothesis import settings  # noqa: E402

# Python's cyclic collector walks every live object in its oldest generation, and a test
# worker's heap grows with each program JAX traces and keeps: at the default thresholds,
# collections took 8 % of a worker's time (5.3 of 68.6 s over test_robustness.py and
# test_refine.py), most of them while tracing.  Rarer young collections (nearly no old
# ones) leave the objects' lifetimes to reference counting.
gc.set_threshold(20_000, 50, 50)
jax.config.update("jax_numpy_rank_promotion", "raise")
jax.config.update("jax_compilation_cache_dir", os.environ["JAX_COMPILATION_CACHE_DIR"])

settings.register_profile("ci", max_examples=40, deadline=None, derandomize=True)
settings.register_profile("dev", max_examples=20, deadline=None)
settings.load_profile("ci" if os.environ.get("CI") else "dev")


def pytest_unconfigure(config):
    """The run's cache folder (tens of MB) goes with the run: removed by the process that
    ran the session (with xdist, the controller, after every worker has finished)."""
    if _OWN_CACHE and not hasattr(config, "workerinput"):
        shutil.rmtree(os.environ["JAX_COMPILATION_CACHE_DIR"], ignore_errors=True)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


class _Count(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names = []

    def emit(self, record):  # one per backend compilation (also a persistent-cache read)
        msg = record.getMessage()
        if msg.startswith("Finished XLA compilation of"):
            self.names.append(msg)


def _compiles_during(fn):
    handler = _Count()
    logger = logging.getLogger("jax")
    old = logger.level
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles(True):
            fn()
    finally:
        logger.removeHandler(handler)
        logger.setLevel(old)
    return handler.names


@pytest.fixture
def compiles_during():
    """``compiles_during(fn)``: the backend compilations ``fn()`` causes (JAX's log lines)."""
    return _compiles_during
