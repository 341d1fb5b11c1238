"""Suite-wide settings.

Hypothesis runs derandomized (a fixed seed per test, no example database), like every other
stochastic test here: the same commit gives the same verdict on every machine, CI included.
Set ``HYPOTHESIS_PROFILE=explore`` to search with fresh random examples instead.
"""

import os

from hypothesis import settings

settings.register_profile("mtplan", derandomize=True, database=None, print_blob=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "mtplan"))


def pytest_configure(config):
    """With workers (``-n``), each computes on one core, its BLAS too: set before the
    workers start, so that they load their BLAS libraries with one thread. (Two workers with
    two BLAS threads each on two cores: a thread that waits for the core the other worker
    holds spins; the suite ran 4 % longer.) An explicit setting in the environment wins."""
    if getattr(config.option, "numprocesses", None) and not os.environ.get("PYTEST_XDIST_WORKER"):
        for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ.setdefault(name, "1")
