"""LPIPS from local weight files: discovery, metric properties, bad files, an independent
layer-1 reference, the lpips package's own distances (a stored fixture), and `evaluate
--lpips-weights` end to end. The weight files are random but laid out like torchvision's AlexNet
state dict and the lpips package's v0.1 alex.pth."""

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
from metric_references import alexnet_features, lpips_pair, state_sha256

from metalens_cli.cli.main import run
from metalens_cli.errors import InputError
from metalens_cli.imaging.lpips import ALEXNET_FILE, ENV_VAR, LIN_FILE, Lpips, find_lpips_weights, lpips_distance

CONVS = {0: (64, 3, 11), 3: (192, 64, 5), 6: (384, 192, 3), 8: (256, 384, 3), 10: (256, 256, 3)}
CHANNELS = (64, 192, 384, 256, 256)


def write_weights(folder, seed=0, lin_scale=(1, 1, 1, 1, 1), bad_key=None):
    """Random weights in the real key layouts; ``bad_key`` (a 4-D weight) gets a wrong shape."""
    g = torch.Generator().manual_seed(seed)
    alex = {}
    for i, (cout, cin, k) in CONVS.items():
        bound = 1 / (cin * k * k) ** 0.5
        alex[f"features.{i}.weight"] = (2 * torch.rand(cout, cin, k, k, generator=g) - 1) * bound
        alex[f"features.{i}.bias"] = (2 * torch.rand(cout, generator=g) - 1) * bound
    alex["classifier.1.weight"], alex["classifier.1.bias"] = (
        torch.zeros(4, 9),
        torch.zeros(4),
    )  # ignored (real: 4096 × 9216)
    lin = {
        f"lin{n}.model.1.weight": s * torch.rand(1, c, 1, 1, generator=g)
        for n, (c, s) in enumerate(zip(CHANNELS, lin_scale))
    }
    for state in (alex, lin):
        if bad_key in state:
            state[bad_key] = state[bad_key][:, :1].clone()  # (out, 1, …) instead of (out, in, …)
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(alex, folder / ALEXNET_FILE)
    torch.save(lin, folder / LIN_FILE)
    return folder


@pytest.fixture(scope="module")
def weights_dir(tmp_path_factory):
    return write_weights(tmp_path_factory.mktemp("lpips"))


@pytest.fixture(scope="module")
def model(weights_dir):
    return Lpips.from_files(weights_dir / ALEXNET_FILE, weights_dir / LIN_FILE)


@pytest.fixture
def no_defaults(monkeypatch, tmp_path):
    """No env var and an empty torch hub dir."""
    monkeypatch.delenv(ENV_VAR, raising=False)
    hub = tmp_path / "hub"
    hub.mkdir()
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(hub))
    return hub


def images(seed, shape=(2, 3, 48, 40)):
    return torch.rand(shape, generator=torch.Generator().manual_seed(seed), dtype=torch.float64)


def test_discovery_by_directory_and_env(weights_dir, no_defaults, monkeypatch):
    paths, note = find_lpips_weights(weights_dir)
    assert note is None and paths == (weights_dir / ALEXNET_FILE, weights_dir / LIN_FILE)
    monkeypatch.setenv(ENV_VAR, str(weights_dir))
    assert find_lpips_weights() == (paths, None)


def test_discovery_hub_with_lpips_package(weights_dir, no_defaults, monkeypatch, tmp_path):
    (no_defaults / "checkpoints").mkdir()
    (no_defaults / "checkpoints" / ALEXNET_FILE).write_bytes((weights_dir / ALEXNET_FILE).read_bytes())
    package = tmp_path / "site" / "lpips"
    (package / "weights" / "v0.1").mkdir(parents=True)
    (package / "__init__.py").write_text("raise RuntimeError('must not be imported')\n")
    (package / "weights" / "v0.1" / LIN_FILE).write_bytes((weights_dir / LIN_FILE).read_bytes())
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    paths, note = find_lpips_weights()
    assert note is None and paths == (
        no_defaults / "checkpoints" / ALEXNET_FILE,
        package / "weights" / "v0.1" / LIN_FILE,
    )


def test_skip_note_when_absent(no_defaults, monkeypatch, tmp_path):
    paths, note = find_lpips_weights()
    assert paths is None and "\n" not in note and note.startswith("LPIPS skipped")
    assert ENV_VAR in note and str(no_defaults) in note
    monkeypatch.setenv(ENV_VAR, str(tmp_path))  # set but empty: still skipped, and named
    paths, note = find_lpips_weights()
    assert paths is None and str(tmp_path) in note
    with pytest.raises(InputError, match=LIN_FILE):  # an explicit directory must hold both files
        find_lpips_weights(tmp_path)


def test_identity_positive_symmetric(model):
    x, y = images(1), images(2)
    assert torch.equal(lpips_distance(model, x, x), torch.zeros(2, dtype=torch.float32))
    dxy, dyx = lpips_distance(model, x, y), lpips_distance(model, y, x)
    assert dxy.shape == (2,) and (dxy > 0).all()
    assert torch.allclose(dxy, dyx, rtol=1e-6, atol=0)
    single = lpips_distance(model, x[1], y[1])
    assert single.ndim == 0 and float(single) == pytest.approx(float(dxy[1]), rel=1e-5)


@pytest.mark.parametrize("bad_key", ["features.3.weight", "lin2.model.1.weight"])
def test_wrong_shape_names_file(tmp_path, bad_key):
    folder = write_weights(tmp_path / "bad", bad_key=bad_key)
    bad_file = folder / (LIN_FILE if bad_key.startswith("lin") else ALEXNET_FILE)
    with pytest.raises(InputError) as info:
        Lpips.from_files(folder / ALEXNET_FILE, folder / LIN_FILE)
    message = str(info.value)
    assert str(bad_file) in message and bad_key in message and "\n" not in message


