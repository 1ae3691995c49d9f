"""What ``pdr run``'s forkserver imports before it forks a worker (``pool.PRELOAD``; a dask worker too).

Every worker inherits these modules imported, the overview figure drawn and
the model's kernels loaded (``pipeline.validate.warmup``, last).  Python's
garbage collector is paused meanwhile: the imports allocate a few hundred
thousand objects that live as long as the process, and collecting them over
and over took about a quarter of this start, which every ``pdr run`` waits
for.  What the imports leave as garbage (~3 MB) is frozen with the rest by
the warm-up, shared by the workers and never scanned.
"""

import gc
import importlib

MODULES = ("numpy", "pandas", "pyarrow.parquet", "rerun", "matplotlib.figure", "pipeline.run.stages",
           "pipeline.ingest.stage", "pipeline.derive.stage", "pipeline.validate.stage",
           "pipeline.validate.rerun_log", "pipeline.validate.warmup")

gc.disable()
try:
    for _name in MODULES:
        importlib.import_module(_name)
finally:
    gc.enable()
