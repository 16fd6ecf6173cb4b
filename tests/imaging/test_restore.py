"""Applying a trained network: tiling with overlap, the model file, the design fingerprint."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.network import NetworkShape, ReconstructionNet
from metalens_cli.imaging.restore import (
    Reconstructor,
    _starts,
    design_fingerprint,
    inference_bytes,
    load_reconstructor,
    save_model,
)


def _net(seed: int = 0, identity: bool = False) -> ReconstructionNet:
    torch.manual_seed(seed)
    net = ReconstructionNet(NetworkShape(width=4, depth=2, frequencies=2, position_scale=20.0))
    if not identity:
        torch.nn.init.normal_(net.head.weight, std=0.05)
    return net.eval()


@pytest.mark.parametrize("length, side, overlap", [(100, 40, 8), (41, 40, 8), (40, 40, 8), (257, 64, 16)])
def test_tiles_cover_the_image_and_overlap_enough(length, side, overlap):
    starts = _starts(length, side, overlap)
    assert starts[0] == 0 and starts[-1] + side >= length
    assert all(b - a <= side - overlap for a, b in zip(starts, starts[1:]))


def _budget_for(side: int, net) -> int:
    return inference_bytes(net.shape, side * side)


def test_tiled_identity_network_returns_its_input_exactly():
    net = _net(identity=True)
    image = np.random.default_rng(0).uniform(0, 1, size=(3, 90, 70)).astype(np.float32)
    recon = Reconstructor(net, memory_bytes=_budget_for(40, net), overlap=8)
    assert recon.tile_side(90, 70) == 40  # a multiple of 2^depth within the budget
    np.testing.assert_allclose(recon(image), image, rtol=0, atol=1e-6)  # blend weights sum to one everywhere


@pytest.mark.parametrize("size, tile, overlap", [(96, 48, 16), (512, 320, 64)])
def test_tiled_equals_whole_image_up_to_global_pooling(size, tile, overlap):
    """Tiles see their positions and the whole capture's mean; what differs is only what the
    network pools over the image (CBAM's channel attention) and the spectral filter's view: the
    tiles differ from the whole image by under 12 % of what the network changes (measured 9.4 %
    at 96 × 80 with 48 px tiles, 7.8 % at 512² with 320 px tiles; the trained quick networks:
    benchmarks/bench_reconstruct.py)."""
    torch.manual_seed(0)
    shape = NetworkShape(width=4, depth=2, frequencies=2, position_scale=20.0) if size < 512 else NetworkShape()
    net = ReconstructionNet(shape)
    torch.nn.init.normal_(net.head.weight, std=0.05)
    torch.nn.init.normal_(net.spectral.gain, std=0.01)
    net.eval()
    image = np.random.default_rng(1).uniform(0, 1, size=(3, size, size)).astype(np.float32)
    whole = Reconstructor(net)(image)
    recon = Reconstructor(net, memory_bytes=inference_bytes(shape, tile * tile), overlap=overlap)
    assert recon.tile_side(size, size) == tile
    tiled = recon(image)
    change, difference = np.sqrt(np.mean((whole - image) ** 2)), np.sqrt(np.mean((whole - tiled) ** 2))
    assert change > 0.1 and difference < 0.12 * change, (change, difference)


def test_model_file_round_trip_and_refusals(tmp_path):
    net = _net()
    save_model(tmp_path / "model.pt", net, {"spec": "x", "fingerprint": "abc"})
    loaded = load_reconstructor(tmp_path)
    assert loaded.design == {"spec": "x", "fingerprint": "abc"} and loaded.shape == net.shape
    image = np.random.default_rng(2).uniform(0, 1, size=(3, 24, 30)).astype(np.float32)
    np.testing.assert_array_equal(loaded(image), Reconstructor(net)(image))
    with pytest.raises(InputError, match="no such run directory"):
        load_reconstructor(tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="holds no trained network"):
        load_reconstructor(tmp_path / "empty")
    (tmp_path / "foreign.pt").write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="cannot read"):
        load_reconstructor(tmp_path / "foreign.pt")
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(InputError, match="not a metalens reconstruction model"):
        load_reconstructor(tmp_path / "other.pt")
    older = torch.load(tmp_path / "model.pt", weights_only=True)
    older["format"] = "metalens-reconstruct/1"  # a network from before the grey-wall invariant
    torch.save(older, tmp_path / "older.pt")
    with pytest.raises(InputError, match="metalens-reconstruct/1 model") as error:
        load_reconstructor(tmp_path / "older.pt")
    assert "train the network again" in error.value.expected


@pytest.mark.slow
def test_compiled_network_agrees_with_eager(tmp_path):
    """``torch.compile`` (apply --compile) fuses the elementwise work; the result is the eager one to rounding."""
    net = _net()
    image = np.random.default_rng(3).uniform(0, 1, size=(3, 40, 56)).astype(np.float32)
    eager = Reconstructor(net)(image)
    compiled = Reconstructor(net, compile=True)(image)
    np.testing.assert_allclose(compiled, eager, rtol=0, atol=1e-5)


def test_fingerprint_names_the_lens_not_the_spec():
    from pathlib import Path

    from metalens_cli.io.designs import resolve_design

    preset = Path(__file__).parents[2] / "presets" / "hyperbolic-532.toml"
    by_spec = resolve_design("hyperbolic:532nm", f_m=4e-3, aperture_m=2.516e-3)
    by_preset = resolve_design(str(preset))
    other = resolve_design("hyperbolic:530nm", f_m=4e-3, aperture_m=2.516e-3)
    assert design_fingerprint(by_spec) == design_fingerprint(by_preset) != design_fingerprint(other)
