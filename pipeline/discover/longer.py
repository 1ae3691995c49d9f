"""The named effects' values refitted on more of the recording than the search used.

The search (rounds, checks, verdict) runs on the first ``MAX_SAMPLES`` samples, where its budget holds.
On a longer recording, what it named is then fitted again, jointly and from the search's values, on up
to ``REFIT_SAMPLES``: one least-squares refit, a few dozen replays, where the search took thousands.
Two effects on a ridge are pinned down by the cycles the search did not see (draw 277: a backlash beside
a heavier rack, on 2000 of 7666 samples 27 % off with an interval of +-26 %; on 4000, 18 % off).

The refit is kept only where the verdict is ``explained`` and stays so: every value still nameable,
the search's window still without structure under them.  It is skipped where the search's commands
are not the logged ones (switches inferred from the angle and settled on the window would be unsettled
beyond it) and after a board reset (the counter's zero is refitted with the effects there).
"""

from __future__ import annotations

from dataclasses import replace

import pandas as pd

from pipeline.config import RigConfig
from pipeline.discover.candidates import Evaluator
from pipeline.discover.joint import effect_intervals, joint_fit
from pipeline.discover.measurement import MAX_SAMPLES, measurement_from_kinematics
from pipeline.discover.residuals import noise_floor
from pipeline.discover.criterion import nameable, residual_taus
from pipeline.discover.search import Selection, excess
from pipeline.discover.start_refit import held_start_sensitivity, refine_start

REFIT_SAMPLES = 2 * MAX_SAMPLES


def refit_on_more_samples(sel: Selection, kin: pd.DataFrame, config: RigConfig, name: str,
                          zero_samples: dict[str, int] | None = None) -> Selection:
    """``sel`` with its effects, intervals and what they leave refitted on up to ``REFIT_SAMPLES``
    samples (see the module docstring), or ``sel`` as it was."""
    window = sel.meas
    if (sel.verdict != "explained" or window.samples_in_recording <= window.n or not window.angle_reference_known
            or window.dir_source != "logged"):
        return sel
    longer = replace(measurement_from_kinematics(kin, config, name, zero_samples=zero_samples,
                                                 max_samples=REFIT_SAMPLES), lost_shifts=window.lost_shifts)
    ev = Evaluator(longer, noise_floor(longer, longer.replay(longer.spec())))
    effects = joint_fit(ev, sel.effects, taus=residual_taus(ev, sel.effects))
    if effects == sel.effects or not all(nameable(e, sel.policy) for e in effects):
        return replace(sel, work=sel.work + ev.work)
    on_window = Evaluator(window, sel.floor)
    refine_start(on_window, effects)
    left = excess(on_window, effects)
    if max(left.values()) > sel.policy.structure_floors:
        return replace(sel, work=sel.work + ev.work + on_window.work)
    refine_start(ev, effects)
    spans = effect_intervals(held_start_sensitivity(ev, effects), effects)
    return replace(sel, effects=effects, intervals=spans, excess_after=left,
                   command_after=on_window.command_for(effects), work=sel.work + ev.work + on_window.work,
                   refit_samples=longer.n)
