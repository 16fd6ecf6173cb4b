"""Training pairs for the reconstruction network: simulated through a design, or read from disk.

Simulated pairs use the image formation of ``simulate`` (``imaging.formation.form_image``): a
pool of captures of ``data.pool_pixels``² sensor pixels on the canvas their PSF windows need,
each with its own clean scene (generated, or a random crop of ``data.images``), obstruction kind
and depths from a bank of PSFs at stratum midpoints of the camera's depth intervals. Every entry
draws from its own (seed, generation, index) streams, so a resumed run rebuilds the same pool.
Each training step takes random crops of pool entries and augments them (:func:`batch`).

Captured pairs (``--pairs DIR``)::

    DIR/gt/NAME.png             the clean reference (any of PNG, JPEG, TIFF, EXR)
    DIR/captures/NAME.png       a capture of scene NAME through the lens, aligned to gt/NAME
    DIR/captures/NAME@K.png     further captures of the same scene (K any text)

Every scene of gt/ has a capture and every capture a gt image. 8/16-bit files are sRGB-encoded,
EXR linear. The last tenth of the scenes (by name; at least one) are held out for validation, all
captures of a scene on the same side, so training and validation scenes are disjoint (hence at
least two scenes). ``data.validation_pairs`` is the simulated held-out pool's size only.
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.channel_psfs import ChannelPsfs, channel_psfs
from metalens_cli.imaging.formation import add_noise, canvas_margin, form_image, psf_transform
from metalens_cli.imaging.network import pixel_positions
from metalens_cli.imaging.obstructions import make_obstruction
from metalens_cli.io.input_files import IMAGE_SUFFIXES

VALIDATION_GENERATION = 2**40  # the held-out pool's generation, far from any training generation
MIN_SCENES = 2  # captured scenes: one to train on, one held out for validation


@dataclass(frozen=True)
class Camera:
    """What the design's camera fixes: pixel pitch (m), depth intervals (m), obstruction sizes."""

    pixel_pitch_m: float
    z_near_m: tuple[float, float]
    z_far_m: tuple[float, float]
    obstruction_params: object = None


