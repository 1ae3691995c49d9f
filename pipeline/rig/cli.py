"""``pdr rig``: the virtual rig writes synthetic recordings, with chosen hidden effects and serial artefacts."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import typer

from pipeline.errors import PdrError
from pipeline.rig.serial import TERMINAL_STAMPS

app = typer.Typer(help="The virtual rig: synthetic recordings with hidden effects and serial artefacts.",
                  no_args_is_help=True)

_FLAGS = {"crlf": ("crlf", True), "bom": ("bom", True), "partial": ("partial_first_line", True),
          "no-header": ("header", False), "no-dir": ("dir_column", False),
          "ide": ("ide_prefix", "classic"), "ide2": ("ide_prefix", "ide2")}
_COUNTS = {"comments": "comments", "blank": "blank_lines", "garbled": "garbled", "dropped": "dropped"}
ARTEFACT_HELP = ("crlf, bom, partial, no-header, no-dir, ide (12:34:56.789 -> ), ide2 (18:2:13.521 -> ), "
                 "terminal=STYLE (another terminal's stamps: " + "|".join(TERMINAL_STAMPS) + "), stamp-digits=N, "
                 "comments=N, blank=N, garbled=N, dropped=N, reset=S (board reset S seconds in), "
                 "reset-gap=S, time=ms|us|s, columns=T,COUNTS,ADC,DIR")


def parse_effect(text: str, option: str = "--effect"):
    """'coulomb_friction:Tc=6e-4' or 'name:p=v,q=w' -> Effect (MODEL.md names and units)."""
    from pipeline.model.effects import make_effect

    name, sep, rest = text.partition(":")
    if not sep or not rest:
        raise PdrError(f"expected NAME:PARAM=VALUE (e.g. coulomb_friction:Tc=6e-4), got {text!r}", key=option)
    params: dict[str, float] = {}
    for item in rest.split(","):
        key, eq, value = item.partition("=")
        try:
            params[key.strip()] = float(value)
        except ValueError:
            raise PdrError(f"expected PARAM=NUMBER in {text!r}, got {item!r}", key=option) from None
        if not eq:
            raise PdrError(f"expected PARAM=NUMBER in {text!r}, got {item!r}", key=option)
    return make_effect(name.strip(), params, where=option)


def parse_artefacts(items: list[str]):
    """Artefact words (see ARTEFACT_HELP) -> serial.Artefacts."""
    from pipeline.rig.serial import Artefacts

    kw: dict[str, Any] = {}
    for item in items:
        word, eq, value = item.partition("=")
        try:
            if word in _FLAGS and not eq:
                field, val = _FLAGS[word]
                kw[field] = val
            elif word in _COUNTS and eq:
                kw[_COUNTS[word]] = int(value)
            elif word in ("reset", "reset-gap") and eq:
                kw["reset_after_s" if word == "reset" else "reset_gap_s"] = float(value)
            elif word == "terminal" and eq:
                kw["terminal"] = value
            elif word == "stamp-digits" and eq:
                kw["stamp_digits"] = int(value)
            elif word == "time" and eq:
                kw["time_unit"] = value
            elif word == "columns" and eq:
                kw["column_names"] = tuple(v.strip() for v in value.split(","))
            else:
                raise PdrError(f"unknown artefact {item!r}, expected one of: {ARTEFACT_HELP}", key="--artefact")
        except ValueError as err:
            raise PdrError(f"bad value in {item!r}: {err}", key="--artefact") from None
    try:
        return Artefacts(**kw)
    except ValueError as err:
        raise PdrError(str(err), key="--artefact") from None


@app.command("make")
def make(
    name: Annotated[str, typer.Argument(help="Recording name: writes NAME.csv, NAME.toml, truth/NAME.truth.*")],
    out: Annotated[Path, typer.Option(help="Folder to write into.")] = Path("raw"),
    effect: Annotated[list[str], typer.Option(
        help="Hidden effect in the plant, NAME:PARAM=VALUE (repeatable), e.g. backlash:gap=0.05.")] = [],
    declare: Annotated[list[str], typer.Option(
        help="Effect the rig has AND its TOML declares in its effects table (repeatable).")] = [],
    config: Annotated[Path | None, typer.Option(
        help="Rig TOML the user believes (default: the paper's rig); written back as NAME.toml.")] = None,
    seed: Annotated[int, typer.Option(help="Random seed: same seed, same bytes.")] = 0,
    duration: Annotated[float, typer.Option(help="Active logging time after the pre-roll, in s.")] = 24.95,
    pre_roll: Annotated[float, typer.Option(help="Motor-off time before the run, in s (rest data for zero_v = \"auto\").")] = 1.0,
    noise: Annotated[float, typer.Option(help="Current sensor noise sigma in V (default: one ADC step).")] = 5.0 / 1024,
    zero_v: Annotated[str, typer.Option(help="zero_v written to the TOML: calibrated, auto or nominal.")] = "calibrated",
    artefact: Annotated[list[str], typer.Option(help=f"Serial artefact (repeatable): {ARTEFACT_HELP}.")] = [],
) -> None:
    """Record one synthetic run of the virtual rig.

    Example: pdr rig make hidden_backlash --effect backlash:gap=0.05 --artefact ide2 --artefact crlf --seed 7
    """
    from pipeline.rig.recording import check_name, write_recording

    check_name(name)
    rec = recording_from_options(effect, declare, config, seed, duration, artefact,
                                 pre_roll=pre_roll, noise=noise, zero_v=zero_v)
    paths = write_recording(rec, out, name)
    typer.echo(summary_line(name, rec))
    for p in paths.values():
        typer.echo(f"  wrote {p}")


def recording_from_options(effect: list[str], declare: list[str], config: Path | None, seed: int, duration: float,
                           artefact: list[str], *, pre_roll: float = 1.0, noise: float = 5.0 / 1024,
                           zero_v: str = "calibrated"):
    """The virtual rig's recording for the options of ``make`` and ``serve`` (a bad option is a PdrError)."""
    from dataclasses import replace

    from pipeline.config import default_config, resolve_config
    from pipeline.rig.recording import RigSetup, make_recording

    cfg = resolve_config([config]) if config is not None else default_config()
    if declare:
        cfg = replace(cfg, effects=(*cfg.effects, *(parse_effect(d, "--declare") for d in declare)))
    try:
        setup = RigSetup(effects=tuple(parse_effect(e) for e in effect), config=cfg, duration_s=duration,
                         pre_roll_s=pre_roll, noise_v=noise, zero_v=zero_v,
                         artefacts=parse_artefacts(artefact), seed=seed)
        return make_recording(setup)
    except ValueError as err:
        raise PdrError(str(err)) from None


