"""LPIPS v0.1 ("alex", Zhang et al. 2018) in plain torch, from weight files already on disk.

Nothing is downloaded and neither ``lpips`` nor ``torchvision`` is imported. Two files are
needed: torchvision's AlexNet state dict ``alexnet-owt-7be5be79.pth`` (only the ``features.*``
convolutions are used) and the lpips package's linear calibration ``weights/v0.1/alex.pth``
(``lin0.model.1.weight`` … ``lin4.model.1.weight``, each (1, C, 1, 1)).

Conventions: images are display (sRGB-encoded) values in 0..1, shaped (3, H, W) or (B, 3, H, W),
with H, W >= :data:`MIN_PIXELS`; they are mapped to -1..1 (2x - 1) before the network. The
distance is 0 for identical images and grows with perceptual difference (typically 0..1).
Given the same weights it equals the lpips package's ``LPIPS(net="alex", version="0.1")(x, y,
normalize=True)`` (tests/imaging/test_lpips.py, against lpips 0.1.4: within 2e-8).
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import NamedTuple

import torch
from torch import nn

from metalens_cli.constants import LPIPS_WEIGHTS_ENV
from metalens_cli.errors import InputError

ALEXNET_FILE = "alexnet-owt-7be5be79.pth"  # torchvision's ImageNet AlexNet weights
LIN_FILE = "alex.pth"  # lpips package, weights/v0.1/alex.pth
ENV_VAR = LPIPS_WEIGHTS_ENV
MIN_PIXELS = 31  # smallest H, W for which AlexNet's fifth ReLU is at least 1 × 1

# (state-dict index, in channels, out channels, kernel, stride, padding) of AlexNet's convolutions;
# a ReLU follows each, max-pooling (3, stride 2) fills the gaps in the indices (after the first two ReLUs).
_CONVS = (
    (0, 3, 64, 11, 4, 2),
    (3, 64, 192, 5, 1, 2),
    (6, 192, 384, 3, 1, 1),
    (8, 384, 256, 3, 1, 1),
    (10, 256, 256, 3, 1, 1),
)
_SHIFT = (-0.030, -0.088, -0.188)  # LPIPS v0.1 scaling layer, on -1..1 inputs
_SCALE = (0.458, 0.448, 0.450)
_EPS = 1e-10


class LpipsWeights(NamedTuple):
    """Paths of the two weight files."""

    alexnet: Path
    lin: Path


def _expected_forms():
    alex = {f"features.{i}.weight": (cout, cin, k, k) for i, cin, cout, k, _, _ in _CONVS}
    alex.update({f"features.{i}.bias": (cout,) for i, _, cout, _, _, _ in _CONVS})
    lin = {f"lin{n}.model.1.weight": (1, cout, 1, 1) for n, (_, _, cout, _, _, _) in enumerate(_CONVS)}
    return alex, lin


def _complete(directory: Path) -> LpipsWeights | None:
    paths = LpipsWeights(directory / ALEXNET_FILE, directory / LIN_FILE)
    return paths if all(p.is_file() for p in paths) else None


def _lpips_package_lin() -> Path | None:
    """The installed lpips package's weights/v0.1/alex.pth, located without importing lpips."""
    try:
        spec = importlib.util.find_spec("lpips")
    except (ImportError, ValueError):
        return None
    for location in (spec.submodule_search_locations or []) if spec else []:
        candidate = Path(location) / "weights" / "v0.1" / LIN_FILE
        if candidate.is_file():
            return candidate
    return None


def find_lpips_weights(directory: str | os.PathLike | None = None) -> tuple[LpipsWeights | None, str | None]:
    """Locate the LPIPS weight files; (paths, None) when found, else (None, one-line note).

    Looked up in order: ``directory`` (must hold both ``alexnet-owt-7be5be79.pth`` and
    ``alex.pth``; an explicit directory lacking either is an :class:`InputError`), the directory
    in ``$METALENS_LPIPS_WEIGHTS``, then torch hub's ``checkpoints`` folder for the AlexNet file
    together with an installed lpips package's ``weights/v0.1/alex.pth``. Nothing is downloaded.
    """
    expected = f"a directory holding {ALEXNET_FILE} and {LIN_FILE}"
    if directory is not None:
        found = _complete(Path(directory))
        if found is None:
            missing = ", ".join(
                p.name
                for p in LpipsWeights(Path(directory) / ALEXNET_FILE, Path(directory) / LIN_FILE)
                if not p.is_file()
            )
            raise InputError("--lpips-weights", f"{directory} lacks {missing}", expected)
        return found, None
    looked = []
    env = os.environ.get(ENV_VAR)
    if env:
        found = _complete(Path(env))
        if found is not None:
            return found, None
        looked.append(f"${ENV_VAR}={env} incomplete")
    else:
        looked.append(f"${ENV_VAR} unset")
    hub_alexnet = Path(torch.hub.get_dir()) / "checkpoints" / ALEXNET_FILE
    package_lin = _lpips_package_lin()
    if hub_alexnet.is_file() and package_lin is not None:
        return LpipsWeights(hub_alexnet, package_lin), None
    looked.append(
        f"{hub_alexnet} {'present' if hub_alexnet.is_file() else 'absent'}, "
        f"lpips package's weights/v0.1/{LIN_FILE} {'absent' if package_lin is None else 'present'}"
    )
    return None, (
        f"LPIPS skipped, no weights found ({'; '.join(looked)}); nothing is downloaded: pass --lpips-weights "
        f"or set ${ENV_VAR} to {expected}"
    )


