"""Imports point downward: cli → design → plotting → imaging/analysis → io → optics. A module
imports from its own layer or a lower one, and the two packages that share a layer do not both
import each other; optics, the physics core, imports nothing of the package above it."""

import ast
from pathlib import Path

PACKAGE = Path(__file__).parents[1] / "metalens_cli"
RANK = {"cli": 6, "design": 5, "plotting": 4, "imaging": 3, "analysis": 3, "io": 2, "optics": 1}


def imports():
    """(importing layer, imported layer, file, module) for every import inside the package."""
    for path in PACKAGE.rglob("*.py"):
        layer = path.relative_to(PACKAGE).parts[0]
        if layer not in RANK:
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = (
                [node.module]
                if isinstance(node, ast.ImportFrom) and node.module
                else [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else []
            )
            for name in names:
                parts = name.split(".")
                if parts[0] == "metalens_cli" and len(parts) > 1 and parts[1] in RANK:
                    yield layer, parts[1], path.relative_to(PACKAGE), name


def test_imports_point_downward():
    upward = [f"{path} imports {name}" for layer, other, path, name in imports() if RANK[other] > RANK[layer]]
    assert upward == []


def test_layers_that_share_a_rank_do_not_import_each_other_both_ways():
    pairs = {(layer, other) for layer, other, _, _ in imports() if layer != other and RANK[layer] == RANK[other]}
    assert not any((other, layer) in pairs for layer, other in pairs), sorted(pairs)
