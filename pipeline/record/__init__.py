"""``pdr record``: capture the rig's serial output into ``raw/NAME.csv`` byte for byte, with a live view.

Modules: ``capture`` (the loop: port -> file, exclusive create, appends, periodic fsync,
stop reasons), ``decode`` (bytes -> samples with ingest's parsing and units, for the view),
``live`` (the view's thread and Rerun logging, fed by a queue that drops frames, never
bytes), ``ports`` (``--list``), ``session`` (the shell: signals, then ``pdr run``'s code on
the recording), ``cli`` (typer).  The virtual rig to record from without hardware is
``pdr rig serve --pty`` (``pipeline.rig.serve``).
"""