def _load_state(path: Path, expected: dict, what: str) -> dict:
    """The tensors named in ``expected`` from the state dict at ``path``, checked for shape."""
    form = f"{what} state dict ({', '.join(f'{k} {tuple(v)}' for k, v in list(expected.items())[:2])}, …)"
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # unreadable, not a torch file, or unsafe pickle content
        raise InputError(str(path), f"cannot be read as a torch state dict ({type(exc).__name__})", form) from None
    if not isinstance(state, dict):
        raise InputError(str(path), f"holds a {type(state).__name__}, not a state dict", form)
    out = {}
    for key, shape in expected.items():
        value = state.get(key)
        if value is None and key.startswith("lin"):  # saved without the dropout layer in front
            value = state.get(key.replace(".model.1.", ".model.0."))
        if not isinstance(value, torch.Tensor):
            raise InputError(str(path), f"has no tensor {key}", form)
        if tuple(value.shape) != shape:
            raise InputError(str(path), f"{key} has shape {tuple(value.shape)}, not {shape}", form)
        out[key] = value.to(torch.float32)
    return out


class Lpips(nn.Module):
    """LPIPS v0.1 with the AlexNet trunk: ``forward(x, y)`` → one distance per batch entry.

    ``x``, ``y``: (B, 3, H, W) in -1..1 (use :func:`lpips_distance` for 0..1 sRGB images).
    ``features`` is indexed like torchvision's ``alexnet().features`` so its state dict loads
    as is; ``lins`` are the five 1×1 bias-free calibration convolutions. Build from files with
    :meth:`from_files`; the module is in eval mode with gradients off for its parameters.
    """

    def __init__(self):
        super().__init__()
        layers: list[nn.Module] = []
        for index, cin, cout, k, stride, pad in _CONVS:
            while len(layers) < index:
                layers.append(nn.MaxPool2d(3, 2))
            layers += [nn.Conv2d(cin, cout, k, stride=stride, padding=pad), nn.ReLU()]
        self.features = nn.Sequential(*layers)
        self.taps = tuple(index + 1 for index, *_ in _CONVS)  # the five ReLU outputs
        self.lins = nn.ModuleList(nn.Conv2d(cout, 1, 1, bias=False) for _, _, cout, _, _, _ in _CONVS)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1))

    @classmethod
    def from_files(cls, alexnet_path: str | os.PathLike, lin_path: str | os.PathLike) -> Lpips:
        """Load torchvision's AlexNet state dict and the lpips v0.1 ``alex.pth`` (CPU, float32).

        Raises :class:`InputError` naming the file when a key is missing or has the wrong shape.
        """
        alex_form, lin_form = _expected_forms()
        alex = _load_state(Path(alexnet_path), alex_form, "torchvision AlexNet")
        lin = _load_state(Path(lin_path), lin_form, "lpips v0.1 alex")
        model = cls()
        with torch.no_grad():
            for key, value in alex.items():
                _, index, name = key.split(".")
                getattr(model.features[int(index)], name).copy_(value)
            for n in range(len(_CONVS)):
                model.lins[n].weight.copy_(lin[f"lin{n}.model.1.weight"])
        model.requires_grad_(False)
        return model.eval()

    @classmethod
    def load(cls, directory: str | os.PathLike | None = None) -> Lpips | None:
        """:func:`find_lpips_weights` then :meth:`from_files`; None when no weights are found."""
        paths, _ = find_lpips_weights(directory)
        return None if paths is None else cls.from_files(paths.alexnet, paths.lin)

    def layer_features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The five ReLU outputs for (B, 3, H, W) inputs in -1..1 (after the scaling layer)."""
        h = (x - self.shift) / self.scale
        out = []
        for i, layer in enumerate(self.features):
            h = layer(h)
            if i in self.taps:
                out.append(h)
        return out

    def forward(self, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """LPIPS distance (B,) between ``x`` and ``y``, both (B, 3, H, W) in −1..1: at each of the
        five taps the channel-normalised features' squared difference, weighted by the learned 1×1
        layer and averaged over space, summed over the taps."""
        feats = self.layer_features(torch.cat([x, y]))
        total = 0
        for f, lin in zip(feats, self.lins):
            f = f / (f.pow(2).sum(dim=1, keepdim=True).sqrt() + _EPS)
            fx, fy = f.chunk(2)
            total = total + lin((fx - fy) ** 2).mean(dim=(-3, -2, -1))
        return total


def lpips_distance(model: Lpips, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """LPIPS between sRGB images in 0..1, (3, H, W) → scalar or (B, 3, H, W) → (B,).

    Inputs are cast to the model's dtype and device; differentiable (wrap in ``torch.no_grad``
    for evaluation).
    """
    if x.shape != y.shape or x.ndim not in (3, 4) or x.shape[-3] != 3:
        raise InputError(
            "images", f"shapes {tuple(x.shape)} and {tuple(y.shape)}", "equal (3, H, W) or (B, 3, H, W) shapes"
        )
    if min(x.shape[-2:]) < MIN_PIXELS:
        raise InputError(
            "images", f"{tuple(x.shape[-2:])} pixels", f"images at least {MIN_PIXELS} × {MIN_PIXELS} for LPIPS"
        )
    p = model.shift
    single = x.ndim == 3
    x, y = (t.to(dtype=p.dtype, device=p.device).reshape(-1, *t.shape[-3:]) for t in (x, y))
    d = model(2 * x - 1, 2 * y - 1)
    return d[0] if single else d