@dataclass
class Pool:
    """Linear (P, 3, S, S) float32 arrays: clean sensor images, obstructed and unobstructed captures;
    where each lies on a sensor of ``sensor`` pixels a side (``offsets`` (P, 2): top and left
    pixel; None: each capture is the whole sensor)."""

    clean: np.ndarray
    obstructed: np.ndarray
    unobstructed: np.ndarray
    kinds: list[str]
    seconds: float = 0.0
    offsets: np.ndarray | None = None
    sensor: int | None = None

    @cached_property
    def obstructed_means(self) -> np.ndarray:
        """(P, 3) mean of each obstructed capture per channel (float64 sums)."""
        return self.obstructed.mean(axis=(2, 3), dtype=np.float64).astype(np.float32)

    @cached_property
    def unobstructed_means(self) -> np.ndarray:
        """(P, 3) mean of each unobstructed capture per channel (float64 sums)."""
        return self.unobstructed.mean(axis=(2, 3), dtype=np.float64).astype(np.float32)

    def __post_init__(self):
        if self.sensor is None:
            self.sensor = int(self.clean.shape[-1])
        if self.offsets is None:
            self.offsets = np.full((len(self.clean), 2), (self.sensor - self.clean.shape[-1]) // 2)

    def __len__(self) -> int:
        return len(self.clean)


def strata(interval: tuple[float, float], count: int) -> list[float]:
    """Midpoints of ``count`` equal strata of a depth interval; in inverse depth if it reaches ∞."""
    lo, hi = interval
    if math.isinf(hi):
        return [1 / ((1 - (k + 0.5) / count) / lo) if k + 0.5 < count else math.inf for k in range(count)]
    return [lo + (k + 0.5) * (hi - lo) / count for k in range(count)]


@dataclass
class PsfBank:
    """Channel PSFs at the near and far stratum midpoints, and what they cost."""

    near: list[ChannelPsfs]
    far: list[ChannelPsfs]

    @property
    def margin(self) -> int:
        """Canvas margin (pixels) the largest near or far PSF window needs around the sensor."""
        return canvas_margin(*(p.near.shape[-1] for p in self.near), *(p.far.shape[-1] for p in self.far))

    def report(self) -> dict:
        """JSON-ready: the stratum depths (m; an infinite far depth as None), the window sides
        (pixels), the least fraction of a channel's light any near and any far window kept, and the
        seconds of the PSF calls (each counted once)."""
        return {
            "z_near_m": [p.z_near_m for p in self.near],
            "z_far_m": [p.z_far_m if math.isfinite(p.z_far_m) else None for p in self.far],
            "windows_px": {"near": [p.near.shape[-1] for p in self.near], "far": [p.far.shape[-1] for p in self.far]},
            "kept": {
                "near_min": min(min(p.kept_near) for p in self.near),
                "far_min": min(min(p.kept_far) for p in self.far),
            },
            "seconds": sum(p.seconds for p in {id(p): p for p in self.near + self.far}.values()),
        }

    def warnings(self) -> list[str]:
        """The PSFs' warnings (a window that kept less than ``KEPT_WARNING`` of a channel's light),
        each once, sorted."""
        return sorted({w for p in self.near + self.far for w in p.warnings()})


def psf_bank(design, camera: Camera, data, device="cpu") -> PsfBank:
    """PSFs for every near and far depth stratum (one ``channel_psfs`` call per pair of strata)."""
    near_z, far_z = strata(camera.z_near_m, data.near_depths), strata(camera.z_far_m, data.far_depths)
    calls = [
        channel_psfs(
            design,
            near_z[k % len(near_z)],
            far_z[k % len(far_z)],
            list(data.wavelengths_m),
            camera.pixel_pitch_m,
            device=device,
        )
        for k in range(max(len(near_z), len(far_z)))
    ]
    return PsfBank(calls[: len(near_z)], calls[: len(far_z)])


def _scene(data, canvas: int, sensor: int, rng: np.random.Generator, photos: list[np.ndarray] | None) -> np.ndarray:
    from metalens_cli.design.scenes import procedural_scene, random_crop
    from metalens_cli.imaging.dead_leaves import dead_leaves

    if photos:
        return random_crop(photos[rng.integers(len(photos))], (canvas, canvas), rng)
    kind = data.scenes if data.scenes != "mixed" else ("natural", "dead-leaves")[rng.integers(2)]
    if kind in ("natural", "procedural"):
        return procedural_scene((canvas, canvas), rng, (canvas - sensor) // 2, structure=kind == "natural")
    return dead_leaves((canvas, canvas), 1000 + int(rng.integers(2**31)), sensor_shape=(sensor, sensor))


def simulate_pool(
    design,
    camera: Camera,
    data,
    bank: PsfBank,
    seed: int,
    generation: int,
    count: int,
    photos: list[np.ndarray] | None = None,
    device="cpu",
    threads: int = 1,
) -> Pool:
    """``count`` simulated pairs of generation ``generation`` (entries drawn from (seed, generation, index))."""
    import time

    start = time.perf_counter()
    s, margin = data.pool_pixels, bank.margin
    canvas = s + 2 * margin
    transforms = {}
    for k, p in enumerate(bank.near):
        transforms["near", k] = psf_transform(p.near, (s, s))
    for k, p in enumerate(bank.far):
        transforms["far", k] = psf_transform(p.far, (s, s))

    def entry(index: int):
        rng = np.random.default_rng([seed, generation, index, 29])
        clean = _scene(data, canvas, s, rng, photos)
        kind = data.obstructions[rng.integers(len(data.obstructions))]
        i, j = int(rng.integers(len(bank.near))), int(rng.integers(len(bank.far)))
        obstruction = make_obstruction(
            kind,
            (s, s),
            bank.near[i].z_near_m,
            design.focal_length_m,
            camera.pixel_pitch_m,
            [seed, generation, index, 31],
            params=camera.obstruction_params,
            clean=clean,
            margin=margin,
        )
        with torch.no_grad():
            tensors = (
                torch.as_tensor(a, dtype=torch.float32, device=device)
                for a in (clean, obstruction.rgb, obstruction.mask)
            )
            capture = form_image(*tensors, transforms["near", i], transforms["far", j], margin)
            obstructed, unobstructed = capture.obstructed, capture.unobstructed
            if data.photons or data.read_noise:
                noise_seed = int(rng.integers(2**62))
                obstructed = add_noise(
                    obstructed, data.photons or None, read_noise=data.read_noise, generator=noise_seed
                )
                unobstructed = add_noise(
                    unobstructed, data.photons or None, read_noise=data.read_noise, generator=noise_seed + 1
                )
        return (
            clean[:, margin : margin + s, margin : margin + s],
            obstructed.cpu().numpy(),
            unobstructed.cpu().numpy(),
            kind,
        )

    with ThreadPoolExecutor(max_workers=max(1, threads)) as workers:
        entries = list(workers.map(entry, range(count)))
    clean, obstructed, unobstructed, kinds = zip(*entries)
    # the formation is shift-invariant: each capture may lie anywhere on the sensor (its own stream)
    offsets = np.array(
        [
            np.random.default_rng([seed, generation, k, 41]).integers(data.sensor_pixels - s + 1, size=2)
            for k in range(count)
        ]
    )
    return Pool(
        np.stack(clean).astype(np.float32),
        np.stack(obstructed).astype(np.float32),
        np.stack(unobstructed).astype(np.float32),
        list(kinds),
        time.perf_counter() - start,
        offsets,
        data.sensor_pixels,
    )


def read_pairs(folder: str | Path) -> tuple[Pool, Pool]:
    """Training and validation pools from captured pairs (layout in the module docstring); every
    image is cropped to the common smallest square so pools stack."""
    from metalens_cli.imaging.captured_pairs import check_scenes, images_by_stem
    from metalens_cli.imaging.images import read_linear

    root = Path(folder)
    gt_dir, capture_dir = root / "gt", root / "captures"
    if not gt_dir.is_dir() or not capture_dir.is_dir():
        raise InputError(
            "--pairs", f"{str(root)!r} lacks gt/ or captures/", "a folder with gt/NAME.png and captures/NAME[@K].png"
        )

    def files(d: Path) -> list[Path]:
        return sorted(p for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))

    gts = images_by_stem(gt_dir, "--pairs")  # two files of one scene are refused, as by evaluate --pairs
    pairs = [(p.stem.split("@")[0], p) for p in files(capture_dir)]
    if not pairs:
        raise InputError(
            "--pairs", f"{str(capture_dir)!r} holds no images", f"files ending in {', '.join(IMAGE_SUFFIXES)}"
        )
    check_scenes(
        "captures", {name for name, _ in pairs}, gts
    )  # evaluate --pairs' rule: every gt scene captured, and no more
    scenes = sorted(gts)
    if len(scenes) < MIN_SCENES:
        raise InputError(
            "--pairs",
            f"{str(root)!r} holds {len(scenes)} scene ({scenes[0]}), too few to hold out validation scenes "
            "apart from the training ones",
            f"at least {MIN_SCENES} scenes with their captures: the last tenth by name, "
            "at least one, is held out for validation",
        )
    held = set(scenes[len(scenes) - max(1, len(scenes) // 10) :])  # ≥ 1 scene left to train on
    loaded = []
    for name, path in pairs:
        gt, capture = read_linear(gts[name], "--pairs"), read_linear(path, "--pairs")
        if gt.shape != capture.shape:
            raise InputError(
                "--pairs",
                f"{path.name} is {capture.shape[1:]} but gt/{gts[name].name} is {gt.shape[1:]}",
                "captures aligned to their gt image (metalens align), of equal size",
            )
        loaded.append((name in held, gt, capture))
    side = min(min(gt.shape[1:]) for _, gt, _ in loaded)

    def centre(a: np.ndarray) -> np.ndarray:
        top, left = (a.shape[1] - side) // 2, (a.shape[2] - side) // 2
        return a[:, top : top + side, left : left + side]

    def pool(hold: bool) -> Pool:  # the scenes of the two pools are disjoint, neither is empty
        chosen = [(centre(g), centre(c)) for h, g, c in loaded if h == hold]
        clean, capture = (np.stack(x).astype(np.float32) for x in zip(*chosen))
        return Pool(clean, capture, capture, ["captured"] * len(clean))

    return pool(False), pool(True)


@dataclass
class Batch:
    """Network input (B, 3, c, c), target (B, 3, c, c), sensor positions (B, 2, c, c) and the mean
    of each input's whole capture (B, 3, 1, 1), which the network's contrast is relative to."""

    inputs: torch.Tensor
    targets: torch.Tensor
    positions: torch.Tensor
    means: torch.Tensor


def batch(pool: Pool, data, crop: int, seed: int, step: int, indices: list[int], device="cpu") -> Batch:
    """Entries ``indices`` of step ``step``'s batch: a random pool entry (unobstructed with
    probability ``data.clear_fraction``), a random ``crop``² window with its positions on the
    pool's sensor (units of half its side), one of the 8 flips/quarter turns applied to all three,
    then gain, contrast and Gaussian noise on the input only (the capture's mean follows the gain
    and contrast)."""
    s = pool.clean.shape[-1]
    scale = pool.sensor / 2
    inputs, targets, positions, means = [], [], [], []
    for index in indices:
        rng = np.random.default_rng([seed, step, index, 37])
        p = int(rng.integers(len(pool)))
        clear = rng.random() < data.clear_fraction
        source = pool.unobstructed if clear else pool.obstructed
        top, left = int(rng.integers(s - crop + 1)), int(rng.integers(s - crop + 1))
        window = (slice(None), slice(top, top + crop), slice(left, left + crop))
        x = torch.from_numpy(np.ascontiguousarray(source[p][window]))
        y = torch.from_numpy(np.ascontiguousarray(pool.clean[p][window]))
        oy, ox = (int(v) for v in pool.offsets[p])
        u = pixel_positions(crop, crop, top=oy + top, left=ox + left, full=(pool.sensor,) * 2, scale=scale)
        turns, flip = int(rng.integers(4)), bool(rng.integers(2))
        x, y, u = (_orient(t, turns, flip) for t in (x, y, u))  # each pixel keeps its sensor position
        gain = 1 + rng.uniform(-data.brightness, data.brightness)
        contrast = 1 + rng.uniform(-data.contrast, data.contrast)
        mean = x.mean()
        # gain·((x − μ)·contrast + μ), written so that gain = contrast = 1 leaves x bit for bit
        x = (gain * contrast) * x + (gain * (1 - contrast)) * mean
        whole = torch.from_numpy((pool.unobstructed_means if clear else pool.obstructed_means)[p])[:, None, None]
        means.append((gain * contrast) * whole + (gain * (1 - contrast)) * mean)
        if data.noise_sigma:
            noise = torch.randn(x.shape, generator=torch.Generator().manual_seed(int(rng.integers(2**62))))
            x = x + data.noise_sigma * noise
        inputs.append(x)
        targets.append(y)
        positions.append(u)
    return Batch(*(torch.stack(t).to(device) for t in (inputs, targets, positions, means)))


def _orient(t: torch.Tensor, turns: int, flip: bool) -> torch.Tensor:
    t = torch.rot90(t, turns, dims=(-2, -1))
    return t.flip(-1) if flip else t
