"""README's layout section names what the package holds: every folder it names exists, every
subpackage and top-level module of metalens_cli is named, and so is every top-level folder it
lists beside the package."""

import re
from pathlib import Path

ROOT = Path(__file__).parents[1]
PACKAGE = ROOT / "metalens_cli"


def layout_block() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    section = text[text.index("## Layout") :]
    return section[section.index("```") + 3 : section.index("```", section.index("```") + 3)]


def test_layout_names_every_subpackage_and_only_those():
    named = set(re.findall(r"metalens_cli/(\w+)/", layout_block()))
    actual = {p.name for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").exists()}
    assert named == actual


def test_layout_names_every_top_level_module():
    block = layout_block()
    modules = {p.name for p in PACKAGE.glob("*.py")} - {"__main__.py"}
    assert [m for m in sorted(modules) if m not in block] == []


def test_folders_beside_the_package_exist():
    last = [line for line in layout_block().strip().splitlines() if not line.startswith("metalens_cli")]
    folders = [name.rstrip("/") for line in last for name in line.split()]
    assert folders and [f for f in folders if not (ROOT / f).is_dir()] == []
