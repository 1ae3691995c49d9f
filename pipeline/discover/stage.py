"""The discovery workflow on one run: localise, fit every candidate, select, confirm, report.

Pure core (``discover``: kinematics + rig config -> ``Discovery``), imperative
shell (``discover_run``: a processed run folder -> files in an output folder).
The MSEs before/after are validation's measures (``metrics.signal_errors``, closed
loop and replay at the recording's instants, from the start validation estimates).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pipeline.columns import column
from pipeline.config import RigConfig, effects_toml_snippet
from pipeline.discover.measurement import Measurement, measurement_from_kinematics
from pipeline.discover.residuals import binned, describe, signatures
from pipeline.calibrate.structure import declared_model
from pipeline.discover.base_free import BaseFreeCheck, check_with_base_free
from pipeline.discover.declared import check_declared
from pipeline.discover.longer import refit_on_more_samples
from pipeline.discover.policy import DEFAULT_POLICY, DiscoveryPolicy
from pipeline.discover.search import Selection, candidate_names, select
from pipeline.model.effects import Effect
from pipeline.model.params import PlantSpec
from pipeline.model.simulate import MAX_LOST_ROWS, SimResult
from pipeline.runs import RunPaths, config_sources, ingest_segment, load_config
from pipeline.validate.metrics import mse_only, signal_errors
from pipeline.validate.stage import finite_or_none, load_kinematics

WAYS = ("closed_loop", "replay")


@dataclass
class Discovery:
    meas: Measurement
    selection: Selection
    base: dict[str, SimResult]            # closed_loop / replay with the rig's model
    final: dict[str, SimResult]           # the same with the discovered effects added
    mse_before: dict[str, dict[str, float]]   # way -> signal -> MSE
    mse_after: dict[str, dict[str, float]]
    localisation_before: list[str]
    localisation_after: list[str]
    tables_before: dict[str, list[dict]]      # residual RMS binned in state / aligned on events (replay)
    tables_after: dict[str, list[dict]]
    seconds: float
    declared_too_large: list[dict] = field(default_factory=list)   # see declared.check_declared
    base_check: BaseFreeCheck | None = None    # the rig declares no [model]: effects tested with the base free

    @property
    def effects(self) -> tuple[Effect, ...]:
        return self.selection.effects if self.base_check is None else self.base_check.kept

    @property
    def verdict(self) -> str:
        """The search's verdict, or ``unexplained`` where the base-free check dropped what the search
        found: the structure is there, and only the rig's own base parameters can say what it is."""
        if self.base_check is not None and self.base_check.dropped:
            return "unexplained"
        return self.selection.verdict

    @property
    def hint(self) -> str | None:
        return None if self.base_check is None else self.base_check.hint

    def interval_of(self, effect: Effect) -> tuple[float, float]:
        """The effect's first parameter's ~95 % interval, from the fit that gave its value."""
        if self.base_check is None:
            return self.selection.intervals[[e.name for e in self.selection.effects].index(effect.name)]
        return self.base_check.intervals[effect.name]

    @property
    def closed_loop_confirmed(self) -> bool:
        """The augmented model also free-runs closer to the measurement (geometric mean of the
        fitted signals' MSE ratios below 1) -- or nothing was added."""
        if not self.effects:
            return True
        b, a = self.mse_before["closed_loop"], self.mse_after["closed_loop"]
        logs = [np.log(a[s] / b[s]) for s in self.meas.signals if b.get(s) and a.get(s)]
        return bool(logs) and float(np.mean(logs)) < 0.0


def _errors(meas: Measurement, spec: PlantSpec, command: np.ndarray,
            sims: dict[str, SimResult]) -> dict[str, dict[str, float]]:
    """The errors of the model as fitted: after a reset, of the angle in the counter's frame, with the
    counter's zero its start was estimated with (the simulation's angle is about the springs' rest)."""
    kin, zero = meas.kinematics, meas.x0(spec, command).angle_offset
    if zero:
        kin = kin.assign(theta_rad=kin["theta_rad"] - zero)
    return {way: mse_only(signal_errors(kin, sims[way])) for way in WAYS}


