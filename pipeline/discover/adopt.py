"""Adopt discovered effects into a recording's sidecar TOML -- only when the user asks (``--adopt``).

The rest of the file is kept as written (comments included): only the
``[effects]`` table is replaced, with the augmented model's whole effect list,
because a TOML layer's ``[effects]`` replaces the list of the layers below it
(``pipeline.config``).  The result is parsed back through the rig
configuration checks before it replaces the file, atomically.
"""

from __future__ import annotations

import re
import tempfile
from pathlib import Path

from pipeline.config import config_layers_for, effects_toml_snippet, resolve_config
from pipeline.errors import PdrError
from pipeline.io.atomic import write_text
from pipeline.model.effects import Effect

_HEADER = re.compile(r"^\s*\[\[?\s*([A-Za-z0-9_.\-\"' ]+?)\s*\]\]?\s*(#.*)?$")


def without_effects_table(text: str) -> str:
    """``text`` minus every ``[effects]`` / ``[effects.*]`` table (header and body)."""
    out, skipping = [], False
    for line in text.splitlines():
        m = _HEADER.match(line)
        if m:
            skipping = m.group(1).split(".")[0].strip("\"' ") == "effects"
        if not skipping:
            out.append(line)
    return "\n".join(out).rstrip() + "\n" if any(x.strip() for x in out) else ""


def adopted_text(current: str, effects: tuple[Effect, ...]) -> str:
    """The sidecar's new text: the old one without its effects table, then the new table."""
    body = without_effects_table(current)
    return (body + "\n" if body else "") + effects_toml_snippet(effects)


def adopt(csv_path: Path, effects: tuple[Effect, ...]) -> Path:
    """Write ``effects`` as the ``[effects]`` of ``raw/<name>.toml`` beside ``csv_path``; returns its path."""
    csv_path = Path(csv_path)
    target = csv_path.with_suffix(".toml")
    current = target.read_text(encoding="utf-8") if target.is_file() else ""
    if "effects" in current and re.search(r"^\s*effects\s*[.=]", current, flags=re.M):
        raise PdrError("effects are set with dotted keys at the top level; edit the file by hand "
                       "(the discovered table is in the discovery output's effects.toml)", path=target)
    new = adopted_text(current, effects)
    with tempfile.TemporaryDirectory() as tmp:     # check the new layer stack before touching the file
        trial = Path(tmp) / target.name
        trial.write_text(new, encoding="utf-8")
        layers = [p if p != target else trial for p in config_layers_for(csv_path)]
        resolve_config(layers if trial in layers else [*layers, trial])
    write_text(target, new)
    return target
