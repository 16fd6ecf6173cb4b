"""The disk cache (io.cache): entries that lie are named in a warning, set aside and recomputed;
an unusable cache folder is named once; an entry asked for by many threads or processes at once
is computed once, and a killed computer's lock lets the next one compute."""

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
import tomllib
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.io import cache, preset_spectra
from metalens_cli.io.presets import preset_from_dict

KIND, KEY = "test", "0123456789abcdef01234567"
GOOD = np.array([0.25, 0.5, 0.75])
PRESETS = Path(__file__).parents[2] / "presets"

# A process asking for KEY once every process is ready (a "go" file), computing a random η
# (recording its pid in CALLS) in SECONDS; it prints what it got and whether it read it.
WORKER = """
import os, sys, time
from pathlib import Path
import numpy as np
from metalens_cli.io import cache
calls, go, seconds = Path(sys.argv[1]), Path(sys.argv[2]), float(sys.argv[3])
(go.parent / f"ready-{os.getpid()}").touch()
while not go.exists():
    time.sleep(0.005)
def compute():
    (calls / str(os.getpid())).touch()
    time.sleep(seconds)
    return {"eta": np.random.default_rng().random(3)}
entry = cache.cached(sys.argv[4], sys.argv[5], compute, lambda a: cache.check_array(a, "eta", (3,), 0, 1))
print(entry.arrays["eta"].tobytes().hex(), entry.hit, flush=True)
"""


@pytest.fixture
def folder(tmp_path, monkeypatch):
    """An empty cache folder of this test's own; no folder warned about yet."""
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path / "cache"))
    monkeypatch.setattr(cache, "_UNUSABLE_WARNED", set())
    return tmp_path / "cache"


class Counted:
    """A compute function returning ``values`` (a fresh copy) and counting its calls."""

    def __init__(self, values=GOOD, seconds=0.0):
        self.values, self.seconds, self.calls = values, seconds, 0
        self.lock = threading.Lock()

    def __call__(self):
        with self.lock:
            self.calls += 1
            calls = self.calls
        time.sleep(self.seconds)
        return {"eta": np.array(self.values) + (calls - 1)}  # a second call would give another answer


def three_fractions(arrays):
    return cache.check_array(arrays, "eta", (3,), 0, 1)


def ask(compute=None):
    return cache.cached(KIND, KEY, compute or Counted(), three_fractions)


def test_an_entry_is_computed_once_then_read_with_its_metadata(folder):
    compute = Counted()
    first, second = ask(compute), ask(compute)
    assert compute.calls == 1 and not first.hit and second.hit
    assert first.path == second.path == folder / KIND / f"{KEY}.npz"
    np.testing.assert_array_equal(second.arrays["eta"], GOOD)
    with np.load(first.path) as data:
        meta = json.loads(str(data["_meta"]))
        assert sorted(data.files) == ["_meta", "eta"]
    assert {k: meta[k] for k in ("format", "kind", "key")} == {"format": cache.FORMAT, "kind": KIND, "key": KEY}
    assert len(meta["sha256"]) == 64
    assert sorted(p.name for p in (folder / KIND).iterdir()) == [f"{KEY}.npz"]  # no lock, no temporary file left


def test_a_missing_entry_is_computed_without_a_word(folder):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert not ask().hit


def plant_arrays(arrays):
    """An entry whose metadata and checksum vouch for ``arrays``: only the caller's check can tell."""

    def plant(path):
        cache._store(path, KIND, KEY, {name: np.asarray(value) for name, value in arrays.items()})

    return plant


