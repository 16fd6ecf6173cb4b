"""The disk cache seen from the command line: a lying entry of `nanofin sweep` is named and
recomputed rather than recommended, an unusable cache folder is one warning line, and eight
commands started together on an empty cache compute η once and agree (docs/failures.md)."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.io import cache

ROOT = Path(__file__).parents[2]
SWEEP = [
    "nanofin",
    "sweep",
    "--harmonics",
    "3",
    "--max-harmonics",
    "9",
    "--band",
    "530nm:20nm",
    "--samples-per-band",
    "2",
    "--json",
]
GRID = ["--width", "250nm,300nm", "--length", "100nm,150nm"]


@pytest.fixture
def folder(tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(cache, "_UNUSABLE_WARNED", set())
    return tmp_path / "cache"


def sweep(capsys, out: Path) -> dict:
    code = run([*SWEEP, *GRID, "-o", str(out)])
    stdout, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(stdout)


def timeless(value):
    """``value`` (JSON) without its ``seconds``: what a recomputation must repeat."""
    if isinstance(value, dict):
        return {k: timeless(v) for k, v in value.items() if k != "seconds"}
    return [timeless(v) for v in value] if isinstance(value, list) else value


def test_a_lying_sweep_is_recomputed_not_recommended(capsys, folder, tmp_path):
    """The map planted with η = 5 for the fin that is not recommended, the refinement with η = 5
    per band: both are named, set aside and recomputed, and the answer is the first run's."""
    first = sweep(capsys, tmp_path / "first")
    [map_entry], [fine_entry] = (list((folder / kind).glob("*.npz")) for kind in ("nanofin-sweep", "nanofin-refine"))
    with np.load(map_entry) as data:
        eta = data["eta"].copy()
    chosen = first["recommended"]
    eta[[1, 0][first["lengths_m"].index(chosen["length_m"])], [1, 0][first["widths_m"].index(chosen["width_m"])]] = 5.0
    cache._store(map_entry, "nanofin-sweep", map_entry.stem, {"eta": eta, "seconds": np.array(1.0)})
    cache._store(
        fine_entry,
        "nanofin-refine",
        fine_entry.stem,
        {"report": np.array(json.dumps({**chosen["converged"], "eta_per_band": [5.0]}))},
    )
    with pytest.warns(cache.CacheWarning) as caught:
        again = sweep(capsys, tmp_path / "again")
    assert sorted(str(w.message).split(":")[0] for w in caught) == [
        f"cache entry {str(fine_entry)!r}",
        f"cache entry {str(map_entry)!r}",
    ]
    assert "eta: 1 value(s) outside 0..1 (such as 5)" in str(caught[0].message) + str(caught[1].message)
    assert not again["cached"] and not again["converged_cached"] and timeless(again["recommended"]) == timeless(chosen)
    assert (
        map_entry.with_name(map_entry.name + ".bad").exists()
        and fine_entry.with_name(fine_entry.name + ".bad").exists()
    )


def test_an_unusable_cache_folder_is_one_warning_line(tmp_path):
    """The map and the refinement both fail to be cached: one line says so, naming the folder."""
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "metalens_cli",
            *SWEEP,
            "--width",
            "250nm",
            "--length",
            "100nm",
            "-o",
            str(tmp_path / "sweep"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "METALENS_CACHE": os.devnull},
    )
    assert done.returncode == 0, done.stderr
    lines = [line for line in done.stderr.splitlines() if "cache" in line]
    assert lines == [
        "metalens: warning: CacheWarning: cache folder '/dev/null' cannot be used (Not a directory): results are "
        "computed on every run, not stored (set METALENS_CACHE to a writable folder)"
    ], done.stderr
    assert "Traceback" not in done.stderr and json.loads(done.stdout)["recommended"]["converged"]["harmonics"] >= 5


@pytest.mark.slow
def test_eight_bands_checks_on_an_empty_cache_compute_eta_once(tmp_path):
    """Eight `bands check --preset presets/split-spectrum-rcwa.toml` started together on an empty
    cache: all succeed with the same η, one computed it (the others waited and read its entry),
    and the cache holds that one entry and nothing else."""
    env = {**os.environ, "METALENS_CACHE": str(tmp_path / "cache")}
    command = [
        sys.executable,
        "-m",
        "metalens_cli",
        "bands",
        "check",
        "--preset",
        str(ROOT / "presets" / "split-spectrum-rcwa.toml"),
        "--json",
    ]
    processes = [
        subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env) for _ in range(8)
    ]
    results = [process.communicate(timeout=600) for process in processes]
    assert [p.returncode for p in processes] == [0] * 8, [err for _, err in results]
    reports = [json.loads(out)["efficiency"] for out, _ in results]
    assert sorted(r["cached"] for r in reports) == [False] + [True] * 7
    assert all({**r, "cached": None} == {**reports[0], "cached": None} for r in reports)
    assert sorted(str(p.relative_to(tmp_path / "cache")) for p in (tmp_path / "cache").rglob("*")) == [
        "nanofin",
        str(Path(reports[0]["cache_entry"]).relative_to(tmp_path / "cache")),
    ]
