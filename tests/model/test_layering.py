"""The model is what the stages import, never the other way round (docs/ARCHITECTURE.md)."""

import ast
from pathlib import Path

import pipeline.model

STAGES = ("api", "cluster", "derive", "discover", "ingest", "record", "rig", "run", "simulate_cli", "validate")


def test_no_model_module_imports_a_stage():
    root = Path(pipeline.model.__file__).parent
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            found += [f"{path.relative_to(root)}: {n}" for n in names
                      if n.split(".")[:2] in (["pipeline", s] for s in STAGES)]
    assert len(list(root.rglob("*.py"))) >= 10
    assert found == []
