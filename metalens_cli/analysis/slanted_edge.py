"""Slanted-edge SFR after ISO 12233 (e-SFR), one curve per colour channel (Suppl. Note 14).

Method, per channel, on a region of interest (ROI) holding one straight edge tilted a few degrees
from the pixel grid (a near-horizontal edge is transposed first, so the edge crosses every row):

1. Edge location per row: centroid of the row's finite difference I[j+1] − I[j] (located at
   j + ½), first roughly (argmax, robust line fit), then twice under a Tukey window centred on
   the current line; a straight line x = a + b·row is fitted; the tilt is atan(b).
2. Rows are trimmed to a whole number of pixel shifts of the edge (rows·|b| an integer), so
   every sub-pixel phase is equally represented.
3. Edge-spread function (ESF): every pixel's value binned by its distance to the line along the
   edge normal, (x − a − b·row)·cos θ, in bins of ¼ pixel (4× oversampling), over the distance
   range every row covers; empty bins are filled by linear interpolation from their
   neighbours, and refused above 20 % (tilts with tan θ near 1/2 or 1/3 sample too few phases).
4. Line-spread function (LSF): central difference of the ESF; a Tukey window (α = 0.5) centred
   on the fitted edge, as wide as the ESF allows symmetrically. Its flat central half leaves the
   LSF core untouched (no bias while the blur's LSF stays within a quarter of the ROI width),
   and its cosine tapers take the noisy tails and any background slope to zero. A Hamming
   window, the classic choice, weights the core itself (0.92 a quarter of the way out) and so
   biases the low frequencies of a wide LSF.
5. SFR: modulus of the FFT of the windowed LSF, normalised at zero frequency, divided by the
   transfer functions of the central difference, sinc(2ν/4), and of the ¼-pixel bin average,
   sinc(ν/4) (ν in cycles/pixel, sinc(x) = sin πx/(πx)); both stay above 0.57 up to 1 cycle/px.
   Frequencies are in cycles per pixel along the edge normal, from 0 to 1 cycle/pixel (twice the
   Nyquist frequency 0.5: the oversampled ESF resolves them; content there is aliased in
   ordinary images). The pixel aperture is part of the result (for a square pixel the SFR
   contains sinc(ν cos θ)·sinc(ν sin θ)).

Values are taken as linear in intensity. ISO 12233 linearises through the camera's OECF; here
8/16-bit images are used as they are, or decoded from sRGB with ``srgb=True``; EXR is linear.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli import arguments
from metalens_cli.analysis.mtf import PER_MM, mtf50
from metalens_cli.errors import InputError
from metalens_cli.io.image_files import read_image_file, srgb_to_linear

OVERSAMPLING = 4  # ESF bins per pixel
ANGLE_MARGIN_DEG = 1.0  # refuse edges this near 0° (or 90°) and 45°
MAX_FREQUENCY_CY_PER_PX = 1.0
TUKEY_ALPHA = 0.5
AUTO_HALF_WIDTH_PX = 32  # automatic ROI: at most this many pixels kept on each side of the edge
MIN_ROWS, MIN_COLUMNS = 8, 16
MIN_CONTRAST_TO_NOISE = 10.0
MAX_LINE_RMS_PX = 1.0
MAX_EMPTY_BINS = 0.2  # fraction of ESF bins left without a sample: above it the phases are too few
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".exr")


@dataclass(frozen=True)
class EdgeSfr:
    """The SFR of one channel: ``angle_deg`` the edge's signed tilt from the nearest pixel axis
    (image coordinates, y down); ``frequencies_cy_per_px`` (K,) along the edge normal; ``mtf``
    (K,), 1 at zero frequency; ``mtf50_cy_per_px`` NaN where the curve stays above 0.5."""

    channel: str
    angle_deg: float
    frequencies_cy_per_px: np.ndarray
    mtf: np.ndarray
    mtf50_cy_per_px: float

    def frequencies_lpmm(self, pixel_pitch_m: float) -> np.ndarray:
        """The frequency axis in line pairs per mm for pixels of pitch ``pixel_pitch_m`` (metres)."""
        return self.frequencies_cy_per_px / pixel_pitch_m * PER_MM


@dataclass(frozen=True)
class EdgeAnalysis:
    """SFRs of all channels; ``roi`` = (x, y, w, h) in image pixels (x = column, y = row) and
    ``orientation`` "vertical" or "horizontal" (the edge's nearest axis)."""

    roi: tuple[int, int, int, int]
    orientation: str
    channels: list[EdgeSfr]


def read_edge_image(path: str | Path, srgb: bool = False) -> tuple[np.ndarray, list[str]]:
    """An image as (H, W, C) float64 and its channel names ("Y", or "R", "G", "B").

    PNG/TIFF: 8- or 16-bit, 1 or 3 channels (alpha dropped), BGR reordered to RGB, scaled to
    0..1, decoded from sRGB to linear with ``srgb``. EXR: float channels R, G, B or a single
    channel, linear as stored.
    """
    path = Path(path)
    field = str(path)
    if path.suffix.lower() not in IMAGE_SUFFIXES:
        raise InputError(field, f"unsupported image type {path.suffix or '(none)'}", "a .png, .tif/.tiff or .exr image")
    pixels, names, linear = read_image_file(path, field)
    if linear and srgb:
        raise InputError("srgb", "EXR images hold linear values", "no sRGB decoding for an EXR image")
    if names[-1] == "A":
        pixels, names = pixels[:, :, :3], names[:3]
    image = pixels.astype(float)
    return (srgb_to_linear(image, dtype=np.float64) if srgb else image), names


def slanted_edge_sfr(
    image: np.ndarray, channel_names: list[str], *, roi: tuple[int, int, int, int] | None = None
) -> EdgeAnalysis:
    """The SFR of each channel of ``image`` (H, W, C) (or (H, W)) over ``roi`` = (x, y, w, h).

    Without ``roi`` the image must hold one dominant straight edge: it is located on the
    channel mean and the ROI is the band of rows in which the edge stays ``AUTO_HALF_WIDTH_PX``
    (32) pixels from both sides (fewer in a narrow image), cut to those pixels around it.

    Args:
        image: the image, linear values; C channels (or one).
        channel_names: one name per channel, e.g. ["R", "G", "B"].
        roi: (x, y, w, h) in image pixels (x = column, y = row); None: located automatically.

    Returns:
        ``EdgeAnalysis``: the ROI used, the edge's orientation ("vertical" or "horizontal", its
        nearest axis) and one SFR per channel.

    Raises:
        InputError: an ROI outside the image or too small, no edge, a curved edge, a tilt within 1°
            of 0°/90° or of 45°.

    Shape:
        - Input: :math:`(H, W, C)` or :math:`(H, W)`
    """
    image = np.asarray(arguments.array(image, "image", ndim=(2, 3), form="an image (H, W, C) or (H, W)"), dtype=float)
    image = image[..., None] if image.ndim == 2 else image
    if image.ndim != 3 or image.shape[2] != len(channel_names):
        raise InputError(
            "image", f"shape {image.shape} for channels {channel_names}", "(H, W, C) with one name per channel"
        )
    x, y, w, h = (0, 0, image.shape[1], image.shape[0]) if roi is None else _check_roi(roi, image.shape)
    if min(w, h) < MIN_COLUMNS:  # before any statistics of too few pixels
        raise InputError("roi", f"{w} × {h} pixels", f"an image or ROI of at least {MIN_COLUMNS} × {MIN_COLUMNS}")
    region = image[y : y + h, x : x + w]
    vertical = _is_vertical(region.mean(axis=-1))
    oriented = region if vertical else region.transpose(1, 0, 2)
    if roi is None:
        r0, r1, c0, c1 = _auto_roi(oriented.mean(axis=-1))
        oriented = oriented[r0:r1, c0:c1]
        x, y, w, h = (c0, r0, c1 - c0, r1 - r0) if vertical else (r0, c0, r1 - r0, c1 - c0)
    if oriented.shape[0] < MIN_ROWS or oriented.shape[1] < MIN_COLUMNS:
        raise InputError(
            "roi",
            f"{oriented.shape[0]} pixels along the edge × {oriented.shape[1]} across",
            f"at least {MIN_ROWS} × {MIN_COLUMNS}",
        )
    channels = [_channel_sfr(oriented[..., k], name) for k, name in enumerate(channel_names)]
    return EdgeAnalysis((int(x), int(y), int(w), int(h)), "vertical" if vertical else "horizontal", channels)


def _check_roi(roi, shape) -> tuple[int, int, int, int]:
    """(x, y, w, h) inside an image of ``shape`` (H, W, …)."""
    x, y, w, h = (int(v) for v in roi)
    if x < 0 or y < 0 or w < 1 or h < 1 or x + w > shape[1] or y + h > shape[0]:
        raise InputError(
            "roi",
            f"{x},{y},{w},{h} is not inside the {shape[1]} × {shape[0]} image",
            "x,y,w,h with 0 ≤ x, x + w ≤ width, 0 ≤ y, y + h ≤ height",
        )
    return x, y, w, h


def _is_vertical(plane: np.ndarray) -> bool:
    """Whether the edge is nearer vertical: more variation along rows than along columns."""
    return bool(np.abs(np.diff(plane, axis=1)).sum() >= np.abs(np.diff(plane, axis=0)).sum())


def _auto_roi(plane: np.ndarray) -> tuple[int, int, int, int]:
    """Rows r0:r1 where the edge line keeps ``half`` pixels from both sides, and columns c0:c1
    spanning the edge ± ``half`` over those rows; ``half`` = AUTO_HALF_WIDTH_PX, or less in a
    narrow image: the distance to the sides the edge keeps in three quarters of the rows."""
    _check_contrast(plane, "image")
    a, b = _edge_line(plane, "image")
    height, width = plane.shape
    edge = a + b * np.arange(height)
    distance = np.minimum(edge, width - 1 - edge)
    half = min(AUTO_HALF_WIDTH_PX, int(np.floor(np.quantile(distance, 0.25))))
    inside = np.flatnonzero(distance >= half)
    if half < MIN_COLUMNS // 2 or inside.size < MIN_ROWS:
        raise InputError(
            "roi",
            f"the edge keeps < {MIN_COLUMNS // 2} px from the image sides",
            "an edge across the image's middle, or --roi x,y,w,h",
        )
    r0, r1 = int(inside[0]), int(inside[-1]) + 1
    c0 = max(int(math.floor(edge[r0:r1].min())) - half, 0)
    c1 = min(int(math.ceil(edge[r0:r1].max())) + half + 1, width)
    return r0, r1, c0, c1


def _channel_sfr(plane: np.ndarray, name: str) -> EdgeSfr:
    """The SFR of one channel's oriented ROI (edge crossing every row)."""
    _check_contrast(plane, name)
    a, b = _edge_line(plane, name)
    angle = math.degrees(math.atan(b))
    _check_angle(angle, name)
    rows = _whole_phase_rows(plane.shape[0], b, name)
    esf, centre = _binned_esf(plane[:rows], a, b, name)
    frequencies, sfr = _sfr(esf, centre, name)
    return EdgeSfr(name, angle, frequencies, sfr, float(mtf50(frequencies, sfr)))


def _check_contrast(plane: np.ndarray, name: str) -> None:
    """Refuse an ROI whose step across (first vs last 3 columns) is below 10 × the pixel noise
    (robust σ from the differences along the edge direction)."""
    step = abs(plane[:, -3:].mean() - plane[:, :3].mean())
    noise = 1.4826 * np.median(np.abs(np.diff(plane, axis=0))) / math.sqrt(2)
    if step <= 0 or step <= MIN_CONTRAST_TO_NOISE * noise:
        raise InputError(
            name,
            f"no edge in the ROI (step {step:.3g} against pixel noise {noise:.3g})",
            "one brightness step (an edge) across the ROI",
        )


def _edge_line(plane: np.ndarray, name: str) -> tuple[float, float]:
    """(a, b) of the edge line x = a + b·row (x in pixel-centre coordinates, column j at x = j)."""
    derivative = np.diff(plane, axis=1)
    derivative *= 1.0 if derivative.sum() >= 0 else -1.0
    x = np.arange(derivative.shape[1]) + 0.5
    rows = np.arange(plane.shape[0], dtype=float)
    a, b = _robust_line(rows, x[np.argmax(derivative, axis=1)])
    for _ in range(2):
        centre = a + b * rows
        half = np.maximum(np.minimum(centre - x[0], x[-1] - centre), 2.0)
        weights = derivative * _tukey((x[None, :] - centre[:, None]) / half[:, None])
        total = weights.sum(axis=1)
        valid = total > 0
        if valid.sum() < MIN_ROWS:
            raise InputError(name, "no edge found in most rows of the ROI", "one straight edge crossing the ROI")
        centroid = (weights[valid] * x).sum(axis=1) / total[valid]
        b, a = np.polyfit(rows[valid], centroid, 1)
    rms = float(np.sqrt(np.mean((centroid - (a + b * rows[valid])) ** 2)))
    if rms > MAX_LINE_RMS_PX:
        raise InputError(
            name, f"the edge is not straight (rms {rms:.2f} px from a line)", "one straight edge in the ROI"
        )
    return float(a), float(b)


def _robust_line(rows: np.ndarray, positions: np.ndarray) -> tuple[float, float]:
    """(a, b) of positions ≈ a + b·rows, refitted without the rows more than max(2 px, 3σ) off."""
    b, a = np.polyfit(rows, positions, 1)
    residual = np.abs(positions - (a + b * rows))
    keep = residual <= max(2.0, 3 * 1.4826 * float(np.median(residual)))
    b, a = np.polyfit(rows[keep], positions[keep], 1)
    return float(a), float(b)


def _check_angle(angle_deg: float, name: str) -> None:
    """Refuse tilts within ANGLE_MARGIN_DEG of 0° (90°) or of 45°: too few sampling phases."""
    tilt = abs(angle_deg)
    if tilt < ANGLE_MARGIN_DEG:
        raise InputError(
            name,
            f"edge tilted {angle_deg:.2f}° from the pixel grid: too few sub-pixel phases",
            "an edge tilted 2° to 10° (not within 1° of 0° or 90°)",
        )
    if abs(tilt - 45) < ANGLE_MARGIN_DEG:
        raise InputError(
            name,
            f"edge tilted {angle_deg:.2f}°, within 1° of 45°: every row samples the same phases",
            "an edge tilted 2° to 10° (not within 1° of 45°)",
        )


def _whole_phase_rows(rows: int, slope: float, name: str) -> int:
    """The largest row count ≤ ``rows`` over which the edge shifts a whole number of pixels."""
    shifts = math.floor(rows * abs(slope))
    if shifts < 1:
        raise InputError(
            name,
            f"the edge shifts {rows * abs(slope):.2f} px over the ROI's {rows} rows",
            "an ROI long enough for the edge to shift at least 1 px",
        )
    return min(rows, int(round(shifts / abs(slope))))


def _binned_esf(plane: np.ndarray, a: float, b: float, name: str) -> tuple[np.ndarray, float]:
    """The ESF in ¼-pixel bins along the edge normal, over the distances every row covers, and
    the (fractional) bin index of the edge."""
    height, width = plane.shape
    cos = 1 / math.sqrt(1 + b * b)
    edge = a + b * np.arange(height)
    distance = (np.arange(width)[None, :] - edge[:, None]) * cos
    lo = math.ceil(-edge.min() * cos * OVERSAMPLING)  # bins [lo, hi) / OVERSAMPLING: reached by every row
    hi = math.floor((width - 1 - edge.max()) * cos * OVERSAMPLING)
    if hi - lo < 4 * OVERSAMPLING:
        raise InputError(
            name, f"the ROI spans {(hi - lo) / OVERSAMPLING:.1f} px across the edge", "at least 4 px on the edge normal"
        )
    index = np.floor(distance * OVERSAMPLING).astype(np.int64).ravel() - lo
    inside = (index >= 0) & (index < hi - lo)
    counts = np.bincount(index[inside], minlength=hi - lo)
    sums = np.bincount(index[inside], weights=plane.ravel()[inside], minlength=hi - lo)
    filled = counts > 0
    if filled.mean() < 1 - MAX_EMPTY_BINS:
        raise InputError(
            name,
            f"the edge tilt leaves {100 * (1 - filled.mean()):.0f} % of the ¼-pixel ESF bins empty (tan θ near 1/2 or "
            "1/3?)",
            "an edge tilted 2° to 10°",
        )
    centres = np.arange(hi - lo)
    esf = np.interp(centres, centres[filled], sums[filled] / counts[filled])
    return esf, -lo - 0.5


def _sfr(esf: np.ndarray, centre: float, name: str) -> tuple[np.ndarray, np.ndarray]:
    """Frequencies (cycles/pixel, 0 … 1) and the SFR of a ¼-pixel ESF whose edge is at bin
    ``centre``: windowed central-difference LSF, |FFT| at DC = 1, filter corrections."""
    lsf = np.gradient(esf)
    half = min(centre, esf.size - 1 - centre)
    lsf = lsf * _tukey((np.arange(esf.size) - centre) / half)
    spectrum = np.abs(np.fft.rfft(lsf))
    if spectrum[0] <= 0:
        raise InputError(name, "the line-spread function sums to zero", "one brightness step (an edge) across the ROI")
    frequencies = np.fft.rfftfreq(esf.size, d=1 / OVERSAMPLING)
    correction = np.sinc(2 * frequencies / OVERSAMPLING) * np.sinc(frequencies / OVERSAMPLING)
    keep = frequencies <= MAX_FREQUENCY_CY_PER_PX
    return frequencies[keep], spectrum[keep] / spectrum[0] / correction[keep]


def _tukey(t: np.ndarray, alpha: float = TUKEY_ALPHA) -> np.ndarray:
    """Tukey window at normalised offsets t: 1 for |t| ≤ 1 − α, a raised-cosine taper to 0 at
    |t| = 1, 0 beyond."""
    t = np.abs(t)
    taper = 0.5 * (1 + np.cos(np.pi * (t - (1 - alpha)) / alpha))
    return np.where(t <= 1 - alpha, 1.0, np.where(t < 1, taper, 0.0))