@app.command("serve")
def serve(
    pty: Annotated[bool, typer.Option("--pty", help="Serve through a pseudo-terminal (the only transport).")] = False,
    speed: Annotated[float, typer.Option(help="Play X times faster than the rig's own sample times.")] = 1.0,
    effect: Annotated[list[str], typer.Option(help="Hidden effect in the plant, NAME:PARAM=VALUE (repeatable).")] = [],
    declare: Annotated[list[str], typer.Option(help="Effect the rig has AND its TOML declares (repeatable).")] = [],
    config: Annotated[Path | None, typer.Option(help="Rig TOML the user believes (default: the paper's rig).")] = None,
    seed: Annotated[int, typer.Option(help="Random seed: same seed, same bytes as pdr rig make.")] = 0,
    duration: Annotated[float, typer.Option(help="Active logging time after the pre-roll, in s.")] = 24.95,
    artefact: Annotated[list[str], typer.Option(help=f"Serial artefact (repeatable): {ARTEFACT_HELP}.")] = [],
    toml: Annotated[Path | None, typer.Option(help="Also write the rig's TOML here (e.g. raw/NAME.toml).")] = None,
    wait: Annotated[float, typer.Option(help="Give up when no reader opens the port within S seconds.")] = 600.0,
) -> None:
    """Stream a virtual-rig recording through a pseudo-terminal, as the board would, for pdr record.

    Prints the device path, waits for a reader, sends the capture at the rig's sample times
    (or --speed times faster), then closes the port (to the reader: the board unplugged).

    Example: pdr rig serve --pty --speed 10 --toml raw/demo.toml &   then   pdr record /dev/pts/N --name demo
    """
    import importlib.util

    from pipeline.io.atomic import write_text

    if importlib.util.find_spec("termios") is None:       # Windows: no pseudo-terminals
        raise PdrError("pdr rig serve --pty needs a POSIX pseudo-terminal (Linux, macOS); on Windows a "
                       "virtual COM-port pair (e.g. com0com) and pdr rig make are the way to try pdr record",
                       key="--pty")
    from pipeline.rig.serve import PtyRig, line_schedule, serve as stream

    if not pty:
        raise PdrError("expected --pty (the virtual rig serves through a pseudo-terminal)", key="--pty")
    if speed <= 0:
        raise PdrError(f"expected a speed > 0, got {speed}", key="--speed")
    rec = recording_from_options(effect, declare, config, seed, duration, artefact)
    if toml is not None:
        write_text(toml, rec.toml_text)
    rig = PtyRig()
    typer.echo(rig.path, nl=True)
    typer.echo(f"virtual rig on {rig.path}: {len(rec.csv_bytes)} bytes over "
               f"{float(rec.truth['t_s'].iloc[-1]) / speed:.1f} s once a reader opens it", err=True)
    try:
        if not rig.wait_for_reader(wait):
            raise PdrError(f"no reader opened the port within {wait:g} s", path=rig.path)
        sent = stream(rig, line_schedule(rec), speed)
        rig.drain(timeout_s=10.0)
    finally:
        rig.close()
    typer.echo(f"sent {sent} of {len(rec.csv_bytes)} bytes; port closed", err=True)


