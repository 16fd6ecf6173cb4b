"""Measured PSF frames to a PSF cube (``metalens psf import``): the bench protocol.

Per frame (values as stored; colour frames averaged over R, G, B, alpha dropped):

1. **Saturation**: pixels at or above the saturation code (default the file's full scale,
   65535 for 16-bit) are counted. A frame with any is refused unless saturated frames are
   allowed, and then it is reported in the result and the cube's header: never silently used.
2. **Dark frame** subtracted (taken at the same exposure: that is the bench's business), then
   the frame is divided by its exposure when given (counts per second), so that repeats taken
   with different exposures average correctly. A dark frame brighter than a frame's background
   (by over 3σ: another exposure or gain) is warned about, once for all such frames.
3. **Background**: a plane a + b·x + c·y fitted to a border strip (5 % of the smaller side,
   at least 4 pixels; pixels beyond 5σ left out) is subtracted, so stray light tilting across
   the frame does not pull the centroid; the noise σ is 1.4826 × the strip's median absolute
   deviation about the plane, and at least 1e-6 of the frame's largest value (a simulated,
   noiseless spot has σ = 0: only light above the plane's rounding counts). A frame with no
   light above 3σ (flat, or saturated all over) is refused. Light in the strip (the PSF wider
   than the frame: the sides' middles stand above the corners) is warned about: its wings are
   taken for background.
4. **Hot pixels**: pixels standing more than k·σ (k = ``hot_pixel_sigma``, 6) above the median
   of their 3 × 3 neighbourhood in the dark frame, or in 90 % of the frames and on a dark
   background (their neighbourhood's median below 3σ) in half of them, are replaced by that
   median. Photon noise inside the light stands above the background's σ in many frames, but
   not on a dark background; a sharp PSF core spikes in its own frames only. Without a dark
   frame this needs at least 3 frames; a hot pixel inside the light of most frames can only
   be found with a dark frame.
5. **Centre**: the light's centroid (pixels above 3σ, weighted by their excess over 3σ, in a
   disc around the brightest smoothed spot, iterated) or its peak (a Gaussian fitted through
   the maximum and its four neighbours), in frame pixels. The window is moved by whole pixels
   and by the remaining fraction with a Fourier shift (a phase ramp), so the centre lands on
   the centre of pixel (N//2, N//2) (``docs/formats.md``). Separate patches of light off the spot (a ghost,
   a second source: ≥ 10 % of its light, centred away from it, unlike its rings) are
   reported (``other_spots``) and warned about: the centroid and the window take them too.
6. **Crop** to N × N: given, or the smallest odd window holding 99.5 % of every frame's light
   above 3σ (a PSF window is as large as its light), plus 4 pixels a side. Repeats of one
   (depth, wavelength) are averaged; each PSF is normalised to sum to one or to peak at one.

The cube's pixel pitch is the camera's pixel pitch over the magnification of the relay optics
(the PSF in the metalens' sensor plane is imaged onto the camera magnified). Values are float32
and may dip below zero by the noise around the subtracted background.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from metalens_cli.analysis.subpixel import fourier_shift, parabola_vertex
from metalens_cli.errors import InputError
from metalens_cli.io.psf_manifest import FrameEntry, Manifest, read_frame

NORMALIZATIONS = ("sum-to-one", "peak-one")
CENTRINGS = ("centroid", "peak")
MAD_TO_SIGMA = 1.4826
LIGHT_SIGMA = 3.0  # pixels above this many σ are light
LIGHT_FRACTION = 0.995  # of the light above LIGHT_SIGMA inside the automatic window
WINDOW_MARGIN = 4  # pixels a side beyond the light radius in the automatic window
CROP_MARGIN = 8  # pixels kept a side around the light for centring
HOT_FRAME_FRACTION = 0.9  # a hot pixel spikes in this fraction of the frames
HOT_ISOLATED_FRACTION = 0.5  # ... and on a dark background in this fraction
LOW_SNR = 20.0  # peak / σ below this is warned about
BORDER_BULGE_SIGMA = 1.0  # side middles above corners of the border strip, in σ: the PSF's wings are in the background
MIN_FRAMES_FOR_HOT = 3  # without a dark frame, hot pixels are told from light by recurring in this many frames
KEPT_LIGHT = 0.99  # a given window keeping less of a frame's light is warned about
SPOT_SHARE = 0.1  # a separate patch of light with this share of the main spot's light is a second spot


@dataclass(frozen=True)
class ImportSettings:
    """How frames become PSFs. Lengths in metres; ``pixels`` N or None (automatic);
    ``saturation``: the saturation code (None: each file's full scale; float files then have
    none); ``hot_pixel_sigma`` 0 turns hot-pixel removal off."""

    camera_pixel_pitch_m: float
    magnification: float = 1.0
    pixels: int | None = None
    normalization: str = "sum-to-one"
    centring: str = "centroid"
    saturation: float | None = None
    allow_saturated: bool = False
    hot_pixel_sigma: float = 6.0

    @property
    def pixel_pitch_m(self) -> float:
        """Pitch of the cube: the camera's pixel pitch referred to the metalens' sensor plane."""
        return self.camera_pixel_pitch_m / self.magnification


@dataclass
class MeasuredCube:
    """``psf`` (D, W, N, N) float32 normalised per ``normalization``; ``wavelengths_m`` (W,),
    ``depths_m`` (D,) (``inf`` at infinity); ``frames``: one report per frame (JSON-able);
    ``hot_pixels``: how many were replaced; ``warnings``: one line each."""

    psf: np.ndarray
    wavelengths_m: np.ndarray
    depths_m: np.ndarray
    pixel_pitch_m: float
    frames: list[dict]
    hot_pixels: int
    warnings: list[str] = field(default_factory=list)


@dataclass
class _Frame:
    """A frame after the first pass: its light cropped to a window around the brightest spot."""

    entry: FrameEntry
    crop: np.ndarray  # (S, S) float32, background subtracted, per second if exposed
    origin: tuple[int, int]  # frame (row, column) of crop pixel (0, 0)
    rough: tuple[int, int]  # crop pixel of the brightest smoothed spot
    radius: float  # light radius (pixels) holding LIGHT_FRACTION of the light
    noise: float
    report: dict
    spikes: np.ndarray  # flat frame indices of pixels above their neighbourhood by k·σ
    isolated: np.ndarray  # ... of those on a dark background


BORDER_SAMPLES = 40_000  # border pixels the background is fitted to (a fixed stride through the strip)


@functools.lru_cache(maxsize=8)
def _border_samples(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(rows, columns, corner?, side middle?) of up to BORDER_SAMPLES pixels of the border strip
    (5 % of the smaller side wide, at least 4 pixels), evenly strided."""
    h, w = shape
    b = max(4, round(0.05 * min(h, w)))
    mask = np.ones(shape, dtype=bool)
    mask[b:-b, b:-b] = False
    rows, cols = np.nonzero(mask)
    step = max(1, rows.size // BORDER_SAMPLES)
    rows, cols = rows[::step], cols[::step]
    corner = ((rows < b) | (rows >= h - b)) & ((cols < b) | (cols >= w - b))
    middle = ((np.abs(rows - h / 2) < h / 6) | (np.abs(cols - w / 2) < w / 6)) & ~corner
    return rows, cols, corner, middle


def frame_stats(frame: np.ndarray, field: str = "frame") -> tuple[tuple[float, float, float], float, float]:
    """((a, b, c), σ, bulge) of a frame (H, W): the background plane a + b·x/W + c·y/H (x column,
    y row) fitted by least squares to its border strip (5 % of the smaller side, at least 4
    pixels; refitted without the pixels beyond 5σ: hot pixels, stray light), 1.4826 × the
    median absolute deviation of the strip about it, and how far (in σ) the middles of the
    strip's sides stand above its corners after the fit: light that reaches the border (a PSF
    wider than the frame) makes a bulge no plane takes out. Up to 40 000 strip pixels are used.
    σ is at least :func:`_floor` of the frame: a noiseless (simulated) frame has σ = 0, and the
    plane's rounding error must not stand above it as light."""
    h, w = frame.shape
    if 2 * max(4, round(0.05 * min(h, w))) >= min(h, w):
        raise InputError(
            field, f"{w} × {h} pixels", "frames of at least 16 × 16 pixels (the border gives the background)"
        )
    rows, cols, corner, middle = _border_samples(frame.shape)
    values = frame[rows, cols].astype(np.float64)
    design = np.stack([np.ones_like(values), cols / w, rows / h], axis=1)
    floor = _floor(frame)
    keep = np.ones(values.size, dtype=bool)
    for _ in range(2):
        coefficients = np.linalg.lstsq(design[keep], values[keep], rcond=None)[0]
        residual = values - design @ coefficients
        sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(residual[keep] - np.median(residual[keep])))), floor)
        keep = np.abs(residual) <= 5 * sigma
    bulge = float(np.median(residual[middle]) - np.median(residual[corner])) / sigma
    return tuple(float(c) for c in coefficients), sigma, bulge


