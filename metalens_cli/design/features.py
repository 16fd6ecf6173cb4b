"""Domain-adaptation (DA) feature loss: DeepLabv3+ encoder features, written in plain torch.

The paper's image loss is L_img = L1 + (1 − SSIM) + L_DA, where L_DA is an L1 distance between
features that DeepLabv3+ (Chen et al. 2018) extracts from the simulated capture and from the clean
image.  This module rebuilds the DeepLabv3+ *encoder* — a ResNet-50/101 backbone at output stride
16 plus the ASPP head — and loads its weights from a checkpoint of the public
VainF/DeepLabV3Plus-Pytorch project (``best_deeplabv3plus_resnet50_*.pth`` / ``resnet101``; a dict
whose ``model_state`` holds ``backbone.*`` and ``classifier.aspp.*`` keys).  The decoder and the
classifier are not needed and their keys are ignored.  Nothing is ever downloaded: when no weights
file is given, the DA term is skipped with a one-line note (see :func:`find_deeplab_weights`).

Conventions: images are (B, 3, H, W) or (3, H, W) RGB in 0..1 (linear or display-referred; no
transfer curve is applied here), ImageNet mean/std normalisation happens inside the module, the
network is frozen (``requires_grad`` False) and always in eval mode (BatchNorm uses its running
statistics), and gradients flow to the input images.
"""

from __future__ import annotations

import os
import pickle
import re
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from metalens_cli.errors import InputError

ENV_VAR = "METALENS_DEEPLAB_WEIGHTS"
SKIP_NOTE = (
    "domain-adaptation loss skipped: no DeepLabv3+ weights "
    f"(set {ENV_VAR} or loss.domain_adaptation_weights; no download is attempted)"
)
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
ASPP_RATES_OS16 = (6, 12, 18)
ASPP_CHANNELS = 256
# Bottleneck blocks per stage (layer1..layer4) of each supported ResNet depth.
RESNET_BLOCKS = {50: (3, 4, 6, 3), 101: (3, 4, 23, 3)}
_EXPECTED_FORM = "a VainF/DeepLabV3Plus-Pytorch deeplabv3plus_resnet50/101 checkpoint with 'model_state'"


def _imagenet_stats() -> tuple[torch.Tensor, torch.Tensor]:
    """ImageNet RGB mean and std as (1, 3, 1, 1) tensors."""
    return torch.tensor(IMAGENET_MEAN).view(1, 3, 1, 1), torch.tensor(IMAGENET_STD).view(1, 3, 1, 1)