def discover(kin: pd.DataFrame, config: RigConfig, name: str, after_reset: bool = False,
             zero_samples: dict[str, int] | None = None, model_declared: bool = True,
             policy: DiscoveryPolicy = DEFAULT_POLICY) -> Discovery:
    """The whole workflow on one kinematics table (no I/O); ``after_reset``: the table is a segment
    that began after a board reset (its angle's zero is wherever the counter restarted);
    ``zero_samples``: per signal whose zero ingest read off rest readings, how many;
    ``model_declared``: the rig's TOML sets its [model] (else what was found is checked with the base
    free, ``base_free``); ``policy``: the thresholds the search decides by."""
    t0 = time.perf_counter()
    sel = select(measurement_from_kinematics(kin, config, name, angle_reference_known=not after_reset,
                                             zero_samples=zero_samples), policy=policy, exchange=model_declared)
    sel = refit_on_more_samples(sel, kin, config, name, zero_samples)
    meas = sel.meas
    check = None
    if not model_declared and (sel.effects or sel.verdict == "unexplained"):
        check = check_with_base_free(meas, sel.effects, candidate_names(meas), policy, spent=sel.work)
    effects = sel.effects if check is None else check.kept
    base = meas.simulate_ways(meas.spec(), sel.command_before)
    final = meas.simulate_ways(meas.spec(effects), sel.command_after) if effects else base
    over = check_declared(meas, sel.floor, policy) if sel.verdict == "unexplained" and not sel.effects else []
    sig_b = signatures(meas, base["replay"], sel.floor)
    sig_a = signatures(meas, final["replay"], sel.floor)
    return Discovery(meas=meas, selection=sel, base=base, final=final,
                     mse_before=_errors(meas, meas.spec(), sel.command_before, base),
                     mse_after=_errors(meas, meas.spec(sel.effects),
                                      sel.command_after if sel.effects else sel.command_before, final),
                     localisation_before=describe(sig_b, sel.floor), localisation_after=describe(sig_a, sel.floor),
                     tables_before=binned(meas, base["replay"], sel.floor),
                     tables_after=binned(meas, final["replay"], sel.floor),
                     seconds=time.perf_counter() - t0, declared_too_large=over, base_check=check)


def merge_effects(existing: tuple[Effect, ...], found: tuple[Effect, ...]) -> tuple[Effect, ...]:
    """The augmented model's whole effect list: the rig's own effects plus what was found, one entry
    per name (a TOML table cannot repeat a key), two of a kind combined as the effect says
    (``Effect.combine``: as stacking them in ``build_spec`` does)."""
    merged: dict[str, Effect] = {e.name: e for e in existing}
    for e in found:
        merged[e.name] = merged[e.name].combine(e) if e.name in merged else e
    return tuple(merged.values())


def augmented_effects(d: "Discovery") -> tuple[Effect, ...]:
    return merge_effects(d.meas.config.effects, d.effects)


def _effect_json(e: Effect, span: tuple[float, float], sel: Selection) -> dict:
    out = e.to_json()
    out["interval"] = {e.PARAMS[0].name: list(span)}
    out["round"] = next((a.round for rnd in sel.rounds for a in rnd
                         if getattr(a, "accepted", False) and a.fit.name == e.name), None)
    return out


def _onset_shift(d: Discovery) -> dict | None:
    """How far the fitted motor start moved from the inferred one (None when the command was logged)."""
    k0 = d.meas.onset
    if k0 is None:
        return None
    first = lambda c: int(np.flatnonzero(c != 0)[0])  # noqa: E731
    return {"inferred": k0, "base": first(d.selection.command_before) - k0,
            "augmented": first(d.selection.command_after) - k0}


def unexplained_text(d: Discovery) -> list[str]:
    """Where the structure that no candidate removes lives."""
    sel = d.selection
    left = {s: round(v, 1) for s, v in sel.excess_after.items()}
    lines = [f"structure left above the noise floor (in noise variances): {left}"]
    for o in d.declared_too_large:
        where = "[model]" if o["name"] == "model.b" else "[effects]"
        lines.append(f"the rig's TOML may overstate {o['name']}: its {where} {o['parameter']} = {o['declared']:.4g} "
                     f"explains the data at {o['fitted']:.4g} (structure left {max(o['structure_left'].values()):.1f} "
                     f"noise variances); effects only add, so this is for you to correct")
    return lines + d.localisation_after


