"""``dask worker --preload pipeline.cluster.preload ADDRESS``: a worker imports what pdr's recordings need
(numpy, pandas, pyarrow, rerun, matplotlib, numba's kernels: seconds) when it starts, instead of at the
start of every ``pdr run --cluster`` that finds it cold."""

from pipeline.cluster.connect import prepare_worker

prepare_worker()
