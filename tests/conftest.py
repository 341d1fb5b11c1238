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
