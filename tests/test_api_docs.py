"""docs/api.md runs: its ```python blocks, top to bottom in one namespace, from the repository
root (as CI does); and the public API is what ``__all__`` says."""

import os
import re
import subprocess
import sys
from pathlib import Path

import metalens_cli as ml

ROOT = Path(__file__).parents[1]


def test_api_page_runs(monkeypatch, capsys):
    blocks = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "api.md").read_text(encoding="utf-8"), flags=re.S)
    assert len(blocks) >= 6
    monkeypatch.chdir(ROOT)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, "docs/api.md", "exec"), namespace)  # noqa: S102  (the page is ours)
    assert "fins" in capsys.readouterr().out


def test_every_public_name_resolves():
    assert [name for name in ml.__all__ if not hasattr(ml, name)] == []
    assert sorted(set(ml.__all__) - {"__version__"}) == sorted(ml._EXPORTS)


def test_import_loads_no_torch():
    code = "import sys, metalens_cli as ml; ml.parse_length; print('torch' in sys.modules)"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "False"


def test_unknown_name_is_an_attribute_error():
    try:
        ml.no_such_name  # noqa: B018
    except AttributeError as error:
        assert "no_such_name" in str(error)
    else:
        raise AssertionError("no AttributeError")
