"""``pdr gate``: per-run MSE thresholds, so a change that degrades validation fails CI.

Thresholds live in a TOML file (``raw/thresholds.toml`` by default): defaults
per way of simulating (``replay``: the continuous dynamics; ``closed_loop``:
with the simulator's own switching) and signal, plus per-recording overrides::

    [default.replay]          # MSE: theta rad^2, omega (rad/s)^2, current A^2
    theta = 1e-3
    [runs."bench-0001".replay]
    omega = 0.2

A signal without a threshold is reported but not gated.  A run counts as
failed when any gated MSE exceeds its threshold, and also when it has no
``validation.json`` (the pipeline did not get that far), when that file is not
what validate writes, or when it holds no figure to gate: a gate that cannot
fail is worse than none.  For the same reason a thresholds file naming a run
that ``processed/`` does not hold fails the gate, naming it.

Without a thresholds file the gate uses ``BUILTIN_DEFAULTS`` (the shipped
``raw/thresholds.toml``'s defaults, which a test keeps equal): a new project
is gated from its first run, near the virtual rig's noise floor for replay
and loosely for the closed loop (see that file for where the numbers come from).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from pipeline.config import read_toml
from pipeline.errors import ConfigError, PdrError

WAYS = ("replay", "closed_loop")
SIGNALS = ("theta", "omega", "current")
UNITS = {"theta": "rad^2", "omega": "(rad/s)^2", "current": "A^2"}

Thresholds = dict[str, dict[str, float]]        # way -> signal -> MSE threshold

# MSE per way and signal when no thresholds file exists (units: UNITS).
BUILTIN_DEFAULTS: Thresholds = {
    "replay": {"theta": 1e-5, "omega": 5e-4, "current": 1.5e-3},
    "closed_loop": {"theta": 0.3, "omega": 1.0, "current": 1.5e-2},
}
BUILTIN_SOURCE = "built-in defaults"


@dataclass(frozen=True)
class ThresholdFile:
    default: Thresholds
    runs: dict[str, Thresholds]
    source: str

    def for_run(self, run: str) -> Thresholds:
        """Defaults overlaid with the run's own table (a segment ``x-seg2`` also matches ``x``)."""
        out = {way: dict(self.default.get(way, {})) for way in WAYS}
        stem = run.rsplit("-seg", 1)[0]
        for key in (stem, run) if stem != run else (run,):
            for way, table in self.runs.get(key, {}).items():
                out[way].update(table)
        return out


def _ways(table: object, source: str, where: str) -> Thresholds:
    if not isinstance(table, dict):
        raise ConfigError("expected a table with [..replay] and/or [..closed_loop]", path=source, key=where)
    out: Thresholds = {}
    for way, signals in table.items():
        if way not in WAYS:
            raise ConfigError(f"unknown way, expected one of {', '.join(WAYS)}", path=source, key=f"{where}.{way}")
        if not isinstance(signals, dict):
            raise ConfigError("expected a table of MSE thresholds", path=source, key=f"{where}.{way}")
        out[way] = {}
        for sig, value in signals.items():
            key = f"{where}.{way}.{sig}"
            if sig not in SIGNALS:
                raise ConfigError(f"unknown signal, expected one of {', '.join(SIGNALS)}", path=source, key=key)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0 \
                    or not math.isfinite(value):
                raise ConfigError(f"expected a positive MSE threshold in {UNITS[sig]}, got {value!r}",
                                  path=source, key=key)
            out[way][sig] = float(value)
    return out


def parse_thresholds(data: dict, source: str) -> ThresholdFile:
    unknown = [k for k in data if k not in ("default", "runs")]
    if unknown:
        raise ConfigError("unknown section, expected [default.<way>] or [runs.\"<run>\".<way>]",
                          path=source, key=unknown[0])
    runs = data.get("runs", {})
    if not isinstance(runs, dict):
        raise ConfigError("expected a table of runs", path=source, key="runs")
    return ThresholdFile(default=_ways(data.get("default", {}), source, "default"),
                         runs={name: _ways(t, source, f"runs.{name}") for name, t in runs.items()},
                         source=source)


def builtin_thresholds() -> ThresholdFile:
    return ThresholdFile(default={w: dict(v) for w, v in BUILTIN_DEFAULTS.items()}, runs={}, source=BUILTIN_SOURCE)


def load_thresholds(path: Path | None, *, missing_ok: bool = False) -> ThresholdFile:
    """The thresholds in ``path``; ``BUILTIN_DEFAULTS`` when there is none and ``missing_ok``
    (the default location), a refusal when a file named by the user is missing."""
    if path is None or (missing_ok and not Path(path).exists()):
        return builtin_thresholds()
    if not Path(path).is_file():
        raise PdrError("thresholds file not found (expected TOML with [default.replay] etc.)", path=path)
    return parse_thresholds(read_toml(Path(path)), str(path))


@dataclass(frozen=True)
class Check:
    run: str
    way: str
    signal: str
    mse: float | None
    threshold: float | None

    @property
    def passed(self) -> bool:
        return self.threshold is None or (self.mse is not None and self.mse <= self.threshold)

    @property
    def margin(self) -> float | None:
        """Threshold minus MSE as a share of the threshold: negative when exceeded."""
        if self.threshold is None or self.mse is None:
            return None
        return 1.0 - self.mse / self.threshold

    def margin_text(self) -> str:
        """How far from the threshold, as a ratio: "19,350x over", "3.2x under" ("-" when not gated)."""
        if self.threshold is None or self.mse is None:
            return "-"
        if self.mse == 0.0:
            return "MSE 0"
        ratio = self.mse / self.threshold
        over = ratio > 1.0
        r = ratio if over else 1.0 / ratio
        return (f"{r:,.0f}x" if r >= 100 else f"{r:.3g}x") + (" over" if over else " under")


