"""Imported by ``pdr run``'s forkserver (last in ``pipeline.run.preload``) before it forks workers.

Importing it draws one overview figure, so each worker inherits a ready
figure, loaded fonts and a cached background instead of paying for them on its
first recording.  Nothing else imports this module.
"""

import gc

from pipeline.validate.plots import warm_up

try:
    warm_up()
except Exception:  # only a head start: a worker that lacks it draws its first figure itself
    pass

# Everything imported and built so far lives as long as the process: move it out of the garbage
# collector's generations, so a worker's collections never touch (and copy-on-write) the pages it
# inherited from the forkserver.
gc.freeze()