@app.command("shipped")
def shipped(
    out: Annotated[Path, typer.Option(help="Folder to write into.")] = Path("raw"),
    check: Annotated[bool, typer.Option(help="Write nothing; exit 1 if a shipped file is missing or stale.")] = False,
) -> None:
    """Regenerate the synthetic recordings shipped in raw/ (byte-identical each time).

    Example: pdr rig shipped --out raw     (or: pdr rig shipped --check)
    """
    from pipeline.rig.shipped import SHIPPED, stale_shipped, write_shipped

    if check:
        stale = stale_shipped(out)
        for path in stale:
            typer.echo(f"stale or missing: {path}")
        if stale:
            raise typer.Exit(1)
        typer.echo(f"{len(SHIPPED)} shipped recordings up to date in {out}")
        return
    for name, paths in write_shipped(out).items():
        typer.echo(f"{name}: {SHIPPED[name][0]}")
        for p in paths.values():
            typer.echo(f"  wrote {p}")


def summary_line(name: str, rec) -> str:
    t = rec.truth
    meta = rec.truth_meta
    hidden = ", ".join(f"{e['name']}({', '.join(f'{k}={v:g}' for k, v in e['parameters'].items())})"
                       for e in meta["hidden_effects"]) or "none"
    switches = int(sum((((t["dir"].shift() * t["dir"]) < 0)).fillna(False)))
    from pipeline.rig.serial import Artefacts

    defaults = vars(Artefacts())
    kinds = [k for k, v in meta["artefacts"]["requested"].items() if v != defaults[k] and k != "reset_gap_s"]
    return (f"{name}: {len(t)} samples in {len(meta['segments'])} segment(s), {switches} switches, "
            f"{meta['n_lines']} lines; hidden effects: {hidden}; artefacts: {', '.join(kinds) or 'none'}")


@app.command("randomise")
def randomise(
    name: Annotated[str, typer.Argument(help="Recording name: writes NAME.csv, NAME.toml, truth/NAME.truth.*")],
    seed: Annotated[int, typer.Option(help="The draw's seed: same seed, same lab, same bytes.")] = 0,
    out: Annotated[Path, typer.Option(help="Folder to write into.")] = Path("raw"),
) -> None:
    """Record one run of a lab drawn at random: its rig's conventions, its capture and its hidden effects
    (pipeline/rig/randomised.py; the truth JSON says what was drawn).

    Example: pdr rig randomise some_lab --seed 42
    """
    import numpy as np

    from pipeline.rig.randomised import randomised_setup
    from pipeline.rig.recording import check_name, make_recording, write_recording

    check_name(name)
    draw = randomised_setup(np.random.default_rng(seed))
    rec = make_recording(draw.setup)
    paths = write_recording(rec, out, name)
    typer.echo(summary_line(name, rec) + (f"; outside the catalogue: {draw.outside}" if draw.outside else ""))
    typer.echo("  " + ", ".join(f"{k}={v}" for k, v in draw.conventions.items()))
    for p in paths.values():
        typer.echo(f"  wrote {p}")
