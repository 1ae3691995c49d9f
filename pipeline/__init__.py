"""pdr: pinion-double-rack recordings to a validated hybrid model.

Before anything imports numba: its compiled kernels are cached once per machine (``jit_cache``)."""

from pipeline.jit_cache import use_shared_cache

use_shared_cache()