def truncate(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def flip_payload_byte(path):
    """One bit of η's data flipped: the zip's CRC (or else the checksum) no longer matches."""
    data = bytearray(path.read_bytes())
    data[data.index(GOOD.tobytes()) + 3] ^= 0x10
    path.write_bytes(bytes(data))


def rewrite_payload(path):
    """η changed and the archive rewritten whole, keeping the metadata: only the checksum can tell."""
    with np.load(path) as data:
        meta = data["_meta"]
    np.savez(path, _meta=meta, eta=np.array([0.25, 0.5, 0.76]))


def old_format(path):
    np.savez(path, eta=GOOD)


def another_key(path):
    cache._store(path, KIND, "f" * 24, {"eta": GOOD})


@pytest.mark.parametrize(
    ("spoil", "reason"),
    [
        (plant_arrays({"eta": [0.25, np.nan, 0.75]}), "eta: 1 of 3 value(s) not finite"),
        (plant_arrays({"eta": [0.25, 5.0, 0.75]}), "eta: 1 value(s) outside 0..1 (such as 5)"),
        (plant_arrays({"eta": [0.25, 0.5, 0.75, 1.0]}), "eta: of shape (4,), expected (3,)"),
        (plant_arrays({"eta": [[0.25, 0.5, 0.75]]}), "eta: of shape (1, 3), expected (3,)"),
        (plant_arrays({"eta": ["a", "b", "c"]}), "eta: of type <U1, not real numbers"),
        (plant_arrays({"other": GOOD}), "eta: missing"),
        (truncate, "unreadable (BadZipFile"),
        (flip_payload_byte, "unreadable (BadZipFile: Bad CRC-32"),
        (rewrite_payload, "checksum mismatch"),
        (old_format, "no format version"),
        (another_key, f"written as 'test' entry '{'f' * 24}'"),
    ],
    ids=[
        "nan",
        "eta-5",
        "longer",
        "2d",
        "text",
        "renamed",
        "truncated",
        "flipped-byte",
        "checksum",
        "old-format",
        "other-key",
    ],
)
def test_a_lying_entry_is_named_set_aside_and_recomputed(folder, spoil, reason):
    path = ask().path
    spoil(path)
    planted = path.read_bytes()
    compute = Counted(values=[0.1, 0.2, 0.3])
    with pytest.warns(cache.CacheWarning) as caught:
        entry = ask(compute)
    assert len(caught) == 1
    message = str(caught[0].message)
    assert (
        message.startswith(f"cache entry {str(path)!r}: {reason}") and f"moved to {KEY}.npz.bad, recomputing" in message
    ), message
    assert (folder / KIND / f"{KEY}.npz.bad").read_bytes() == planted
    assert compute.calls == 1 and not entry.hit and entry.arrays["eta"].tolist() == [0.1, 0.2, 0.3]
    assert ask(Counted()).hit and cache.load(KIND, KEY, three_fractions)["eta"].tolist() == [0.1, 0.2, 0.3]


def test_a_plain_npy_or_a_folder_in_the_entry_s_place_is_set_aside(folder):
    path = ask().path
    path.unlink()
    np.save(path.with_suffix(".tmp.npy"), GOOD)
    os.replace(path.with_suffix(".tmp.npy"), path)
    with pytest.warns(cache.CacheWarning, match="not an .npz archive"):
        assert not ask().hit
    path.unlink()
    path.mkdir()
    with pytest.warns(cache.CacheWarning, match="IsADirectoryError"):
        assert not ask().hit
    assert (folder / KIND / f"{KEY}.npz.bad").is_dir() and ask().hit


def unusable_folders(tmp_path):
    (tmp_path / "file").write_text("")
    read_only = tmp_path / "read-only"
    read_only.mkdir(mode=0o555)
    return {"file": tmp_path / "file", "dev-null": Path(os.devnull), "read-only": read_only}


@pytest.mark.parametrize("which", ["file", "dev-null", "read-only"])
def test_an_unusable_folder_is_named_once_and_results_are_computed(folder, tmp_path, monkeypatch, which):
    if which == "read-only" and os.geteuid() == 0:
        pytest.skip("root writes in read-only folders")
    place = unusable_folders(tmp_path)[which]
    monkeypatch.setenv("METALENS_CACHE", str(place))
    compute = Counted()
    with pytest.warns(cache.CacheWarning) as caught:
        entries = [cache.cached(kind, KEY, compute, three_fractions) for kind in (KIND, KIND, "other")]
    assert [str(w.message) for w in caught] == [
        f"cache folder {str(place)!r} cannot be used "
        f"({'Permission denied' if which == 'read-only' else 'Not a directory'}): results are computed on every run, "
        "not stored (set METALENS_CACHE to a writable folder)"
    ]
    assert compute.calls == 3 and all(e.path is None and not e.hit for e in entries)


def test_a_read_only_cache_serves_its_entries_and_says_once_that_it_stores_none(folder, monkeypatch):
    """A folder where no file can be created (read-only, as root cannot make one here): its
    entries are read without a word; what it lacks is computed, and not stored, with one warning."""
    ask()

    def refused(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(os, "open", refused)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert ask().hit
    compute = Counted()
    with pytest.warns(cache.CacheWarning, match=r"cannot be used \(Permission denied\)") as caught:
        entries = [cache.cached(KIND, "1" * 24, compute, three_fractions) for _ in range(2)]
    assert len(caught) == 1 and compute.calls == 2 and all(e.path is None for e in entries)


def test_a_full_disk_is_an_unusable_folder(folder, monkeypatch):
    def full(*args, **kwargs):
        raise OSError(28, "No space left on device", "x")

    monkeypatch.setattr(np, "savez", full)
    with pytest.warns(cache.CacheWarning, match=r"cannot be used \(No space left on device\)") as caught:
        entry = ask()
        ask()
    assert len(caught) == 1 and entry.path is None and entry.arrays["eta"].tolist() == GOOD.tolist()
    assert list((folder / KIND).iterdir()) == []


def test_threads_asking_for_one_entry_compute_it_once(folder):
    compute = Counted(seconds=0.3)
    with ThreadPoolExecutor(8) as pool:
        entries = list(pool.map(lambda _: ask(compute), range(8)))
    assert compute.calls == 1 and sum(not e.hit for e in entries) == 1
    assert all(np.array_equal(e.arrays["eta"], GOOD) for e in entries)
    assert sorted(p.name for p in (folder / KIND).iterdir()) == [f"{KEY}.npz"]


def start_workers(tmp_path, count, seconds):
    """``count`` WORKER processes released together; returns them and their calls folder."""
    calls, go = tmp_path / "calls", tmp_path / "go"
    calls.mkdir(exist_ok=True)
    workers = [
        subprocess.Popen(
            [sys.executable, "-c", WORKER, str(calls), str(go), str(seconds), KIND, KEY],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for _ in range(count)
    ]
    deadline = time.monotonic() + 60
    while len(list(tmp_path.glob("ready-*"))) < count and time.monotonic() < deadline:
        time.sleep(0.01)
    go.touch()
    return workers, calls


def test_processes_asking_for_one_entry_compute_it_once_and_agree(folder, tmp_path):
    workers, calls = start_workers(tmp_path, 6, 0.5)
    results = [worker.communicate(timeout=60) for worker in workers]
    assert all(worker.returncode == 0 for worker in workers), [err for _, err in results]
    answers = [out.split() for out, _ in results]
    assert len(list(calls.iterdir())) == 1 and sorted(hit for _, hit in answers) == ["False"] + ["True"] * 5
    assert len({eta for eta, _ in answers}) == 1
    with np.load(folder / KIND / f"{KEY}.npz") as data:
        assert data["eta"].tobytes().hex() == answers[0][0]  # the entry is what they all got
    assert sorted(p.name for p in (folder / KIND).iterdir()) == [f"{KEY}.npz"]


def test_a_killed_computer_lets_the_next_one_compute(folder, tmp_path):
    (holder,), calls = start_workers(tmp_path, 1, 60)
    deadline = time.monotonic() + 30
    while not any(calls.iterdir()) and time.monotonic() < deadline:
        time.sleep(0.01)
    compute = Counted()
    try:
        waiter = ThreadPoolExecutor(1).submit(ask, compute)
        time.sleep(0.5)
        assert not waiter.done() and compute.calls == 0  # waits for the holder
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(timeout=10)
    entry = waiter.result(timeout=10)
    assert compute.calls == 1 and not entry.hit and entry.path is not None
    assert sorted(p.name for p in (folder / KIND).iterdir()) == [f"{KEY}.npz"]


def rcwa_preset():
    data = tomllib.loads((PRESETS / "quick-split-spectrum.toml").read_text())
    table = {k: v for k, v in data["nanofin"].items() if not k.startswith("efficiency")}
    data["nanofin"] = {**table, "efficiency": "rcwa", "harmonics": 5}
    return preset_from_dict(data)


def test_a_preset_s_eta_entry_that_lies_is_recomputed(folder):
    """η by RCWA (the cheapest truncation, 40 nm): an entry planted with NaN, with η = 5 or with
    one wavelength fewer is named, set aside and recomputed to the same η as the first time."""
    nanofin, narrow = rcwa_preset().nanofin, (500e-9, 540e-9)
    first = preset_spectra.preset_efficiency(nanofin, narrow)
    path = Path(first.report["cache_entry"])
    key = path.stem
    for change, reason in [
        (lambda a: a["conversion"].__setitem__(1, np.nan), "conversion: 1 of"),
        (lambda a: a["conversion"].__setitem__(1, 5.0), "conversion: 1 value(s) outside 0..1"),
        (lambda a: a.update(wavelengths_m=a["wavelengths_m"][:-1]), "conversion: of shape"),
    ]:
        arrays = {name: np.array(value) for name, value in cache.load(preset_spectra.CACHE_KIND, key).items()}
        change(arrays)
        cache._store(path, preset_spectra.CACHE_KIND, key, arrays)
        with pytest.warns(cache.CacheWarning, match=re.escape(reason)):
            again = preset_spectra.preset_efficiency(nanofin, narrow)
        assert not again.report["cached"] and np.array_equal(again.values, first.values)
        assert (path.parent / f"{key}.npz.bad").exists()


def test_the_folder_is_metalens_cache_when_set(tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path / "mine"))
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_folder() == tmp_path / "mine"
    assert cache.entry_path(KIND, KEY).parent == tmp_path / "mine" / KIND


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="XDG_CACHE_HOME is Linux's (platformdirs)")
def test_without_metalens_cache_xdg_cache_home_then_home_on_linux(tmp_path, monkeypatch):
    monkeypatch.delenv("METALENS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.cache_folder() == tmp_path / "xdg" / "metalens"
    monkeypatch.setenv("METALENS_CACHE", "")  # blank counts as unset
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache.cache_folder() == tmp_path / "home" / ".cache" / "metalens"


def test_without_metalens_cache_the_platform_s_user_cache_folder(tmp_path, monkeypatch):
    import platformdirs

    asked = []

    def user_cache_dir(appname=None, appauthor=None, *args, **kwargs):
        asked.append((appname, appauthor))
        return str(tmp_path / "platform" / appname)

    monkeypatch.delenv("METALENS_CACHE", raising=False)
    monkeypatch.setattr(platformdirs, "user_cache_dir", user_cache_dir)
    assert cache.cache_folder() == tmp_path / "platform" / "metalens"
    assert asked == [("metalens", False)]