def test_not_a_state_dict_names_file(tmp_path, weights_dir):
    junk = tmp_path / ALEXNET_FILE
    junk.write_text("not a torch file")
    with pytest.raises(InputError, match="cannot be read"):
        Lpips.from_files(junk, weights_dir / LIN_FILE)


def test_too_small_images_rejected(model):
    with pytest.raises(InputError, match="at least"):
        lpips_distance(model, images(1, (3, 24, 24)), images(2, (3, 24, 24)))


def test_layer1_against_independent_reference(tmp_path):
    """Only lin0 non-zero → LPIPS is layer 1's term: conv by torch's conv2d, the rest in numpy loops."""
    folder = write_weights(tmp_path / "w", seed=3, lin_scale=(1, 0, 0, 0, 0))
    model = Lpips.from_files(folder / ALEXNET_FILE, folder / LIN_FILE).double()
    alex, lin = torch.load(folder / ALEXNET_FILE), torch.load(folder / LIN_FILE)
    x, y = images(4, (1, 3, 40, 36)), images(5, (1, 3, 40, 36))
    shift = np.array([-0.030, -0.088, -0.188])[:, None, None]
    scale = np.array([0.458, 0.448, 0.450])[:, None, None]

    def layer1(img):
        scaled = torch.as_tensor(((2 * img[0].numpy() - 1) - shift) / scale)[None]
        w, b = alex["features.0.weight"].double(), alex["features.0.bias"].double()
        return torch.relu(torch.nn.functional.conv2d(scaled, w, b, stride=4, padding=2))[0].numpy()

    fx, fy = layer1(x), layer1(y)
    w = lin["lin0.model.1.weight"].double().numpy().reshape(-1)
    channels, height, width = fx.shape
    total = 0.0
    for i in range(height):
        for j in range(width):
            nx = np.sqrt(sum(fx[c, i, j] ** 2 for c in range(channels))) + 1e-10
            ny = np.sqrt(sum(fy[c, i, j] ** 2 for c in range(channels))) + 1e-10
            total += sum(w[c] * (fx[c, i, j] / nx - fy[c, i, j] / ny) ** 2 for c in range(channels))
    reference = total / (height * width)
    assert reference > 0
    assert float(lpips_distance(model, x, y)[0]) == pytest.approx(reference, rel=1e-5)


def test_matches_the_lpips_package(tmp_path):
    """Against lpips 0.1.4 itself (data/lpips_alex_reference.json, written by
    data/make_lpips_fixture.py): its shipped v0.1 alex.pth calibration (data/lpips_v0.1_alex.pth)
    with seeded AlexNet weights, regenerated here with numpy, on nine 64 × 64 pairs (noise, blur,
    a shift, colour, brightness, unrelated). Measured: ≤ 1.5e-8 apart (float32 round-off)."""
    data = Path(__file__).parent / "data"
    reference = json.loads((data / "lpips_alex_reference.json").read_text())
    lin = data / "lpips_v0.1_alex.pth"
    assert hashlib.sha256(lin.read_bytes()).hexdigest() == reference["lin_file_sha256"]
    features = alexnet_features(reference["alexnet_seed"])
    assert state_sha256(features) == reference["alexnet_sha256"], "numpy no longer draws the same AlexNet weights"
    torch.save({k: torch.from_numpy(v) for k, v in features.items()}, tmp_path / ALEXNET_FILE)
    shutil.copyfile(lin, tmp_path / LIN_FILE)
    model = Lpips.load(tmp_path)
    rows = reference["pairs"]
    x, y = (torch.as_tensor(np.stack(a), dtype=torch.float32) for a in zip(*(lpips_pair(row) for row in rows)))
    for i, row in enumerate(rows):  # the pairs regenerated as they were drawn
        assert float(x[i].double().mean()) == pytest.approx(row["x_mean"], rel=1e-9)
        assert float(y[i].double().mean()) == pytest.approx(row["y_mean"], rel=1e-9)
    with torch.no_grad():
        ours = lpips_distance(model, x, y).double().numpy()
    expected = np.array([row["lpips"] for row in rows])  # 0.0055 … 0.14
    np.testing.assert_allclose(ours, expected, rtol=0, atol=1e-3)
    np.testing.assert_allclose(ours, expected, rtol=1e-4)  # the smallest is 0.0055: 1e-3 alone is loose


def test_evaluate_reports_lpips(capsys, weights_dir, tmp_path):
    csv = tmp_path / "e.csv"
    args = [
        "evaluate",
        "hyperbolic:532nm",
        "--f",
        "4mm",
        "--aperture",
        "0.3mm",
        "--pixels",
        "64",
        "--wavelengths",
        "420:680:20nm",
        "--z-near",
        "45mm",
        "--z-far",
        "1m",
        "--images",
        "charts",
        "--limit",
        "1",
        "--obstruction",
        "dirt",
        "--lpips-weights",
        str(weights_dir),
        "--csv",
        str(csv),
        "--json",
    ]
    code = run(args)
    out, err = capsys.readouterr()
    assert code == 0 and "LPIPS" not in err
    report = json.loads(out)
    assert report["notes"] == [] and len(report["rows"]) == 2
    for row in report["rows"]:
        assert row["lpips"] > 0
    assert "delta_lpips" in report["deltas"][0]
    assert csv.read_text().splitlines()[0].endswith(",ssim_hi,lpips,lpips_lo,lpips_hi")
    assert run(args[:-3]) == 0 and "dirt LPIPS" in capsys.readouterr().out  # the table
