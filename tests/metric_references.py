"""Inputs of the checks against the reference metric packages (scikit-image and torchmetrics
for SSIM/PSNR, the lpips package for LPIPS), regenerated from seeds by the tests and by the
fixture scripts in tests/imaging/data/ alike (on sys.path via pytest's `pythonpath`).

numpy (and scikit-image's shipped sample photograph) only: neither the tests nor this module
need torchmetrics, lpips or torchvision.
"""

import hashlib

import numpy as np

# AlexNet's convolutions as torchvision's ``alexnet().features`` indexes them:
# (index, in channels, out channels, kernel)
ALEXNET_CONVS = ((0, 3, 64, 11), (3, 64, 192, 5), (6, 192, 384, 3), (8, 384, 256, 3), (10, 256, 256, 3))
ALEXNET_BIAS_STD = 0.1


def alexnet_features(seed: int = 0) -> dict[str, np.ndarray]:
    """Deterministic stand-ins for torchvision's AlexNet ``features.*`` weights (float32): one
    ``np.random.default_rng(seed)`` stream, conv by conv, weight (He: normal, std √(2/fan_in),
    fan_in = in channels × kernel²) then bias (normal, std 0.1)."""
    rng = np.random.default_rng(seed)
    out = {}
    for index, cin, cout, k in ALEXNET_CONVS:
        out[f"features.{index}.weight"] = (rng.standard_normal((cout, cin, k, k)) * np.sqrt(2 / (cin * k * k))).astype(
            np.float32
        )
        out[f"features.{index}.bias"] = (rng.standard_normal(cout) * ALEXNET_BIAS_STD).astype(np.float32)
    return out


def state_sha256(state: dict[str, np.ndarray]) -> str:
    """sha256 over the arrays' keys, shapes and little-endian float32 bytes, in key order."""
    h = hashlib.sha256()
    for key, value in state.items():
        h.update(f"{key}{tuple(value.shape)}".encode())
        h.update(np.ascontiguousarray(value, dtype="<f4").tobytes())
    return h.hexdigest()


def blur(image: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian blur of the last two axes (radius ⌊3.5σ + ½⌋, mirrored borders)."""
    r = int(3.5 * sigma + 0.5)
    g = np.exp(-(np.arange(-r, r + 1) ** 2) / (2 * sigma**2))
    g /= g.sum()
    out = image
    for axis in (-2, -1):
        pad = [(0, 0)] * image.ndim
        pad[axis] = (r, r)
        padded = np.pad(out, pad, mode="reflect")
        n = out.shape[axis]
        out = sum(w * np.take(padded, np.arange(i, i + n), axis=axis) for i, w in enumerate(g))
    return out


def texture(seed: int, shape=(3, 64, 64)) -> np.ndarray:
    """A smooth colour texture in 0..1: normal noise blurred at three scales, summed, stretched."""
    rng = np.random.default_rng(seed)
    t = sum(w * blur(rng.standard_normal(shape), s) for s, w in ((0.7, 0.3), (2.0, 1.0), (5.0, 2.0)))
    return (t - t.min()) / (t.max() - t.min())


# LPIPS pairs, 3 × 64 × 64 in 0..1 (float64; fed to the networks as float32)
LPIPS_PAIRS = (
    {"name": "noise-0.03", "kind": "noise", "seed": 1, "noise_seed": 101, "sigma": 0.03},
    {"name": "noise-0.15", "kind": "noise", "seed": 2, "noise_seed": 102, "sigma": 0.15},
    {"name": "blur-1", "kind": "blur", "seed": 3, "sigma": 1.0},
    {"name": "blur-3", "kind": "blur", "seed": 4, "sigma": 3.0},
    {"name": "shift-3px", "kind": "shift", "seed": 5, "pixels": 3},
    {"name": "colour", "kind": "colour", "seed": 6, "gain": [1.15, 1.0, 0.8], "offset": [0.0, 0.03, 0.06]},
    {"name": "brighter", "kind": "offset", "seed": 7, "offset": 0.1},
    {"name": "unrelated", "kind": "unrelated", "seed": 8, "other_seed": 9},
    {"name": "uniform-noise", "kind": "uniform", "seed": 10},
)


def lpips_pair(recipe: dict, size: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """The (reference, distorted) pair that ``recipe`` (one of :data:`LPIPS_PAIRS`) describes."""
    kind, shape = recipe["kind"], (3, size, size)
    if kind == "shift":  # two crops of one wider texture, ``pixels`` apart horizontally
        wide = texture(recipe["seed"], (3, size, size + recipe["pixels"]))
        return wide[..., :size], wide[..., recipe["pixels"] :]
    if kind == "uniform":
        rng = np.random.default_rng(recipe["seed"])
        return rng.random(shape), rng.random(shape)
    x = texture(recipe["seed"], shape)
    if kind == "noise":
        noise = np.random.default_rng(recipe["noise_seed"]).standard_normal(shape)
        return x, np.clip(x + recipe["sigma"] * noise, 0, 1)
    if kind == "blur":
        return x, blur(x, recipe["sigma"])
    if kind == "colour":
        gain, offset = (np.array(recipe[k])[:, None, None] for k in ("gain", "offset"))
        return x, np.clip(gain * x + offset, 0, 1)
    if kind == "offset":
        return x, np.clip(x + recipe["offset"], 0, 1)
    if kind == "unrelated":
        return x, texture(recipe["other_seed"], shape)
    raise ValueError(kind)


def photograph() -> np.ndarray:
    """A 3 × 96 × 128 crop of scikit-image's astronaut photograph (her face and the flag), 0..1."""
    from skimage import data

    return data.astronaut()[40:136, 160:288].transpose(2, 0, 1) / 255.0


def ssim_pairs() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """(reference, distorted) pairs, 3 × 96 × 128 in 0..1 (float64), for SSIM and PSNR: the
    photograph with noise, blur, a constant shift and a colour change, and two textures."""
    photo = photograph()
    noise = np.random.default_rng(11).standard_normal(photo.shape)
    rng = np.random.default_rng(12)
    return {
        "photo-noise": (photo, np.clip(photo + 0.05 * noise, 0, 1)),
        "photo-blur": (photo, blur(photo, 2.0)),
        "photo-shift": (photo, np.clip(photo + 0.1, 0, 1)),
        "photo-colour": (photo, np.clip(photo * np.array([1.1, 0.95, 0.8])[:, None, None], 0, 1)),
        "noise-vs-noise": (rng.random(photo.shape), rng.random(photo.shape)),
        "texture-blur": (texture(13, photo.shape), blur(texture(13, photo.shape), 1.0)),
    }