def subtract_plane(frame: np.ndarray, plane: tuple[float, float, float]) -> np.ndarray:
    """``frame`` (H, W) less the plane a + b·x/W + c·y/H, float32."""
    a, b, c = plane
    h, w = frame.shape
    return (
        frame
        - (np.float32(a) + np.float32(b) * np.arange(w, dtype=np.float32) / w)[None, :]
        - (np.float32(c) * np.arange(h, dtype=np.float32) / h)[:, None]
    )


def dark_frame(values: np.ndarray, hot_pixel_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """The dark frame (H, W) (colour averaged) and the flat indices of its hot pixels."""
    frame = _monochrome(values)
    if hot_pixel_sigma <= 0:
        return frame, np.zeros(0, dtype=np.int64)
    _, sigma, _ = frame_stats(frame, "--dark")
    excess = frame - _median3(frame)
    return frame, np.flatnonzero(excess > hot_pixel_sigma * sigma)


def import_psfs(
    manifest: Manifest,
    settings: ImportSettings,
    dark: tuple[np.ndarray, np.ndarray] | None = None,
    on_progress: Callable[[int, int], None] | None = None,
    workers: int = 2,
) -> MeasuredCube:
    """Every frame of ``manifest`` through the protocol above, into a (D, W, N, N) cube.

    ``dark``: (frame, hot pixel indices) from :func:`dark_frame`, or None. Refuses (InputError
    naming the manifest line) a frame of another size than the dark frame or the first frame,
    a saturated frame unless allowed, a frame without light above the background.
    """
    if settings.normalization not in NORMALIZATIONS:
        raise InputError("normalization", repr(settings.normalization), " or ".join(NORMALIZATIONS))
    if settings.centring not in CENTRINGS:
        raise InputError("centring", repr(settings.centring), " or ".join(CENTRINGS))
    total = len(manifest.frames) * 2
    frames: list[_Frame] = []
    shape = None if dark is None else dark[0].shape
    pending: deque = deque()
    with ThreadPoolExecutor(
        max_workers=workers
    ) as pool:  # this thread reads (C-library output is captured per read), the pool processes
        for entry in [*manifest.frames, None]:
            if entry is not None:
                values, full_scale = read_frame(entry)
                pending.append(
                    pool.submit(_first_pass, entry, values, full_scale, settings, None if dark is None else dark[0])
                )
            while pending and (entry is None or len(pending) > workers):
                frame = pending.popleft().result()
                frame_shape = (frame.report["height"], frame.report["width"])
                if shape is not None and frame_shape != shape:
                    raise InputError(
                        frame.entry.where,
                        f"{frame.entry.name} is {frame_shape[1]} × {frame_shape[0]} pixels, "
                        f"{'the dark frame' if dark is not None else 'the first frame'} {shape[1]} × {shape[0]}",
                        "frames (and the dark frame) of one size",
                    )
                shape = frame_shape
                frames.append(frame)
                if on_progress is not None:
                    on_progress(len(frames), total)
    if settings.pixels is not None and settings.pixels > min(shape):
        raise InputError(
            "pixels",
            f"a {settings.pixels}-pixel window is larger than the {shape[1]} × {shape[0]} frames",
            f"at most {min(shape)} pixels",
        )
    hot = _hot_pixels(frames, shape, dark[1] if dark is not None else np.zeros(0, np.int64), settings.hot_pixel_sigma)
    n = settings.pixels or _automatic_window(frames, shape)
    warnings = [w for f in frames for w in _frame_warnings(f, settings)] + (
        _dark_warnings(frames) if dark is not None else []
    )
    depths, wavelengths = manifest.depths_m, manifest.wavelengths_m
    sums = np.zeros((len(depths), len(wavelengths), n, n))
    counts = np.zeros((len(depths), len(wavelengths)), dtype=int)
    for k, frame in enumerate(frames):
        psf, centre, kept = _centred(frame, hot, shape, n, settings.centring)
        frame.report["centre_px"] = [round(c, 4) for c in centre]
        frame.report["light_in_window"] = kept
        if kept < KEPT_LIGHT:
            warnings.append(
                f"{frame.entry.where}: the {n}-pixel window keeps {100 * kept:.1f} % of the light (--pixels)"
            )
        i, j = depths.index(frame.entry.depth_m), wavelengths.index(frame.entry.wavelength_m)
        sums[i, j] += psf
        counts[i, j] += 1
        if on_progress is not None:
            on_progress(len(frames) + k + 1, total)
    psf = sums / counts[:, :, None, None]
    return MeasuredCube(
        _normalised(psf, settings.normalization, manifest),
        np.array(wavelengths),
        np.array(depths),
        settings.pixel_pitch_m,
        [f.report for f in frames],
        int(hot.size),
        warnings,
    )


def _first_pass(
    entry: FrameEntry, values: np.ndarray, full_scale: float | None, settings: ImportSettings, dark: np.ndarray | None
) -> _Frame:
    """One frame as read (:func:`read_frame`): count saturation; subtract dark and background;
    find its light."""
    level = settings.saturation if settings.saturation is not None else full_scale
    colour = values[:, :, :3] if values.shape[2] >= 3 else values
    saturated = 0 if level is None else int(np.count_nonzero((colour >= level).any(axis=2)))
    if saturated and not settings.allow_saturated:
        raise InputError(
            entry.where,
            f"{entry.name} has {saturated} saturated pixel(s) (≥ {level:g})",
            "frames below saturation (shorten the exposure), or --allow-saturated to import them, reported",
        )
    frame = _monochrome(values)
    if dark is not None and frame.shape == dark.shape:
        frame = frame - dark
    if entry.exposure_s is not None:
        with np.errstate(over="ignore"):
            frame = frame / np.float32(entry.exposure_s)
    _check_finite(frame, entry)
    background, noise, bulge = frame_stats(frame, entry.where)
    with np.errstate(over="ignore", invalid="ignore"):
        frame = subtract_plane(frame, background)
    _check_finite(frame, entry)
    median = _median3(frame)
    spikes = (
        np.flatnonzero(frame - median > settings.hot_pixel_sigma * noise)
        if settings.hot_pixel_sigma > 0
        else np.zeros(0, np.int64)
    )
    isolated = spikes[median.ravel()[spikes] < LIGHT_SIGMA * noise]
    light = _light(median, noise)
    if light is None:
        clipped = f" ({saturated} of its {frame.size} pixels saturated)" if saturated else ""
        raise InputError(
            entry.where,
            f"{entry.name} has no light above the background noise{clipped}",
            "a frame with a PSF brighter than 3σ of its border",
        )
    rough, radius, others = light
    crop, origin = _window(frame, rough, math.ceil(1.5 * radius) + CROP_MARGIN + (settings.pixels or 0) // 2)
    peak = float(crop.max())
    report = {
        "file": entry.name,
        "where": entry.where,
        "wavelength_m": entry.wavelength_m,
        "depth_m": None if entry.depth_m == math.inf else entry.depth_m,
        "exposure_s": entry.exposure_s,
        "height": frame.shape[0],
        "width": frame.shape[1],
        "saturated_pixels": saturated,
        "background": background[0] + (background[1] + background[2]) / 2,
        "background_tilt": [background[1], background[2]],
        "noise": noise,
        "peak_snr": peak / noise,
        "light_radius_px": radius,
        "border_bulge_sigma": bulge,
        "other_spots": others,
    }
    return _Frame(
        entry, crop, origin, (rough[0] - origin[0], rough[1] - origin[1]), radius, noise, report, spikes, isolated
    )


def _check_finite(frame: np.ndarray, entry: FrameEntry) -> None:
    """Refuse a frame whose values overflowed single precision (huge values, tiny exposures)."""
    if not np.isfinite(frame).all():
        raise InputError(
            entry.where,
            f"{entry.name}'s values overflow single precision (after the exposure)",
            "frame values and exposures whose ratio stays below 1e38",
        )


def _monochrome(values: np.ndarray) -> np.ndarray:
    """(H, W) float32 from (H, W, C): the mean of R, G, B (alpha dropped) or the one channel."""
    colour = values[:, :, :3] if values.shape[2] >= 3 else values
    return np.ascontiguousarray(colour.mean(axis=2) if colour.shape[2] > 1 else colour[:, :, 0], dtype=np.float32)


def _median3(frame: np.ndarray) -> np.ndarray:
    """3 × 3 median filter of a float32 frame (edges replicated)."""
    import cv2

    return cv2.medianBlur(np.ascontiguousarray(frame, dtype=np.float32), 3)


def _floor(frame: np.ndarray) -> float:
    """A noise floor for noiseless (synthetic) frames: 1e-6 of the largest value as given
    (before the background is taken out), above float32's rounding of the plane fit."""
    return max(1e-6 * float(np.abs(frame).max()), np.finfo(np.float32).tiny)


def _light(median: np.ndarray, noise: float) -> tuple[tuple[int, int], float, list[dict]] | None:
    """The brightest smoothed spot (row, column), the radius (pixels) around it holding
    LIGHT_FRACTION of the light above LIGHT_SIGMA·σ (from a binned copy of the frame) and the
    other spots (:func:`_other_spots`); None without such light."""
    import cv2

    h, w = median.shape
    smooth = cv2.GaussianBlur(median, (0, 0), 2.0)
    rough = np.unravel_index(int(np.argmax(smooth)), smooth.shape)
    b = max(1, min(h, w) // 512)
    binned = cv2.resize(
        median[: h - h % b, : w - w % b], ((w - w % b) // b, (h - h % b) // b), interpolation=cv2.INTER_AREA
    )
    excess = np.clip(binned - LIGHT_SIGMA * noise / b, 0, None)
    if not excess.any():
        return None
    yy, xx = np.indices(binned.shape)
    r = np.hypot((yy + 0.5) * b - 0.5 - rough[0], (xx + 0.5) * b - 0.5 - rough[1]).ravel()
    order = np.argsort(r)
    cumulative = np.cumsum(excess.ravel()[order])
    radius = float(r[order][np.searchsorted(cumulative, LIGHT_FRACTION * cumulative[-1])]) + b
    return (int(rough[0]), int(rough[1])), max(radius, 2.0), _other_spots(smooth, LIGHT_SIGMA * noise, rough)


def _other_spots(smooth: np.ndarray, level: float, rough: tuple[int, int]) -> list[dict]:
    """Patches of light (8-connected pixels of the smoothed frame above ``level``) apart from the
    one at ``rough`` that hold at least SPOT_SHARE of its light above ``level`` and whose
    centroid lies beyond twice its equivalent radius (+ 2 px) from its centroid: a ghost, a
    second source. Rings around the spot (an Airy pattern's, a defocused lens's) are centred on
    it and are not counted. Each: ``at_px`` (frame row, column) and ``share`` of the main light."""
    import cv2

    count, labels = cv2.connectedComponents((smooth > level).astype(np.uint8), connectivity=8)
    if count <= 2:
        return []
    lit = np.flatnonzero(labels)  # only the light: a frame's worth of index arrays is not needed
    flat, excess = labels.ravel()[lit], (smooth.ravel()[lit] - level).astype(np.float64)
    light = np.bincount(flat, excess, count)
    rows, cols = np.divmod(lit, smooth.shape[1])
    cy, cx = (
        np.divide(np.bincount(flat, excess * axis, count), light, out=np.zeros(count), where=light > 0)
        for axis in (rows, cols)
    )  # label 0, the background, holds no light
    main = labels[rough]
    reach = 2 * math.sqrt(np.count_nonzero(flat == main) / math.pi) + 2
    return [
        {"at_px": [float(cy[k]), float(cx[k])], "share": float(light[k] / light[main])}
        for k in range(1, count)
        if k != main and light[k] >= SPOT_SHARE * light[main] and math.hypot(cy[k] - cy[main], cx[k] - cx[main]) > reach
    ]


def _window(frame: np.ndarray, centre: tuple[int, int], half: int) -> tuple[np.ndarray, tuple[int, int]]:
    """The (2·half + 1)² window of ``frame`` centred on ``centre``, zero outside the frame."""
    y0, x0 = centre[0] - half, centre[1] - half
    side = 2 * half + 1
    out = np.zeros((side, side), dtype=np.float32)
    h, w = frame.shape
    ys, xs = slice(max(y0, 0), min(y0 + side, h)), slice(max(x0, 0), min(x0 + side, w))
    out[ys.start - y0 : ys.stop - y0, xs.start - x0 : xs.stop - x0] = frame[ys, xs]
    return out, (y0, x0)


def _hot_pixels(frames: list[_Frame], shape: tuple[int, int], dark_hot: np.ndarray, sigma: float) -> np.ndarray:
    """Flat frame indices of the hot pixels (see the module docstring)."""
    if sigma <= 0:
        return np.zeros(0, dtype=np.int64)
    if len(frames) < MIN_FRAMES_FOR_HOT:
        return np.asarray(dark_hot, dtype=np.int64)
    size = shape[0] * shape[1]
    spikes = np.bincount(np.concatenate([f.spikes for f in frames]), minlength=size) if frames else np.zeros(size)
    isolated = np.bincount(np.concatenate([f.isolated for f in frames]), minlength=size) if frames else np.zeros(size)
    found = np.flatnonzero(
        (spikes >= math.ceil(HOT_FRAME_FRACTION * len(frames)))
        & (isolated >= max(1, math.ceil(HOT_ISOLATED_FRACTION * len(frames))))
    )
    return np.union1d(found, dark_hot)


def _automatic_window(frames: list[_Frame], shape: tuple[int, int]) -> int:
    """The smallest odd N holding every frame's light radius plus WINDOW_MARGIN, within the frame."""
    radius = max(f.radius for f in frames)
    n = 2 * (math.ceil(radius) + WINDOW_MARGIN) + 1
    return min(n, min(shape) - (1 - min(shape) % 2))


def _centred(
    frame: _Frame, hot: np.ndarray, shape: tuple[int, int], n: int, centring: str
) -> tuple[np.ndarray, tuple[float, float], float]:
    """The frame's N × N PSF with its centre on pixel (N//2, N//2), that centre in frame pixels
    (row, column), and the fraction of the crop's light above LIGHT_SIGMA·σ the window keeps."""
    crop = frame.crop.copy()
    if hot.size:
        _replace_hot(crop, frame.origin, hot, shape)
    cy, cx = _centroid(crop, frame) if centring == "centroid" else _peak(crop)
    iy, ix = round(cy), round(cx)
    fy, fx = cy - iy, cx - ix
    half = n // 2
    need = max(half + 1 - min(iy, ix), max(iy, ix) + (n - half) - crop.shape[0] + 1, 0)
    if need:
        crop = np.pad(crop, need)
        iy, ix = iy + need, ix + need
    shifted = fourier_shift(crop, -fy, -fx)
    window = (slice(iy - half, iy - half + n), slice(ix - half, ix - half + n))
    light = np.clip(shifted - LIGHT_SIGMA * frame.noise, 0, None)
    kept = float(light[window].sum() / light.sum()) if light.any() else 1.0
    return shifted[window], (frame.origin[0] + cy, frame.origin[1] + cx), kept


def _replace_hot(crop: np.ndarray, origin: tuple[int, int], hot: np.ndarray, shape: tuple[int, int]) -> None:
    """Hot pixels inside the crop replaced by the median of their 3 × 3 neighbourhood."""
    rows, cols = np.divmod(hot, shape[1])
    rows, cols = rows - origin[0], cols - origin[1]
    inside = (rows >= 0) & (rows < crop.shape[0]) & (cols >= 0) & (cols < crop.shape[1])
    if inside.any():
        median = _median3(crop)
        crop[rows[inside], cols[inside]] = median[rows[inside], cols[inside]]


def _centroid(crop: np.ndarray, frame: _Frame) -> tuple[float, float]:
    """Centroid (crop row, column) of the light above LIGHT_SIGMA·σ, weighted by its excess, in
    a disc of radius 1.5 × the light radius + 3 pixels, iterated from the brightest spot."""
    weights = np.clip(crop - LIGHT_SIGMA * frame.noise, 0, None).astype(np.float64)
    yy, xx = np.indices(crop.shape, dtype=np.float64)
    cy, cx = map(float, frame.rough)
    radius = 1.5 * frame.radius + 3
    for _ in range(50):
        inside = weights * (((yy - cy) ** 2 + (xx - cx) ** 2) <= radius**2)
        total = inside.sum()
        if total <= 0:
            raise InputError(
                frame.entry.where,
                f"{frame.entry.name} has no light above the background noise",
                "a frame with a PSF brighter than 3σ of its border",
            )
        ny, nx = float((inside * yy).sum() / total), float((inside * xx).sum() / total)
        if abs(ny - cy) < 1e-6 and abs(nx - cx) < 1e-6:
            break
        cy, cx = ny, nx
    return ny, nx


def _peak(crop: np.ndarray) -> tuple[float, float]:
    """The maximum's (row, column), refined by a Gaussian (a parabola in the logarithm) through
    it and its neighbours on each axis; a parabola in the values where one is not positive."""
    iy, ix = np.unravel_index(int(np.argmax(crop)), crop.shape)
    iy, ix = min(max(iy, 1), crop.shape[0] - 2), min(max(ix, 1), crop.shape[1] - 2)

    def vertex(a: float, b: float, c: float) -> float:
        return parabola_vertex(*((math.log(a), math.log(b), math.log(c)) if min(a, b, c) > 0 else (a, b, c)))

    return iy + vertex(*crop[iy - 1 : iy + 2, ix]), ix + vertex(*crop[iy, ix - 1 : ix + 2])


def _normalised(psf: np.ndarray, normalization: str, manifest: Manifest) -> np.ndarray:
    """Each (depth, wavelength) PSF scaled to sum to one or to peak at one."""
    scale = psf.sum(axis=(-2, -1)) if normalization == "sum-to-one" else psf.max(axis=(-2, -1))
    if np.any(scale <= 0):
        i, j = np.argwhere(scale <= 0)[0]
        raise InputError(
            manifest.source,
            f"the PSF at {manifest.wavelengths_m[j] * 1e9:g} nm, depth index {i} holds no light",
            "frames with light above their background",
        )
    return (psf / scale[:, :, None, None]).astype(np.float32)


def _dark_warnings(frames: list[_Frame]) -> list[str]:
    """One line when the dark frame is brighter than some frames' background (by more than
    LIGHT_SIGMA·σ): a dark frame of another exposure or gain. The plane fit takes its excess out
    with the background, so the PSFs stand, but its fixed pattern is not the frames'."""
    darker = [f for f in frames if f.report["background"] < -LIGHT_SIGMA * f.noise]
    if not darker:
        return []
    worst = max(darker, key=lambda f: -f.report["background"] / f.noise)
    return [
        f"the dark frame is brighter than the background of {len(darker)} of {len(frames)} frame(s) (by up to "
        f"{-worst.report['background'] / worst.noise:.0f}σ, {worst.entry.where}): was it taken at another exposure or "
        "gain? Its excess is removed with the background, its pattern may not match the frames'"
    ]


def _frame_warnings(frame: _Frame, settings: ImportSettings) -> list[str]:
    """One-line warnings: saturated pixels used, low signal, light at the frame's edge."""
    r, out = frame.report, []
    if r["saturated_pixels"]:
        out.append(f"{frame.entry.where}: {r['saturated_pixels']} saturated pixel(s) imported (--allow-saturated)")
    if r["peak_snr"] < LOW_SNR:
        out.append(f"{frame.entry.where}: the peak is only {r['peak_snr']:.1f}σ above the background noise")
    y, x = frame.origin[0] + frame.rough[0], frame.origin[1] + frame.rough[1]
    if min(y, x, r["height"] - 1 - y, r["width"] - 1 - x) < frame.radius:
        out.append(f"{frame.entry.where}: the light reaches the frame's edge; the PSF is clipped")
    elif r["border_bulge_sigma"] > BORDER_BULGE_SIGMA:
        out.append(
            f"{frame.entry.where}: the border strip bulges {r['border_bulge_sigma']:.1f}σ between its corners: the "
            "PSF's wings reach it and are taken for background (use a larger frame)"
        )
    if r["other_spots"]:
        first = max(r["other_spots"], key=lambda spot: spot["share"])
        out.append(
            f"{frame.entry.where}: {1 + len(r['other_spots'])} separate spots of light (one at row "
            f"{first['at_px'][0]:.0f}, column {first['at_px'][1]:.0f} with {first['share']:.0%} of the brightest's "
            "light): the PSF takes them together; crop the frame to one spot (a ghost or a second source)"
        )
    return out
