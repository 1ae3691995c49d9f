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


def without_table(text: str, table: str = "effects") -> str:
    """``text`` minus every ``[table]`` / ``[table.*]`` table (header and body)."""
    out, skipping = [], False
    for line in text.splitlines():
        m = _HEADER.match(line)
        if m:
            skipping = m.group(1).split(".")[0].strip("\"' ") == table
        if not skipping:
            out.append(line)
    return "\n".join(out).rstrip() + "\n" if any(x.strip() for x in out) else ""


def replace_table(target: Path, table: str, snippet: str, layers: list[Path] | None = None,
                  hint: str = "") -> Path:
    """Replace ``[table]`` of the TOML ``target`` by ``snippet`` (the rest kept as written), checked
    through the rig configuration (with ``layers`` when given) before it replaces the file, atomically."""
    current = target.read_text(encoding="utf-8") if target.is_file() else ""
    if re.search(rf"^\s*{table}\s*[.=]", current, flags=re.M):
        raise PdrError(f"{table} is set with dotted keys at the top level; edit the file by hand"
                       + (f" ({hint})" if hint else ""), path=target)
    body = without_table(current, table)
    new = (body + "\n" if body else "") + snippet
    with tempfile.TemporaryDirectory() as tmp:
        trial = Path(tmp) / target.name
        trial.write_text(new, encoding="utf-8")
        resolve_config([p if p != target else trial for p in (layers or [target])])
    write_text(target, new)
    return target


def adopt(csv_path: Path, effects: tuple[Effect, ...]) -> Path:
    """Write ``effects`` as the ``[effects]`` of ``raw/<name>.toml`` beside ``csv_path``; returns its path."""
    csv_path = Path(csv_path)
    target = csv_path.with_suffix(".toml")
    layers = config_layers_for(csv_path)
    return replace_table(target, "effects", effects_toml_snippet(effects),
                         layers if target in layers else [*layers, target],
                         hint="the discovered table is in the discovery output's effects.toml")