def discovery_json(d: Discovery, recording: str) -> dict:
    """The object ``pdr discover --json`` prints (docs/FORMAT.md) plus the evidence behind it."""
    sel = d.selection
    candidates = [a.to_json() for rnd in sel.rounds for a in rnd]
    out = {
        "recording": recording,
        "run": d.meas.name,
        "effects": [_effect_json(e, d.interval_of(e), sel) for e in d.effects],
        "verdict": d.verdict,
        "mse_before": d.mse_before["replay"],
        "mse_after": d.mse_after["replay"],
        "mse_before_closed_loop": d.mse_before["closed_loop"],
        "mse_after_closed_loop": d.mse_after["closed_loop"],
        "mse_way": ("replay: the logged command drives the model, as validation's replay way; "
                    "*_closed_loop: the model's own guard decides (the paper's free run), which jumps "
                    "when a simulated switch slips by one control period"),
        "closed_loop_confirmed": d.closed_loop_confirmed,
        "candidates": candidates,
        "near_tie": sel.near_tie,
        "noise_floor": sel.floor,
        "structure_before": sel.excess_before,
        "structure_after": sel.excess_after,
        "localisation_before": d.localisation_before,
        "localisation_after": d.localisation_after,
        "localisation_tables": {"before": d.tables_before, "after": d.tables_after,
                                "unit": "residual RMS in noise standard deviations (1 = at the noise floor)"},
        "effects_toml": effects_toml_snippet(augmented_effects(d)) if d.effects else "",
        "dir_source": d.meas.dir_source,
        "samples": {"used": d.meas.n, "in_recording": d.meas.samples_in_recording,
                    "values_refitted_on": sel.refit_samples or d.meas.n},
        "motor_start_shift_samples": _onset_shift(d),
        "simulations": sel.simulations,
        "work": sel.work,                  # simulated samples, start estimates included (DiscoveryPolicy.work_budget)
    }
    if d.base_check is not None:
        out["base_free_check"] = d.base_check.to_json()
    if d.hint:
        out["hint"] = d.hint
    if d.verdict == "unexplained":
        out["unexplained"] = unexplained_text(d)
        out["declared_too_large"] = d.declared_too_large
    if d.selection.pruned:
        out["pruned"] = {"effects": d.selection.pruned,
                         "why": "accepted in an earlier round, then dropped: with the later effects refitted "
                                "its interval includes 'no effect', or, a sensor's zero, the other signals keep "
                                "structure, and a plant the model gets wrong moves that sensor's mean too"}
    if d.selection.stopped_for_time:
        out["stopped_for_time"] = ("the work budget was spent before the search ended: a further round, or a "
                                   "round's later candidates, were not tried (simulated samples, start estimates "
                                   "included: about 7 CPU s for all searches on the recording, more where its starts are event-driven)")
    if d.selection.failures:
        out["simulation_failures"] = len(d.selection.failures)
    return finite_or_none(out)


# ------------------------------------------------------------------ shell

def after_board_reset(segment: dict) -> bool:
    """Whether a run's ingest segment (``runs.ingest_segment``) follows the capture's first: ingest
    starts a segment at each board reset."""
    index = segment.get("index", 0)
    return isinstance(index, int) and index > 0


def zero_samples(segment: dict) -> dict[str, int]:
    """How many rest readings the current's zero is the mean of, when ingest read it off the data."""
    zero = segment.get("current_zero")
    zero = zero if isinstance(zero, dict) else {}
    rest = zero.get("samples") if zero.get("method", "configured") != "configured" else None
    return {"current": rest} if isinstance(rest, int) and rest > 0 else {}


def segment_to_discover(runs: list[RunPaths], policy: DiscoveryPolicy = DEFAULT_POLICY) -> RunPaths:
    """One recording, one answer: of a capture's segments (a board reset starts one), the first,
    unless a later one has more than ``policy.later_segment_factor`` times its samples.  The first segment's
    counter started where the springs hold the pinion; after a reset it restarts wherever the pinion
    then is, so where the springs rest in its count is a nuisance that a constant load torque only
    moves (such a segment tells Tl - k * offset, not Tl), and every model's start and offset are
    fitted there (costlier: one search run, no further starts, ``search._search``)."""
    import pyarrow.parquet as pq

    def samples(paths: RunPaths) -> int:
        return pq.ParquetFile(paths.kinematics).metadata.num_rows if paths.kinematics.is_file() else 0

    sizes = [samples(p) for p in runs]
    longest = max(range(len(runs)), key=sizes.__getitem__)
    return runs[longest] if sizes[longest] > policy.later_segment_factor * sizes[0] else runs[0]


def discover_run(paths: RunPaths, recording: str | None = None) -> tuple[Discovery, dict]:
    """Discovery on one processed (ingested and derived) run."""
    config = load_config(paths)
    kin, left_out = before_a_gap(load_kinematics(paths), config.controller.period_s)
    segment = ingest_segment(paths)
    d = discover(kin, config, paths.name, after_reset=after_board_reset(segment),
                 zero_samples=zero_samples(segment), model_declared=declared_model(config_sources(paths)))
    doc = discovery_json(d, recording if recording is not None else str(paths.root))
    if left_out:
        doc["left_out"] = left_out
    return d, doc


def before_a_gap(kin: pd.DataFrame, period_s: float) -> tuple[pd.DataFrame, str | None]:
    """The samples before the first gap of more than ``MAX_LOST_ROWS`` periods (a paused capture, a
    timestamp glitch), and what was left out: across a gap the rig's state is unknown (the sketch went
    on deciding), and stepping each candidate's non-smooth plant over days of it took minutes."""
    t = column(kin, "t_s", dtype=float)
    gaps = np.flatnonzero(np.diff(t) > MAX_LOST_ROWS * period_s)
    if not len(gaps):
        return kin, None
    k = int(gaps[0]) + 1
    return kin.iloc[:k].reset_index(drop=True), (
        f"the {len(t) - k} samples from t = {t[k]:.6g} s on, after a gap of {t[k] - t[k - 1]:.6g} s with no "
        f"sample (more than {MAX_LOST_ROWS} sample periods: not rows lost over serial)")
