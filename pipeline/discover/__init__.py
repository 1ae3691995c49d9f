"""Discovery: where model and measurement disagree, which catalogued effect is missing, and proof.

The workflow (issue 6), module by module:

- ``measurement``: a derived run as arrays; replay (the logged command drives the model) is what
  every fit runs on, because it is smooth in the parameters -- a closed-loop free run jumps when
  a simulated switch slips by one control period.  The start (x0, pre-log commands) is estimated
  per model as validation does (``pipeline.estimate.initial_state``).  Without a logged command,
  the inferred motor start and near-guard switches are nuisances settled by the fit.
- ``residuals``: the noise floor from the recording itself (``pipeline.estimate.noise``: robust
  differences of each signal, never below the quantisation, plus the clock's share for the angle)
  and the localisation: where the residual lives, in words, numbers and tables (per mode, binned
  by state, aligned on events).
- ``candidates``: every effect of ``pipeline.model.effects.CATALOGUE`` fitted for its parameter
  within its bounds (coarse geometric scan, then Brent), earlier effects refitted with it, an
  interval from the joint Gauss-Newton information (autocorrelation-corrected, widened by the
  held-out folds' spread), and held-out scores (fit on half the cycles, score the other half).
- ``search``: forward selection by one criterion, the held-out (cross-validated) likelihood an
  effect removes, in independent samples, charged per parameter; round one's best candidates as
  further starts; backward elimination by the same criterion; the verdict ``explained`` / ``none`` /
  ``unexplained``.  Every threshold is a field of ``policy.DiscoveryPolicy``.
- ``stage``: the pure ``discover(kinematics, config, name)`` and the JSON of docs/FORMAT.md; MSEs
  before/after are computed by validation's own code (``simulate_both`` + ``signal_errors``).
- ``report``: JSON, ``[effects]`` snippet, Markdown with PNGs, Rerun recording.
- ``adopt``: writes the augmented ``[effects]`` into the sidecar TOML, only on ``--adopt``.
- ``cli``: ``pdr discover RECORDING [--json] [--adopt] [--out DIR]``.
"""
