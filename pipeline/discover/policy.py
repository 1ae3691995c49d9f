"""Every threshold discovery decides by, in one value (issue 27).

``select(meas, policy=...)`` takes a ``DiscoveryPolicy`` and passes it down to where each field is
used (``evidence``, ``selection``, ``thorough``, ``longer``, ``declared``, ``stage``), so a search with
other thresholds is a different value, not an edit of module constants, and the thresholds a run used
travel with its ``Selection``.  Each field's comment says what it protects against.

Not here, because they are not decisions (they change how much a search costs or how finely it looks,
not what counts as evidence):

- cost accounting: ``candidates.EVENT_SAMPLE_COST``, ``REPLAY_OVERHEAD``, ``START_RUN_COST`` (the work unit
  the budgets below are counted in, fitted to measured CPU) and ``candidates.FAILED_NLL``;
- the simulation and sample grid: ``measurement.MAX_SAMPLES``, ``OFFSET_STEP``, ``SIM_GRID_S``,
  ``longer.REFIT_SAMPLES``, and each effect's scan grid (``Param.scan`` in the model's catalogue);
- the nuisances' search range and numerics: ``candidates.ONSET_SHIFTS``/``ONSET_WINDOW`` (how late a
  motor start may be: a loop delay or a breakaway), ``start_refit.STEPS``/``RELATIVE_STEP`` and
  ``joint.joint_fit``'s evaluations;
- a measured fact: ``evidence.FLOOR_RELATIVE_VARIANCE`` (the noise floor estimate's relative variance);
- the questions across runs (``pooled.AGREE_P``, ``TREND_P``, ``MIN_TREND_RUNS``), which are not one
  recording's search, and the base-free check (``base_free``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DiscoveryPolicy:
    """The thresholds of one recording's discovery; ``DEFAULT_POLICY`` is what ``pdr discover`` uses."""

    # --- evidence a candidate must show (``evidence.assess``: the six checks of ``selection``'s docstring)
    # held-out angle MSE a candidate must remove, in noise variances: the angle's floor counts only
    # quantisation and the clock, so less than a whole variance is the data's own integration error
    theta_min_gain: float = 1.0
    # the current's floor is its sensor's white noise, which the right model reaches: a gain there is
    # evidence at this much chi-square over the recording (an offset of a third of a sigma over 1,000
    # samples is ~100) ...
    current_min_gain_chi2: float = 25.0
    # ... and at most this many noise variances however short the recording
    current_min_gain: float = 0.25
    # structure in the current within this many standard errors of the floor's own estimate may be the
    # floor's error, which no effect removes: a candidate moving the current alone is not asked for it
    floor_sigmas: float = 2.0
    # share of the held-out structure a candidate must remove: a candidate that buys a little likelihood
    # without removing the pattern is absorbing another effect's misfit
    min_heldout_share: float = 0.5
    # no signal may get worse than this on held-out data (noise variances): an effect that trades one
    # signal's fit for another's has the wrong shape (a stacked partner may cost a little)
    max_worsening_floors: float = 2.0
    # "strong" evidence on Kass & Raftery's scale, each parameter charged: against overfitting noise
    max_delta_bic: float = -10.0
    # the residual pattern that points at the candidate must at least shrink by this factor ...
    signature_shrink: float = 0.5
    # ... or fall to this many noise variances ...
    signature_noise: float = 3.0
    # ... or the candidate remove this share of all held-out structure (its local window may then hold
    # what a stacked effect leaves): against an effect that fits well without its own fingerprint
    dominant_share: float = 0.8
    # samples after a switch or an angle zero crossing where such a fingerprint is looked for
    signature_window: int = 3
    # |omega| under this share of its largest is "near zero velocity" (friction's fingerprint)
    low_speed_share: float = 0.15
    # an effect confounded with a zero read off rest readings must stand this many of that zero's
    # standard errors clear of it (by chance 3 are exceeded once in ~370 recordings)
    zero_sigmas: float = 3.0
    # smallest nameable effect, as a share of its catalogue's typical size: a catalogued effect that
    # absorbs a small misfit of another kind takes a small value
    min_size_share: float = 0.1

    # --- the criterion (``search``)
    # held-out nll an effect must remove, in independent samples, for each of its parameters: clear of
    # what chance gives a parameter fitted to noise
    evidence_per_parameter: float = 5.0
    # round one's best candidates the rounds are run from (near-twins picked before their partners are known)
    starts: int = 3

    # --- the verdict
    # residual MSE above this many noise variances is structure: the line between explained/none and
    # unexplained, and where the searches beyond the rounds stop
    structure_floors: float = 25.0

    # --- the search (``selection``, ``thorough``)
    # most effects stacked on one recording: against an ever longer model of small misfits
    max_effects: int = 3
    # later rounds fully assess only this many candidates, those the coarse scan ranks first (round one
    # assesses all): bounds a round's cost
    later_full_fits: int = 3
    # a run of the rounds starts a round, a candidate, a wide search or a twin swap only within this
    # work (``Evaluator.work``, ~0.6 us of CPU a unit: ~6 s) ...
    work_budget: int = 10_500_000
    # ... and all runs on one recording (round one's two best, resettled switches) within this (~7 s):
    # counted, not timed, so a busy machine gets the same answer as an idle one
    total_work_budget: int = 11_000_000
    # a later run of the rounds starts only with this much of the total left (a round) ...
    later_run_work: int = 1_500_000
    # ... and the wide searches (a thorough round, a pair restart: each 2-4 M) with this much
    wide_search_work: int = 3_000_000
    # a twin replaces an adopted effect when it fits every sample better by this share of
    # ``max_delta_bic`` (equal parameter counts): against swapping on noise
    twin_swap_share: float = 0.5
    # after a swap the partners are refitted at most this many times, while each gains
    # ``twin_settle_nll`` in likelihood: they had settled around the old twin
    twin_settles: int = 2
    twin_settle_nll: float = 1.0
    # the runner-up is reported as a near tie when it leaves at most this many times the winner's
    # held-out structure (+1 noise variance each): tells a user the choice was close
    near_tie: float = 2.0
    # round one's best candidates (by held-out gain) a pair restart is drawn from: bounds its cost
    pair_pool: int = 6
    # a pair must leave at most this share of the structure the effects found leave: a pair of wrong
    # effects can buy a little likelihood without removing the pattern
    pair_shrink: float = 0.5
    # evaluations of each step's refit of the adopted effects along the profile walk: bounds its cost
    walk_nfev: int = 8

    # --- which segment of a capture with board resets is discovered (``stage``)
    # a later segment is taken over the first only when it has more than this many times its samples:
    # the first's counter started where the springs rest, a later one's zero is a nuisance
    later_segment_factor: float = 2.0


DEFAULT_POLICY = DiscoveryPolicy()
