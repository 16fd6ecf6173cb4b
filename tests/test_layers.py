"""Imports point downward: cli → design → plotting → imaging/analysis → io → optics. A module
imports from its own layer or a lower one, and the two packages that share a layer do not both
import each other; optics, the physics core, imports nothing of the package above it. Every public
function, class and method (a name not starting with ``_``) has a docstring."""

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


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(path): path for path in PACKAGE.rglob("*.py")}


def module_imports() -> dict[str, set[str]]:
    """Module → the package's modules it imports, at module level or inside functions alike
    (an import inside a function still makes the two modules need each other)."""
    graph = {}
    for name, path in MODULES.items():
        targets = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("metalens_cli"):
                for alias in node.names:
                    full = f"{node.module}.{alias.name}"
                    targets.add(full if full in MODULES else node.module)
            elif isinstance(node, ast.Import):
                targets |= {a.name for a in node.names if a.name.startswith("metalens_cli")}
        graph[name] = {t for t in targets if t in MODULES and t != name}
    return graph


def test_no_module_imports_itself_through_a_circle():
    graph = module_imports()
    circles = []
    for start in graph:  # a path from a module's imports back to it
        seen, frontier = set(), list(graph[start])
        while frontier:
            module = frontier.pop()
            if module == start:
                circles.append(start)
                break
            if module not in seen:
                seen.add(module)
                frontier += graph[module]
    assert circles == []


def test_no_module_imports_the_package_root():
    """The root (``metalens_cli/__init__.py``) is the API that imports everything; a module that
    imports a name from it (``__version__`` was one) points back up. Its submodules are fine."""
    upward = [
        name for name, imported in module_imports().items() if name != "metalens_cli" and "metalens_cli" in imported
    ]
    assert upward == []


def undocumented() -> list[str]:
    """``file:line:name`` of every public module-level function or class, and every public method
    of a public class, without a docstring (a name starting with ``_`` is private)."""
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        where = path.relative_to(PACKAGE.parent)
        for node in ast.parse(path.read_text(encoding="utf-8")).body:
            if not isinstance(node, (ast.FunctionDef, ast.ClassDef)) or node.name.startswith("_"):
                continue
            if not ast.get_docstring(node):
                missing.append(f"{where}:{node.lineno}:{node.name}")
            if isinstance(node, ast.ClassDef):
                missing += [
                    f"{where}:{method.lineno}:{node.name}.{method.name}"
                    for method in node.body
                    if isinstance(method, ast.FunctionDef)
                    and not method.name.startswith("_")
                    and not ast.get_docstring(method)
                ]
    return missing


def test_every_public_definition_has_a_docstring():
    missing = undocumented()
    assert missing == [], f"{len(missing)} public definitions lack a docstring:\n" + "\n".join(missing)