@dataclass(frozen=True)
class RunVerdict:
    run: str
    checks: tuple[Check, ...]
    problem: str | None = None      # set when the run could not be checked at all
    skipped: tuple[str, ...] = ()   # ways not run on this recording (no encoder: validation.json says why)

    @property
    def passed(self) -> bool:
        return self.problem is None and all(c.passed for c in self.checks)

    def failures(self) -> list[str]:
        if self.problem:
            return [self.problem]
        return [f"{c.way} {c.signal} MSE {c.mse:.4g} > {c.threshold:.4g} {UNITS[c.signal]}"
                if c.mse is not None else f"{c.way} {c.signal} MSE missing"
                for c in self.checks if not c.passed]


class MalformedValidation(ValueError):
    """A ``validation.json`` whose shape is not what validate writes: the message says where and what was expected."""


def _block(doc: dict, key: str) -> dict:
    value = doc.get(key)
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise MalformedValidation(f"'{key}': expected an object, got {type(value).__name__}")
    return value


def _mse(entry: object, where: str) -> float | None:
    """One signal's MSE as a number (None when absent); anything else is a malformed document."""
    if not isinstance(entry, dict):
        raise MalformedValidation(f"'{where}': expected an object with 'mse', got {type(entry).__name__}")
    mse = entry.get("mse")
    if mse is None:
        return None
    if isinstance(mse, bool) or not isinstance(mse, (int, float)):
        raise MalformedValidation(f"'{where}.mse': expected a number (MSE in {UNITS[where.rsplit('.', 1)[1]]}), "
                                  f"got {mse!r:.40}")
    return float(mse)


def check_run(validation: dict, thresholds: Thresholds, run: str | None = None) -> RunVerdict:
    """Pure: one run's validation figures against its thresholds (``run``: its name, else the document's).

    Raises ``MalformedValidation`` when the document is not shaped as validate writes it.  A run with
    no figure to check fails, unless validation.json says why each way was skipped (no encoder)."""
    if not isinstance(validation, dict):
        raise MalformedValidation(f"expected a JSON object, got {type(validation).__name__}")
    run = run or validation.get("run")
    if not isinstance(run, str):
        raise MalformedValidation(f"'run': expected the run's name, got {run!r:.40}")
    checks = []
    for way in WAYS:
        signals = _block(_block(validation, way), "signals")
        for sig in SIGNALS:
            if signals.get(sig) is None:      # not logged (e.g. no current sensor): nothing to gate
                continue
            checks.append(Check(run, way, sig, _mse(signals[sig], f"{way}.signals.{sig}"),
                                thresholds.get(way, {}).get(sig)))
    skipped = tuple(way for way in WAYS if way in _block(validation, "skipped"))
    if not checks and len(skipped) < len(WAYS):
        return RunVerdict(run, (), problem="validation.json holds no MSE figures to gate "
                                           "(expected replay/closed_loop signals; re-run pdr validate)")
    return RunVerdict(run, tuple(checks), skipped=skipped)


def run_dirs(processed: Path) -> list[Path]:
    """Every run folder of ``processed/`` (one per ingested segment), sorted by name."""
    if not processed.is_dir():
        return []
    return sorted(p for p in processed.iterdir()
                  if p.is_dir() and not p.name.startswith(".") and (p / "rig.json").is_file())


def _verdict(root: Path, thresholds: ThresholdFile) -> RunVerdict:
    """One run folder's verdict; a validation.json that cannot be read or is malformed fails that run alone."""
    path = root / "validation.json"
    if not path.is_file():
        return RunVerdict(root.name, (), problem="no validation.json (pipeline failed before validate)")
    try:
        validation = json.loads(path.read_bytes().decode("utf-8"))
    except OSError as err:
        return RunVerdict(root.name, (), problem=f"{path}: cannot read it: {err.strerror}")
    except UnicodeDecodeError:
        return RunVerdict(root.name, (), problem=f"{path}: not UTF-8 text (expected validate's JSON)")
    except json.JSONDecodeError as err:
        return RunVerdict(root.name, (), problem=f"{path}: not valid JSON at line {err.lineno} column {err.colno}: "
                                                 f"{err.msg} (expected validate's JSON; re-run pdr validate)")
    except RecursionError:
        return RunVerdict(root.name, (), problem=f"{path}: nested too deeply (expected validate's JSON)")
    try:
        return check_run(validation, thresholds.for_run(root.name), run=root.name)
    except MalformedValidation as err:
        return RunVerdict(root.name, (), problem=f"{path}: {err} (re-run pdr validate)")


def unmatched_runs(thresholds: ThresholdFile, runs: list[str]) -> list[str]:
    """The runs a thresholds file names that match no run folder (nor the stem of a segment's):
    a misspelt name would otherwise gate nothing, silently."""
    names = set(runs) | {run.rsplit("-seg", 1)[0] for run in runs}
    return [name for name in thresholds.runs if name not in names]


def gate(processed: Path, thresholds: ThresholdFile) -> list[RunVerdict]:
    """Every run in ``processed/`` against its thresholds (a run without validation fails), then a failing
    verdict for each run the thresholds name that is not there."""
    verdicts = [_verdict(root, thresholds) for root in run_dirs(processed)]
    if not verdicts:
        return []
    return verdicts + [RunVerdict(name, (), problem=f"{thresholds.source} has thresholds for this run, "
                                                    f"but {processed} holds no such run (a misspelt name?)")
                       for name in unmatched_runs(thresholds, [v.run for v in verdicts])]