class Bottleneck(nn.Module):
    """ResNet v1.5 bottleneck: 1×1 → 3×3 (carries stride and dilation) → 1×1 (×4 channels), plus shortcut."""

    expansion = 4

    def __init__(self, inplanes: int, planes: int, stride: int = 1, dilation: int = 1, downsample: bool = False):
        super().__init__()
        out = planes * self.expansion
        self.conv1 = nn.Conv2d(inplanes, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride=stride, padding=dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, out, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(out)
        self.downsample = (
            nn.Sequential(nn.Conv2d(inplanes, out, 1, stride=stride, bias=False), nn.BatchNorm2d(out))
            if downsample
            else None
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, inplanes, H, W) → (B, 4·planes, ⌈H/stride⌉, ⌈W/stride⌉): ReLU of the three
        convolutions plus the shortcut."""
        out = F.relu(self.bn1(self.conv1(x)))
        out = F.relu(self.bn2(self.conv2(out)))
        out = self.bn3(self.conv3(out))
        shortcut = x if self.downsample is None else self.downsample(x)
        return F.relu(out + shortcut)


def _stage(inplanes: int, planes: int, blocks: int, stride: int, dilation: int, first_dilation: int) -> nn.Sequential:
    """One ResNet stage; the first block changes width/stride (torchvision's ``_make_layer``)."""
    layers = [Bottleneck(inplanes, planes, stride, first_dilation, downsample=True)]
    layers += [Bottleneck(planes * Bottleneck.expansion, planes, 1, dilation) for _ in range(blocks - 1)]
    return nn.Sequential(*layers)


class ResNetOS16(nn.Module):
    """ResNet-50/101 trunk at output stride 16: layer4 has stride 1 and dilation 2.

    Equivalent to torchvision's ``replace_stride_with_dilation=[False, False, True]``: the first
    layer4 block keeps dilation 1, the following ones use dilation 2.  Returns
    (layer1 output: 256 ch at 1/4 resolution, layer4 output: 2048 ch at 1/16 resolution).
    """

    def __init__(self, blocks: tuple[int, int, int, int] = RESNET_BLOCKS[50]):
        super().__init__()
        self.conv1 = nn.Conv2d(3, 64, 7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(64)
        self.layer1 = _stage(64, 64, blocks[0], stride=1, dilation=1, first_dilation=1)
        self.layer2 = _stage(256, 128, blocks[1], stride=2, dilation=1, first_dilation=1)
        self.layer3 = _stage(512, 256, blocks[2], stride=2, dilation=1, first_dilation=1)
        self.layer4 = _stage(1024, 512, blocks[3], stride=1, dilation=2, first_dilation=1)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """ImageNet-normalised (B, 3, H, W) → (layer1 output (B, 256, ⌈H/4⌉, ⌈W/4⌉), layer4 output
        (B, 2048, ⌈H/16⌉, ⌈W/16⌉))."""
        x = F.max_pool2d(F.relu(self.bn1(self.conv1(x))), kernel_size=3, stride=2, padding=1)
        low = self.layer1(x)
        return low, self.layer4(self.layer3(self.layer2(low)))


class _SeparableConv(nn.Module):
    """Atrous depthwise-separable 3×3 convolution (key layout ``body.0`` depthwise, ``body.1`` pointwise)."""

    def __init__(self, cin: int, cout: int, rate: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(cin, cin, 3, padding=rate, dilation=rate, groups=cin, bias=False),
            nn.Conv2d(cin, cout, 1, bias=False),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.body(x)


class _ImagePooling(nn.Sequential):
    """ASPP image-level branch: global average → 1×1 conv → BN → ReLU → bilinear back to the input size."""

    def __init__(self, cin: int, cout: int):
        super().__init__(nn.AdaptiveAvgPool2d(1), nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.interpolate(super().forward(x), size=x.shape[-2:], mode="bilinear", align_corners=False)


class ASPP(nn.Module):
    """Atrous spatial pyramid pooling: 1×1 branch, three 3×3 atrous branches, image pooling, 1×1 projection.

    ``convs`` index 0 is the 1×1 branch, 1..3 the atrous rates, 4 the image pooling; the projection
    maps 5 × 256 → 256 channels (its dropout is an identity in eval mode and is left out).
    """

    def __init__(self, cin: int = 2048, rates: tuple[int, int, int] = ASPP_RATES_OS16, separable: bool = False):
        super().__init__()
        c = ASPP_CHANNELS
        branches: list[nn.Module] = [nn.Sequential(nn.Conv2d(cin, c, 1, bias=False), nn.BatchNorm2d(c), nn.ReLU())]
        for r in rates:
            conv = _SeparableConv(cin, c, r) if separable else nn.Conv2d(cin, c, 3, padding=r, dilation=r, bias=False)
            branches.append(nn.Sequential(conv, nn.BatchNorm2d(c), nn.ReLU()))
        branches.append(_ImagePooling(cin, c))
        self.convs = nn.ModuleList(branches)
        self.project = nn.Sequential(nn.Conv2d(5 * c, c, 1, bias=False), nn.BatchNorm2d(c), nn.ReLU())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(B, cin, h, w) → (B, 256, h, w): the five branches concatenated and projected."""
        return self.project(torch.cat([branch(x) for branch in self.convs], dim=1))


class _Head(nn.Module):
    """Holds the ASPP under ``classifier.aspp`` so parameter names match the checkpoint."""

    def __init__(self, aspp: ASPP):
        super().__init__()
        self.aspp = aspp


class DeepLabFeatures(nn.Module):
    """Frozen DeepLabv3+ encoder (ResNet backbone at OS16 + ASPP) returning the DA feature maps.

    ``forward(images)`` takes RGB in 0..1, shape (B, 3, H, W) or (3, H, W), applies ImageNet
    normalisation and returns ``(low_level, aspp)``: the layer1 output (B, 256, ⌈H/4⌉, ⌈W/4⌉) and
    the ASPP output (B, 256, ⌈H/16⌉, ⌈W/16⌉).  Parameters never require grad and the module stays
    in eval mode even if ``train()`` is called; the output is differentiable in the input.
    """

    def __init__(self, depth: int = 50, separable: bool = False):
        super().__init__()
        if depth not in RESNET_BLOCKS:
            raise ValueError(f"ResNet depth {depth} is not supported (50 or 101)")
        self.depth = depth
        self.separable = separable
        self.backbone = ResNetOS16(RESNET_BLOCKS[depth])
        self.classifier = _Head(ASPP(2048, ASPP_RATES_OS16, separable))
        mean, std = _imagenet_stats()
        self.register_buffer("mean", mean, persistent=False)
        self.register_buffer("std", std, persistent=False)
        self.requires_grad_(False)
        self.eval()

    def train(self, mode: bool = True) -> DeepLabFeatures:
        """Always stays in eval mode: BatchNorm must use the checkpoint's running statistics."""
        return super().train(False)

    def normalise(self, images: torch.Tensor) -> torch.Tensor:
        """RGB 0..1 → ImageNet-normalised (x − mean) / std, batched to (B, 3, H, W)."""
        if images.ndim == 3:
            images = images.unsqueeze(0)
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(f"expected RGB images (B, 3, H, W) or (3, H, W), got shape {tuple(images.shape)}")
        return (images - self.mean) / self.std

    def forward(self, images: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """RGB in 0..1, (B, 3, H, W) or (3, H, W) → (low_level (B, 256, ⌈H/4⌉, ⌈W/4⌉), aspp (B, 256,
        ⌈H/16⌉, ⌈W/16⌉)), differentiable in ``images``."""
        low, high = self.backbone(self.normalise(images))
        return low, self.classifier.aspp(high)


# ---------------------------------------------------------------- discovery and loading


def find_deeplab_weights(path: str | os.PathLike | None = None) -> tuple[Path | None, str | None]:
    """Locate a local DeepLabv3+ checkpoint; never downloads.

    Order: the explicit ``path`` (preset key ``loss.domain_adaptation_weights``), then the
    environment variable ``METALENS_DEEPLAB_WEIGHTS``.  Returns ``(file, None)`` when found and
    ``(None, SKIP_NOTE)`` when neither is set.  A path that is given but is not a file raises
    :class:`InputError` naming where it came from.
    """
    if path is not None and str(path).strip():
        source, value = "loss.domain_adaptation_weights", str(path)
    elif os.environ.get(ENV_VAR, "").strip():
        source, value = ENV_VAR, os.environ[ENV_VAR]
    else:
        return None, SKIP_NOTE
    file = Path(value.strip()).expanduser()
    if not file.is_file():
        raise InputError(source, f"no such file: {file}", "a local DeepLabv3+ .pth checkpoint")
    return file, None


def _safe_globals() -> list:
    """numpy objects that VainF checkpoints pickle beside the tensors (``best_score`` is a numpy float)."""
    try:
        from numpy._core.multiarray import scalar
    except ImportError:  # older numpy without the numpy._core alias
        from numpy.core.multiarray import scalar
    dtypes = [getattr(np.dtypes, n) for n in dir(np.dtypes) if n.endswith("DType")] if hasattr(np, "dtypes") else []
    return [np.dtype, scalar, (scalar, "numpy.core.multiarray.scalar"), *dtypes]


def _read_state(path: Path, field: str) -> dict[str, torch.Tensor]:
    """The ``model_state`` dict of a checkpoint, read with ``weights_only=True`` (no arbitrary unpickling)."""
    try:
        with torch.serialization.safe_globals(_safe_globals()):
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        refused = re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(exc))
        if refused:
            message = f"holds a Python object ({refused.group(1)}) that a weights-only load refuses"
            raise InputError(field, message, _EXPECTED_FORM) from None
        raise InputError(field, f"not a readable torch checkpoint ({type(exc).__name__})", _EXPECTED_FORM) from None
    except Exception as exc:  # corrupt or not a torch file at all
        raise InputError(field, f"not a readable torch checkpoint ({type(exc).__name__})", _EXPECTED_FORM) from None
    if isinstance(ckpt, dict) and isinstance(ckpt.get("model_state"), dict):
        state = ckpt["model_state"]
    elif isinstance(ckpt, dict) and any(str(k).startswith(("backbone.", "module.backbone.")) for k in ckpt):
        state = ckpt  # a bare state_dict of the same model
    else:
        raise InputError(field, "no 'model_state' dict in the checkpoint", _EXPECTED_FORM)
    return {
        (k[7:] if k.startswith("module.") else k): v for k, v in state.items() if isinstance(k, str)
    }  # DataParallel


def _blocks_per_stage(state: dict) -> tuple[int, ...]:
    """Number of bottleneck blocks in backbone.layer1..4, read from the key names."""
    counts = []
    for stage in range(1, 5):
        prefix = f"backbone.layer{stage}."
        idx = {k[len(prefix) :].split(".", 1)[0] for k in state if k.startswith(prefix)}
        counts.append(len({i for i in idx if i.isdigit()}))
    return tuple(counts)


def _build(path: Path, field: str) -> DeepLabFeatures:
    """Construct the encoder that matches the checkpoint and load it, checking every key and shape used."""
    state = _read_state(path, field)
    blocks = _blocks_per_stage(state)
    depth = next((d for d, b in RESNET_BLOCKS.items() if b == blocks), None)
    if not any(blocks):
        raise InputError(field, "no ResNet backbone keys (backbone.layer1..4.*)", _EXPECTED_FORM)
    if depth is None:
        raise InputError(
            field, f"backbone blocks per stage {blocks} are neither ResNet-50 nor ResNet-101", _EXPECTED_FORM
        )
    with torch.device("meta"):  # shapes only: skips the random initialisation of ~40-60 M weights
        model = DeepLabFeatures(depth, separable="classifier.aspp.convs.1.0.body.0.weight" in state)
    wanted = model.state_dict()
    # num_batches_tracked only counts training steps; older checkpoints lack it and eval ignores it.
    missing = [k for k in wanted if k not in state and not k.endswith("num_batches_tracked")]
    if missing:
        more = f" and {len(missing) - 3} more" if len(missing) > 3 else ""
        raise InputError(field, f"missing {len(missing)} key(s): {', '.join(missing[:3])}{more}", _EXPECTED_FORM)
    for key, ref in wanted.items():
        got = state.get(key, ref)
        if not isinstance(got, torch.Tensor):
            raise InputError(field, f"{key} is a {type(got).__name__}, not a tensor", _EXPECTED_FORM)
        if tuple(got.shape) != tuple(ref.shape):
            message = f"{key} has shape {tuple(got.shape)}, ResNet-{depth} needs {tuple(ref.shape)}"
            raise InputError(field, message, _EXPECTED_FORM)
    tensors = {}
    for key, ref in wanted.items():
        if key not in state:  # num_batches_tracked only
            tensors[key] = torch.zeros((), dtype=ref.dtype)
        else:  # float32 (int64 for the counters), contiguous, whatever the file stored
            tensors[key] = state[key].to(ref.dtype).contiguous()
    model.load_state_dict(tensors, strict=True, assign=True)
    model.mean, model.std = _imagenet_stats()  # non-persistent buffers, still on the meta device
    return model


_CACHE: dict[tuple[str, int, int], DeepLabFeatures] = {}
_CACHE_SIZE = 2  # a ResNet-101 encoder is ~250 MB of float32


def load_feature_extractor(path: str | os.PathLike) -> DeepLabFeatures:
    """Load (or reuse) the frozen DeepLabv3+ encoder stored in the checkpoint at ``path``.

    ResNet-50 vs -101 and a separable-convolution ASPP are detected from the key names; decoder
    and classifier keys are ignored; a missing key or a wrong shape raises :class:`InputError`
    with ``field`` = the file path.  Results are cached per (resolved path, mtime, size), so
    repeated calls return the same module (CPU, float32 unless moved by :func:`feature_l1`).
    """
    file = Path(path).expanduser().resolve()
    if not file.is_file():
        raise InputError(str(path), "no such file", "a local DeepLabv3+ .pth checkpoint")
    stat = file.stat()
    key = (str(file), stat.st_mtime_ns, stat.st_size)
    if key in _CACHE:
        return _CACHE[key]
    model = _build(file, str(path))
    for old in [k for k in _CACHE if k[0] == key[0]]:  # the file was rewritten
        del _CACHE[old]
    while len(_CACHE) >= _CACHE_SIZE:
        del _CACHE[next(iter(_CACHE))]
    _CACHE[key] = model
    return model


def feature_l1(extractor: DeepLabFeatures, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """DA loss: mean |F(x) − F(y)| over the layer1 features plus the same over the ASPP features.

    ``x`` (simulated capture) and ``y`` (clean image) are RGB in 0..1 of equal shape (B, 3, H, W)
    or (3, H, W).  The extractor is moved to the inputs' device if needed and runs in its own
    dtype (float32); the scalar loss is returned in the inputs' floating dtype.  Dimensionless.
    """
    if x.shape != y.shape:
        raise ValueError(f"feature_l1: shapes differ {tuple(x.shape)} vs {tuple(y.shape)}")
    param = next(extractor.parameters())
    if param.device != x.device:
        extractor.to(x.device)
    fx, fy = extractor(x.to(param.dtype)), extractor(y.to(param.dtype))
    loss = sum((a - b).abs().mean() for a, b in zip(fx, fy))
    return loss.to(x.dtype) if x.is_floating_point() else loss
