"""``pdr run --cluster``: the per-recording work on a ``dask.distributed`` cluster.

Where outputs are written: by the client (``pdr run``'s own process), from the
bytes the workers return.  A worker ingests, derives and validates its
recordings in a private scratch folder (``/dev/shm`` when there is one),
reads every file back and deletes the folder; the client renames each file
into ``processed/`` complete (``pipeline.io.atomic``), syncs once per chunk,
then writes the chunk's stamps.  So workers need no shared file system (the
client sends each raw file's bytes and its resolved rig configuration), a
worker killed mid-task leaves nothing behind in ``processed/``, and the lock,
the stamps and ``summary.csv`` stay with the client, as in a local run.

``connect`` (address from ``--cluster`` or ``PDR_CLUSTER``), ``work`` (what runs
on a worker), ``execute`` (submission, progress, retries, writing).
"""
