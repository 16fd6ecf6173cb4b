"""Applying a trained reconstruction network to captures of any size.

A trained network lives in ``RUN/model.pt`` (written by ``metalens reconstruct train``): the
network shape, its weights and the identity of the design it was trained for
(``design_fingerprint``). Images larger than the memory budget allows are cut into tiles that
overlap by ``overlap`` pixels and blended with linear ramps across the overlaps; each tile is
told where on the sensor it lies (positional encoding) and the whole capture's mean (what the
network's contrast is relative to), so tiling changes only what the network's image-wide pooling
(CBAM's channel attention) and its spectral filter see.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.network import NetworkShape, ReconstructionNet, capture_mean, pixel_positions

MODEL_FILE = "model.pt"
MODEL_FORMAT = "metalens-reconstruct/2"
OLD_FORMATS = ("metalens-reconstruct/1",)  # networks before the grey-wall invariant (biases, a free DC gain)
DEFAULT_MEMORY_BYTES = 1 << 30
FLOAT_BYTES = 4
# float32 planes per unit of width at the peak of a forward pass (17.4-18.2 measured: benchmarks/bench_reconstruct.py)
ACTIVATION_PLANES = 20
DEFAULT_OVERLAP = 64
LOSS_TERMS = ("l1", "ssim", "lpips")  # a model file's loss_terms (design.reconstruct_training's loss)


def design_fingerprint(design) -> str:
    """sha256 over θ (float64 bytes), pitch, aperture and lens-to-sensor distance of a resolved design:
    the same lens gives the same fingerprint whatever spec names it."""
    theta = np.ascontiguousarray(design.lens.theta.detach().cpu().numpy(), dtype=np.float64)
    digest = hashlib.sha256(theta.tobytes())
    digest.update(
        np.array(
            [theta.ndim, design.lens.pitch_m, design.lens.aperture_m, design.focal_length_m], dtype=np.float64
        ).tobytes()
    )
    return digest.hexdigest()[:16]


def inference_bytes(shape: NetworkShape, pixels: int) -> int:
    """Estimated peak memory (bytes) of one forward pass over ``pixels`` pixels (float32)."""
    return pixels * FLOAT_BYTES * (shape.signal_channels + shape.context_channels + ACTIVATION_PLANES * shape.width)


@dataclass
class Reconstructor:
    """A trained network on a device, applied to linear (3, H, W) images. ``compile``: run it
    through ``torch.compile`` (inductor fuses the elementwise work; it compiles again for each
    new image or tile size; its speed-up in docs/benchmarks.md)."""

    net: ReconstructionNet
    design: dict = field(default_factory=dict)
    device: torch.device = torch.device("cpu")
    memory_bytes: int = DEFAULT_MEMORY_BYTES
    overlap: int = DEFAULT_OVERLAP
    source: str = ""
    compile: bool = False

    def __post_init__(self):
        self.net = self.net.to(memory_format=torch.channels_last)  # oneDNN's fast layout: 512² in 0.29 s, not 0.36 s
        self._forward = torch.compile(self.net) if self.compile else self.net

    @property
    def shape(self) -> NetworkShape:
        """The network's :class:`NetworkShape`."""
        return self.net.shape

    def tile_side(self, height: int, width: int) -> int | None:
        """The tile side (a multiple of 2^depth) that fits the memory budget, or None when the whole image does."""
        if inference_bytes(self.shape, height * width) <= self.memory_bytes:
            return None
        step = 2**self.shape.depth
        side = int(math.sqrt(self.memory_bytes / inference_bytes(self.shape, 1))) // step * step
        if side <= 2 * self.overlap:
            least = inference_bytes(self.shape, ((2 * self.overlap // step + 1) * step) ** 2)
            raise InputError(
                "--memory-mib",
                f"{self.memory_bytes / 2**20:g} MiB allow tiles of only {side} px",
                f"at least {math.ceil(least / 2**20)} MiB: tiles larger than twice the {self.overlap} px overlap",
            )
        return side

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """The reconstruction (3, H, W) float32 of a linear (3, H, W) capture."""
        # contiguous: the mean (a reduction) must not depend on the layout the image came in
        x = torch.as_tensor(np.ascontiguousarray(image, dtype=np.float32), device=self.device)
        with torch.inference_mode():
            return self._apply(x).contiguous().cpu().numpy()

    def _apply(self, x: torch.Tensor) -> torch.Tensor:
        h, w = x.shape[-2:]
        side = self.tile_side(h, w)
        scale = self.shape.position_scale
        mean = capture_mean(x[None])
        if side is None:
            return self._forward(_fast(x[None]), pixel_positions(h, w, scale=scale, device=x.device)[None], mean)[0]
        total = torch.zeros_like(x)
        weight = torch.zeros((1, h, w), dtype=x.dtype, device=x.device)
        for top in _starts(h, side, self.overlap):
            for left in _starts(w, side, self.overlap):
                th, tw = min(side, h - top), min(side, w - left)
                positions = pixel_positions(th, tw, top=top, left=left, full=(h, w), scale=scale, device=x.device)
                tile = self._forward(_fast(x[None, :, top : top + th, left : left + tw]), positions[None], mean)[0]
                ramp = _ramp(th, top, h, self.overlap, x)[:, None] * _ramp(tw, left, w, self.overlap, x)[None, :]
                total[:, top : top + th, left : left + tw] += tile * ramp
                weight[:, top : top + th, left : left + tw] += ramp
        return total / weight


def _fast(x: torch.Tensor) -> torch.Tensor:
    """(B, 3, H, W) in channels-last layout, as the network's weights are (the same layout gives
    the same sums: ``imaging.export`` uses it too)."""
    return x.contiguous(memory_format=torch.channels_last)


def _starts(length: int, side: int, overlap: int) -> list[int]:
    """Tile origins covering ``length`` with tiles of ``side`` overlapping by at least ``overlap``."""
    if length <= side:
        return [0]
    count = math.ceil((length - overlap) / (side - overlap))
    return [round(k * (length - side) / (count - 1)) for k in range(count)]


def _ramp(n: int, start: int, length: int, overlap: int, like: torch.Tensor) -> torch.Tensor:
    """Blend weights along one axis of a tile: rising over ``overlap`` pixels where another tile
    precedes, falling where one follows, 1 at the image's own edges."""
    ramp = torch.ones(n, dtype=like.dtype, device=like.device)
    edge = torch.arange(1, overlap + 1, dtype=like.dtype, device=like.device) / (overlap + 1)
    k = min(overlap, n)
    if start > 0:
        ramp[:k] = torch.minimum(ramp[:k], edge[:k])
    if start + n < length:
        ramp[n - k :] = torch.minimum(ramp[n - k :], edge[:k].flip(0))
    return ramp


def model_path(run: str | Path) -> Path:
    """``RUN/model.pt`` of a run directory, or the file itself."""
    path = Path(run)
    return path / MODEL_FILE if path.is_dir() else path


def save_model(path: str | Path, net: ReconstructionNet, design: dict, extra: dict | None = None) -> None:
    """Write the network shape, weights and design identity atomically."""
    from metalens_cli.io.atomic import atomic_write

    state = {
        "format": MODEL_FORMAT,
        "shape": net.shape.to_dict(),
        "state_dict": net.state_dict(),
        "design": design,
        **(extra or {}),
    }
    with atomic_write(path) as temporary:
        torch.save(state, temporary)


def load_reconstructor(
    run: str | Path,
    device="cpu",
    memory_bytes: int = DEFAULT_MEMORY_BYTES,
    field_name: str = "RUN",
    *,
    compile: bool = False,
) -> Reconstructor:
    """The network of a reconstruction run directory (or its model.pt) on ``device``. A file that
    is not a readable ``MODEL_FORMAT`` dict whose shape, finite weights, positive finite position
    scale and design dict make one network is an InputError on ``field_name`` naming it."""
    path = model_path(run)
    expected = "a run directory written by metalens reconstruct train (holding model.pt)"
    if not Path(run).exists():
        raise InputError(field_name, f"no such run directory {str(run)!r}", expected)
    if not path.is_file():
        raise InputError(field_name, f"{str(run)!r} holds no trained network ({MODEL_FILE} missing)", expected)
    try:
        state = load_tensors(path)
    except Exception:  # torch raises many types for foreign or damaged files
        raise InputError(
            field_name, f"cannot read {str(path)!r}: it is truncated, damaged or not a torch file", expected
        ) from None
    if not isinstance(state, dict) or not isinstance(state.get("design", {}), dict):
        raise InputError(field_name, f"{str(path)!r} is not a metalens reconstruction model", expected)
    if state.get("format") != MODEL_FORMAT:
        older = state.get("format") in OLD_FORMATS
        raise InputError(
            field_name,
            f"{str(path)!r} is a {state['format']} model, made before the network kept a grey wall grey"
            if older
            else f"{str(path)!r} is not a metalens reconstruction model",
            f"a {MODEL_FORMAT} model: train the network again with metalens reconstruct train" if older else expected,
        )
    problem = _metadata_problem(state)
    if problem:
        raise InputError(field_name, f"{str(path)!r}: {problem}", expected)
    try:
        shape = NetworkShape(**state["shape"])
        scale = float(shape.position_scale)
        with torch.device("meta"):  # check keys and shapes first: a foreign shape must not allocate what it asks for
            ReconstructionNet(shape).load_state_dict(state["state_dict"], assign=True)
        net = ReconstructionNet(shape)
        net.load_state_dict(state["state_dict"])
    except (TypeError, KeyError, RuntimeError, ValueError) as exc:
        raise InputError(
            field_name, f"{str(path)!r} does not match the network: {' '.join(str(exc).split())}", expected
        ) from None
    if not (0 < scale < math.inf and all(value.isfinite().all() for value in net.state_dict().values())):
        raise InputError(field_name, f"{str(path)!r} holds NaN or infinite weights or position scale", expected)
    net.eval().to(device)
    return Reconstructor(
        net, state.get("design", {}), torch.device(device), memory_bytes, source=str(run), compile=compile
    )


def _metadata_problem(state: dict) -> str | None:
    """What in a model file's fields besides the network no training run writes (None: nothing):
    ``steps`` an integer ≥ 0, ``loss_terms`` a list of LOSS_TERMS, the design's ``spec`` and
    ``fingerprint`` strings (each may be absent: :func:`save_model`'s callers choose)."""
    steps, terms, design = state.get("steps", 0), state.get("loss_terms", []), state.get("design", {})
    if type(steps) is not int or steps < 0:
        return f"steps is {steps!r}, not an integer ≥ 0"
    if not (isinstance(terms, list) and all(term in LOSS_TERMS for term in terms)):
        return f"loss_terms is {terms!r}, not a list of {', '.join(LOSS_TERMS)}"
    for key in ("spec", "fingerprint"):
        if not isinstance(design.get(key, ""), str):
            return f"design.{key} is {design[key]!r}, not a string"
    return None


def load_tensors(path: Path):
    """``torch.load`` of tensors and plain containers only (``weights_only``), onto the CPU, its
    warnings about foreign pickles kept off stderr (callers refuse such files in their own words).
    Shared by model files and training checkpoints."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return torch.load(path, map_location="cpu", weights_only=True)
