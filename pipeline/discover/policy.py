"""Every threshold discovery decides by, in one value (issue 27).

``select(meas, policy=...)`` takes a ``DiscoveryPolicy`` and passes it to where each field is used
(``search``, ``longer``, ``declared``, ``stage``): a search with other thresholds is a different
value, not an edit of module constants, and the thresholds a run used travel with its ``Selection``.
Each field's comment says what it protects against.  They were chosen on benchmark seeds that are
never reported (docs/BENCHMARKS.md).

Not here, because they are not decisions (they change how much a search costs or how finely it
looks, not what counts as evidence): the work unit (``candidates.EVENT_SAMPLE_COST``,
``REPLAY_OVERHEAD``, ``START_RUN_COST``), the simulation and sample grid (``measurement.MAX_SAMPLES``,
``longer.REFIT_SAMPLES``, each effect's scan grid ``Param.scan``), the nuisances' search range
(``candidates.ONSET_SHIFTS``/``ONSET_WINDOW``, ``start_refit.STEPS``), and the questions across runs
(``pooled``) and with the base free (``base_free``).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DiscoveryPolicy:
    """The thresholds of one recording's discovery; ``DEFAULT_POLICY`` is what ``pdr discover`` uses."""

    # --- the criterion: held-out likelihood (``search``)
    # held-out nll an effect must remove, in independent samples, for each of its parameters: clear of
    # what chance gives a parameter fitted to noise (5 is "strong" on Kass & Raftery's scale, 2 ln B = 10)
    evidence_per_parameter: float = 5.0
    # share of some signal's held-out structure (MSE above its noise) an effect must remove: one that is
    # there removes the pattern it makes; one that buys likelihood while most of the pattern stays is
    # absorbing the misfit of something outside the catalogue.  Under half: the true model itself leaves
    # 1-3 noise variances in the angle (the switches' instants are known to the clock's tick), so a small
    # effect beside others cannot remove half of what is above the floor (tuning seeds: 0.2 343, 0.3 and
    # 0.4 349, 0.5 346 of 360)
    min_heldout_share: float = 0.4
    # smallest nameable effect, as a share of its catalogue's typical size: a catalogued effect that
    # absorbs a small misfit of another kind (a hot winding read as springs 1-2 % stiffer) takes a small value
    min_size_share: float = 0.1
    # a sensor's offset must stand this many standard errors clear of the zero ingest read off rest
    # readings (a nuisance with a known error: by chance 3 are exceeded once in ~370 recordings)
    zero_sigmas: float = 3.0
    # structure in a sensor's own signal within this many standard errors of the noise floor's estimate
    # may be the floor's error, which no effect removes: a sensor's zero is not asked for it
    floor_sigmas: float = 2.0

    # --- the verdict
    # residual MSE above this many noise variances is structure: the line between explained/none and
    # unexplained
    structure_floors: float = 25.0

    # --- the search's extent
    # most effects stacked on one recording: against an ever longer model of small misfits
    max_effects: int = 3
    # further starts are tried (and, after elimination, members exchanged) where the model leaves more
    # than this many noise variances in some signal: the true model leaves 1.6-2.9 in the angle (the
    # clock's tick), and a stand-in picked first
    # (viscous friction for a delay and a driver drop together) can leave far less than ``structure_floors``
    # while its partners' pattern stays (25, the verdict's line, before: tuning seeds 349 -> 348 of 360 with
    # 5 or 10, a rack inertia read with springs beside it; six seeds used earlier 686 -> 689 of 720, none lost)
    starts_above: float = 5.0
    # round one's best candidates the rounds are run from when the plain run leaves more than
    # ``starts_above`` (a wrong near-twin picked first leaves its partner's pattern)
    starts: int = 3
    # later rounds fit and cross-validate only this many candidates, those the coarse scan ranks first
    # (round one all of them): bounds a round's cost
    later_full_fits: int = 3
    # a run of the rounds fits a further candidate only within this work (``Evaluator.work``, ~0.6 us of
    # CPU a unit: ~6 s, more where the starts are event-driven) ...
    work_budget: int = 10_500_000
    # ... and further starts begin only within this: counted, not timed, so a busy machine gets the
    # same answer as an idle one
    total_work_budget: int = 11_000_000
    # on a rig whose [model] is not declared, the check with the base free (``base_free``) offers the
    # catalogue again only while the search's work and its own are within this; its first fit and
    # elimination, which can only drop names, always run.  Bounds an undeclared rig's whole decision
    # (~0.5 us of CPU a unit); on used calibration seeds 11-16 (144 recordings) it ended two checks'
    # steps, their answers unchanged, and the decision's CPU max 7.2 s
    decision_work_budget: int = 12_000_000
    # the runner-up is reported as a near tie when its held-out evidence is within this many charges
    # of the winner's: tells a user the choice was close
    near_tie: float = 1.0

    # --- which segment of a capture with board resets is discovered (``stage``)
    # a later segment is taken over the first only when it has more than this many times its samples:
    # the first's counter started where the springs rest, a later one's zero is a nuisance
    later_segment_factor: float = 2.0


DEFAULT_POLICY = DiscoveryPolicy()
