"""Registration of a captured photograph (target) onto its reference: the paper's two stages.

1. A homography from SIFT features (at most ``FEATURE_SIDE`` pixels a side, Lowe's ratio test)
   fitted by MAGSAC++; too few matches or inliers, a low inlier fraction or a degenerate
   homography (folding, mirrored, scale change over ×``MAX_SCALE``, little overlap) raise
   :class:`ResultFailed`.
2. A smooth residual displacement (``refine``): dense DIS optical flow between the reference and
   the homography-warped target at most ``FLOW_SIDE`` pixels a side ("flow"), or a smoothing
   thin-plate spline through the feature matches near the homography ("tps"), or none.

A metalens capture is blurrier, lower in contrast and differently coloured than its reference:
both stages work on luminance stretched between its 0.5 and 99.5 percentiles, the sharper image
blurred (Gaussian) to the other's gradient-to-variance ratio, and the flow on locally contrast
normalised images.

Conventions: pixel (row i, column j) has its centre at x = j, y = i. ``homography`` maps a
reference pixel to the target, (x_t·w, y_t·w, w) = H (x_r, y_r, 1); the target point of reference
pixel p is q = H(p) + flow[p] with ``flow`` (dx, dy) in target pixels. ``Registration.apply``
samples the target at q (bicubic), which puts it on the reference grid. The flow is bilinear
between nodes every ``flow_step`` reference pixels (:func:`metalens_cli.io.warp_files.node_positions`),
which is what a warp file stores, so a saved warp reproduces ``apply`` exactly.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from metalens_cli.constants import REFINEMENTS
from metalens_cli.errors import InputError, ResultFailed
from metalens_cli.imaging.images import LUMA_709
from metalens_cli.io.warp_files import MAX_SIDE, node_positions, read_warp_file, write_warp_file

FEATURE_SIDE = 1024  # features on images downscaled to at most this many pixels a side
MAX_FEATURES = 4000  # strongest SIFT keypoints kept per image
RATIO = 0.75  # Lowe's ratio test
RANSAC_PX = 3.0  # MAGSAC++ threshold, pixels at the target's feature scale
MIN_MATCHES = 12  # fewer tentative matches, or inliers, fail
MIN_INLIER_FRACTION = 0.15  # fewer inliers per tentative match fail
WARN_INLIER_FRACTION = 0.4
WARN_RESIDUAL_PX = 1.0  # RMS inlier residual, pixels at the target's feature scale
MAX_SCALE = 8.0  # largest linear scale change reference → target (either way)
MAX_ANISOTROPY = 4.0  # largest ratio of the homography's local stretches
MIN_OVERLAP = 0.1  # least fraction of the reference the target must cover
WARN_OVERLAP = 0.5
MIN_SPREAD = 0.02  # least fraction of the reference the inliers' convex hull must cover
FLOW_SIDE = 1024  # flow computed at most at this many pixels a side
FLOW_SMOOTH_PX = 2.0  # Gaussian σ smoothing the flow, pixels at the flow scale
NORMALISE_PX = 12.0  # Gaussian σ of the local contrast normalisation, pixels at the flow scale
FLOW_STEP = 4  # flow node spacing, reference pixels
TPS_STEP = 16  # thin-plate spline node spacing, reference pixels
TPS_BINS = 24  # matches binned on a TPS_BINS² grid (median per bin) for the spline
TPS_REACH = 4.0  # matches within this × the RANSAC threshold of H feed the spline
TPS_SMOOTHING = 1e-3  # spline regularisation (coordinates in units of the longer side)
MIN_SIDE = 32
MAX_BLUR_PX = 8.0  # largest σ used to match sharpness


@dataclass(frozen=True, eq=False)
class Registration:
    """Where each reference pixel lies in the target: q = H(p) + flow[p] (see the module
    docstring). Shapes are (rows, columns); ``residual_px`` is the RMS reprojection error of the
    homography's inliers in target pixels, ``refined_residual_px`` theirs with the flow added
    (None: not measured); ``flow_step`` is the node spacing of ``flow``."""

    homography: np.ndarray
    flow: np.ndarray | None
    reference_shape: tuple[int, int]
    target_shape: tuple[int, int]
    matches: int
    inliers: int
    residual_px: float
    refine: str
    flow_step: int = 1
    refined_residual_px: float | None = None

    @cached_property
    def _map(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Target x and y (float32) of every reference pixel, and whether it lies inside the target."""
        rows, columns = self.reference_shape
        x, y = _project(
            self.homography, np.arange(columns, dtype=np.float64)[None, :], np.arange(rows, dtype=np.float64)[:, None]
        )
        x, y = x.astype(np.float32), y.astype(np.float32)
        if self.flow is not None:
            x += self.flow[:, :, 0]
            y += self.flow[:, :, 1]
        height, width = self.target_shape
        inside = (x >= 0) & (x <= width - 1) & (y >= 0) & (y <= height - 1)
        return x, y, inside

    def apply(self, image: np.ndarray) -> np.ndarray:
        """A (Ht, Wt[, C]) target-grid image resampled onto the reference grid (H, W[, C]),
        float32: bicubic (edge pixels repeated past the border), clipped to the range of ``image``
        (no overshoot below its minimum); pixels outside :meth:`valid_mask` are 0."""
        image = np.asarray(image)
        if image.ndim not in (2, 3) or image.shape[:2] != tuple(self.target_shape) or image.dtype.kind not in "fiu":
            raise InputError(
                "image",
                f"array of shape {image.shape} and dtype {image.dtype}",
                f"a real image of {self.target_shape[0]} × {self.target_shape[1]} pixels, the target's",
            )
        x, y, inside = self._map
        source = np.ascontiguousarray(image, dtype=np.float32)
        channels = source.shape[2:]
        if source.ndim == 2 or source.shape[2] <= 4:  # OpenCV remaps up to 4 channels at once
            out = _remap(source, x, y, cv2.INTER_CUBIC).reshape(*x.shape, *channels)
        else:
            out = np.concatenate(
                [
                    _remap(source[:, :, k : k + 4], x, y, cv2.INTER_CUBIC).reshape(*x.shape, -1)
                    for k in range(0, source.shape[2], 4)
                ],
                axis=2,
            )
        np.maximum(out, source.min(), out=out)
        np.minimum(out, source.max(), out=out)
        out[~inside] = 0
        return out

    def valid_mask(self) -> np.ndarray:
        """(H, W) bool: reference pixels whose target point lies within the target's pixel centres."""
        return self._map[2].copy()

    def warnings(self) -> list[str]:
        """Acceptable but doubtful: a low inlier fraction, a large homography residual, little overlap."""
        said = []
        fraction = self.inliers / self.matches if self.matches else 0.0
        if fraction < WARN_INLIER_FRACTION:
            said.append(
                f"only {100 * fraction:.0f} % of {self.matches} feature matches agree on the homography; check the "
                "alignment"
            )
        feature_scale = min(1.0, FEATURE_SIDE / max(self.target_shape))
        final = self.residual_px if self.refined_residual_px is None else self.refined_residual_px
        if final * feature_scale > WARN_RESIDUAL_PX:
            said.append(
                f"the homography leaves {final:.2f} px RMS at its inliers: the images differ by more than a homography "
                "(--refine flow corrects smooth differences)"
                if self.refine == "none"
                else (
                    f"the {self.refine} refinement leaves {final:.2f} px RMS at the consistent feature matches; "
                    "check the alignment"
                )
            )
        overlap = float(self._map[2].mean())
        if overlap < WARN_OVERLAP:
            said.append(f"the target covers only {100 * overlap:.0f} % of the reference; the rest is 0")
        return said

    def to_report(self) -> dict:
        """JSON-able summary: counts, inlier fraction, residual and flow magnitudes (target
        pixels), valid fraction of the reference, homography, warnings."""
        magnitude = None if self.flow is None else np.hypot(self.flow[:, :, 0], self.flow[:, :, 1])
        return {
            "matches": int(self.matches),
            "inliers": int(self.inliers),
            "inlier_fraction": self.inliers / self.matches if self.matches else 0.0,
            "residual_px": float(self.residual_px),
            "refined_residual_px": None if self.refined_residual_px is None else float(self.refined_residual_px),
            "refine": self.refine,
            "flow_rms_px": None
            if magnitude is None
            else float(np.sqrt(np.mean(np.square(magnitude, dtype=np.float64)))),
            "flow_max_px": None if magnitude is None else float(magnitude.max()),
            "valid_fraction": float(self._map[2].mean()),
            "reference_shape": list(self.reference_shape),
            "target_shape": list(self.target_shape),
            "homography": self.homography.tolist(),
            "warnings": self.warnings(),
        }


def register(
    reference: np.ndarray,
    target: np.ndarray,
    *,
    refine: str = "flow",
    field: str = "TARGET",
    reference_field: str = "REFERENCE",
) -> Registration:
    """Register ``target`` onto ``reference`` ((H, W[, C]) real arrays, values about 0..1;
    luminance from R, G, B when C ≥ 3, else the channel mean). ``refine``: "flow", "tps" or
    "none". Raises :class:`ResultFailed` (naming ``field``) when the registration cannot be
    trusted, :class:`InputError` for arrays that are not images or an unknown ``refine``; a
    reference that is not an image or is uniform is named ``reference_field`` (its file in
    `align`'s folder mode)."""
    if refine not in REFINEMENTS:
        raise InputError("refine", f"unknown refinement {refine!r}", ", ".join(REFINEMENTS))
    reference_y = _stretch(_luminance(reference, reference_field), reference_field)
    target_y = _stretch(_luminance(target, field), field)
    reference_small, reference_scale = _downscale(reference_y, FEATURE_SIDE)
    target_small, target_scale = _downscale(target_y, FEATURE_SIDE)
    reference_small, target_small = _match_sharpness(reference_small, target_small)
    p, q = _matches(_sift(reference_small, reference_scale), _sift(target_small, target_scale))
    if len(p) < MIN_MATCHES:
        raise ResultFailed(
            f"{field}: only {len(p)} feature matches with REFERENCE (need ≥ {MIN_MATCHES}); "
            "the images may not show the same scene"
        )
    threshold = RANSAC_PX / min(target_scale)
    homography, mask = cv2.findHomography(p, q, cv2.USAC_MAGSAC, threshold, maxIters=10_000, confidence=0.9999)
    inliers = 0 if homography is None else int(mask.sum())
    if inliers < MIN_MATCHES:
        raise ResultFailed(
            f"{field}: only {inliers} consistent feature matches with REFERENCE (need ≥ {MIN_MATCHES}); "
            "the images may not show the same scene"
        )
    if inliers < MIN_INLIER_FRACTION * len(p):
        raise ResultFailed(
            f"{field}: only {inliers} of {len(p)} feature matches with REFERENCE are consistent "
            f"(need ≥ {100 * MIN_INLIER_FRACTION:.0f} %); the images may not show the same scene"
        )
    homography = homography / homography[2, 2]
    keep = mask.ravel().astype(bool)
    _check_homography(homography, p[keep], reference_y.shape, target_y.shape, field)
    pi, qi = p[keep].astype(np.float64), q[keep].astype(np.float64)
    error = np.stack(_project(homography, pi[:, 0], pi[:, 1]), axis=1) - qi
    residual = refined = float(np.sqrt(np.mean(np.sum(error**2, axis=1))))
    nodes, step = None, 1
    if refine == "flow":
        nodes, step = _flow_nodes(reference_y, target_y, homography), FLOW_STEP
    elif refine == "tps":
        nodes, step = _tps_nodes(p, q, homography, reference_y.shape, TPS_REACH * threshold), TPS_STEP
    flow = None
    if nodes is not None:
        flow = expand_flow(nodes, step, reference_y.shape)
        at = cv2.remap(
            flow,
            pi[None, :, 0].astype(np.float32),
            pi[None, :, 1].astype(np.float32),
            cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_REPLICATE,
        )[0]
        refined = float(np.sqrt(np.mean(np.sum((error + at) ** 2, axis=1))))
    return Registration(
        homography, flow, reference_y.shape, target_y.shape, len(p), inliers, residual, refine, step, refined
    )


def expand_flow(nodes: np.ndarray, step: int, shape: tuple[int, int]) -> np.ndarray:
    """(rows, columns, 2) float32: the flow given at nodes every ``step`` pixels
    (:func:`node_positions`), bilinear in between; equal to ``nodes`` at the nodes, exactly."""
    rows = _along(nodes, node_positions(shape[1], step), shape[1], axis=1)
    return _along(rows, node_positions(shape[0], step), shape[0], axis=0)


def save_warp(path: str | os.PathLike[str], registration: Registration) -> None:
    """Write ``registration`` as a warp file (:mod:`metalens_cli.io.warp_files`), atomically."""
    r = registration
    nodes = None
    if r.flow is not None:
        rows, columns = r.reference_shape
        nodes = r.flow[node_positions(rows, r.flow_step)][:, node_positions(columns, r.flow_step)]
    write_warp_file(
        path,
        r.homography,
        r.reference_shape,
        r.target_shape,
        flow_step=r.flow_step,
        flow_nodes=nodes,
        matches=r.matches,
        inliers=r.inliers,
        residual_px=r.residual_px,
        refined_residual_px=r.refined_residual_px,
        refine=r.refine,
    )


def load_warp(path: str | os.PathLike[str], field: str = "--warp") -> Registration:
    """A registration saved by :func:`save_warp`; a file that is not one is an
    :class:`InputError` naming ``field``."""
    w = read_warp_file(path, field)
    why = _degenerate(w["homography"], w["reference_shape"], w["target_shape"])
    if why is None and w["flow_nodes"] is not None and np.abs(w["flow_nodes"]).max() > max(w["target_shape"]):
        why = (
            f"its refinement moves pixels by up to {np.abs(w['flow_nodes']).max():.3g} pixels, beyond the target's size"
        )
    if why is not None:
        raise InputError(
            field, f"the warp in {os.fspath(path)!r} is degenerate ({why})", "a warp saved by metalens align --warp-out"
        )
    flow = None if w["flow_nodes"] is None else expand_flow(w["flow_nodes"], w["flow_step"], w["reference_shape"])
    return Registration(
        w["homography"],
        flow,
        w["reference_shape"],
        w["target_shape"],
        w["matches"],
        w["inliers"],
        w["residual_px"],
        w["refine"],
        max(w["flow_step"], 1),
        w["refined_residual_px"],
    )


def _along(values: np.ndarray, positions: np.ndarray, size: int, axis: int) -> np.ndarray:
    """Linear interpolation of ``values`` (given at ``positions`` along ``axis``) to 0..size−1,
    as (1 − t)·a + t·b, which returns a node's value exactly at t = 0 and t = 1."""
    if positions.size == 1:
        return np.take(values, np.zeros(size, np.int64), axis=axis)
    pixels = np.arange(size)
    k = np.clip(np.searchsorted(positions, pixels, side="right") - 1, 0, positions.size - 2)
    t = ((pixels - positions[k]) / (positions[k + 1] - positions[k])).astype(np.float32)
    t = t.reshape((-1, 1, 1) if axis == 0 else (1, -1, 1))
    return np.take(values, k, axis=axis) * (1 - t) + np.take(values, k + 1, axis=axis) * t


def _project(homography: np.ndarray, x, y):
    """H applied to points (x, y) (arrays, broadcast): their (x, y) images."""
    h = homography
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    return (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w, (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w


def _jacobian(homography: np.ndarray, x: float, y: float) -> tuple[float, np.ndarray]:
    """H's denominator w at reference point (x, y) and its 2 × 2 Jacobian there (target px per reference px)."""
    h = homography
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    qx, qy = _project(h, x, y)
    return w, (h[:2, :2] - np.outer([qx, qy], h[2, :2])) / w


def _remap(image: np.ndarray, x: np.ndarray, y: np.ndarray, interpolation: int = cv2.INTER_LINEAR) -> np.ndarray:
    return cv2.remap(image, x, y, interpolation, borderMode=cv2.BORDER_REPLICATE)


def _luminance(image: np.ndarray, field: str) -> np.ndarray:
    """(H, W) float32 luminance of an (H, W[, C]) real image (Rec. 709 from the first three
    channels when C ≥ 3, else their mean), checked for size and finite values."""
    if (
        not isinstance(image, np.ndarray)
        or image.ndim not in (2, 3)
        or image.dtype.kind not in "fiu"
        or 0 in image.shape
    ):
        raise InputError(
            field,
            f"not an image array ({getattr(image, 'shape', type(image).__name__)})",
            "an (H, W) or (H, W, C) real array",
        )
    rows, columns = image.shape[:2]
    if min(rows, columns) < MIN_SIDE or max(rows, columns) > MAX_SIDE:
        raise InputError(field, f"{columns} × {rows} pixels", f"images of {MIN_SIDE}-{MAX_SIDE} pixels a side")
    image = image.astype(np.float32, copy=False)
    if image.ndim == 2:
        y = image
    elif image.shape[2] >= 3:
        y = image[:, :, 0] * LUMA_709[0] + image[:, :, 1] * LUMA_709[1] + image[:, :, 2] * LUMA_709[2]
    else:
        y = image.mean(axis=2)
    if not np.all(np.isfinite(y)):
        raise InputError(field, "the image holds NaN or infinite values", "finite pixel values")
    return np.ascontiguousarray(y, dtype=np.float32)


def _stretch(y: np.ndarray, field: str) -> np.ndarray:
    """Luminance mapped to 0..1 between its 0.5 and 99.5 percentiles (sampled), clipped."""
    every = max(1, int(math.sqrt(y.size / 250_000)))
    lo, hi = np.percentile(y[::every, ::every], [0.5, 99.5])
    if hi - lo <= 1e-6 * max(1.0, abs(float(hi))):
        raise ResultFailed(f"{field}: the image is uniform; there is nothing to register")
    return np.clip((y - np.float32(lo)) / np.float32(hi - lo), 0, 1)


def _downscale(y: np.ndarray, side: int) -> tuple[np.ndarray, tuple[float, float]]:
    """``y`` resized (area average) to at most ``side`` pixels a side, and the (x, y) scales."""
    rows, columns = y.shape
    factor = min(1.0, side / max(rows, columns))
    if factor == 1.0:
        return y, (1.0, 1.0)
    size = (max(1, round(columns * factor)), max(1, round(rows * factor)))
    return cv2.resize(y, size, interpolation=cv2.INTER_AREA), (size[0] / columns, size[1] / rows)


def _sharpness(y: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Mean squared gradient over variance (1/px²): larger for sharper images, blind to gain and
    bias; over the pixels of ``mask`` when given."""
    values = y[:-1, :-1]
    gx, gy = y[:-1, 1:] - values, y[1:, :-1] - values
    energy = gx * gx + gy * gy
    if mask is not None:
        inside = mask[:-1, :-1] & mask[:-1, 1:] & mask[1:, :-1]
        energy, values = energy[inside], values[inside]
    variance = float(values.var()) if values.size else 0.0
    return float(energy.mean()) / variance if variance > 0 else 0.0


def _match_sharpness(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) with the sharper one blurred by the Gaussian that brings its :func:`_sharpness` to
    the other's (bisection on σ ≤ ``MAX_BLUR_PX``); statistics over ``mask`` when given."""
    sharp_a, sharp_b = _sharpness(a, mask), _sharpness(b, mask)
    if min(sharp_a, sharp_b) <= 0 or max(sharp_a, sharp_b) < 1.1 * min(sharp_a, sharp_b):
        return a, b
    sharp, goal = (a, sharp_b) if sharp_a > sharp_b else (b, sharp_a)
    lo, hi = 0.0, MAX_BLUR_PX
    for _ in range(10):
        sigma = 0.5 * (lo + hi)
        if _sharpness(cv2.GaussianBlur(sharp, (0, 0), sigma), mask) > goal:
            lo = sigma
        else:
            hi = sigma
    blurred = cv2.GaussianBlur(sharp, (0, 0), hi)
    return (blurred, b) if sharp_a > sharp_b else (a, blurred)


def _sift(y: np.ndarray, scale: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """SIFT keypoints of a 0..1 image as full-resolution (x, y) points (float32), and descriptors."""
    sift = cv2.SIFT_create(nfeatures=MAX_FEATURES, contrastThreshold=0.02)
    keypoints, descriptors = sift.detectAndCompute(np.round(y * 255).astype(np.uint8), None)
    if not keypoints:
        return np.zeros((0, 2), np.float32), np.zeros((0, 128), np.float32)
    points = cv2.KeyPoint_convert(keypoints).astype(np.float64)
    points = (points + 0.5) / np.array(scale) - 0.5
    return points.astype(np.float32), descriptors


def _matches(reference, target) -> tuple[np.ndarray, np.ndarray]:
    """Matched (N, 2) reference and target points that pass the ratio test."""
    (p, dp), (q, dq) = reference, target
    if len(p) < 2 or len(q) < 2:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(dp, dq, k=2)
    good = [
        (m.queryIdx, m.trainIdx)
        for m, n in (pair for pair in pairs if len(pair) == 2)
        if m.distance < RATIO * n.distance
    ]
    if not good:
        return np.zeros((0, 2), np.float32), np.zeros((0, 2), np.float32)
    index = np.array(good)
    return p[index[:, 0]], q[index[:, 1]]


def _check_homography(h: np.ndarray, inlier_points: np.ndarray, reference_shape, target_shape, field: str) -> None:
    """ResultFailed when H is degenerate (:func:`_degenerate`) or its inliers cluster."""
    rows, columns = reference_shape
    why = _degenerate(h, reference_shape, target_shape)
    if why:
        raise ResultFailed(
            f"{field}: the homography onto REFERENCE is degenerate ({why}); the images may not show the same scene"
        )
    hull = cv2.contourArea(cv2.convexHull(inlier_points.astype(np.float32)))
    if hull < MIN_SPREAD * rows * columns:
        raise ResultFailed(
            f"{field}: the consistent feature matches cover only {100 * hull / (rows * columns):.1f} % of REFERENCE "
            f"(need ≥ {100 * MIN_SPREAD:g} %); the homography cannot be trusted"
        )


def _degenerate(h: np.ndarray, reference_shape, target_shape) -> str | None:
    """Why H cannot be a camera's view of the reference, or None: it folds the reference (w ≤
    0), mirrors it, changes scale beyond ``MAX_SCALE`` or ``MAX_ANISOTROPY`` at its corners or
    centre, or the target covers under ``MIN_OVERLAP`` of the reference."""
    rows, columns = reference_shape
    for x, y in ((0, 0), (columns - 1, 0), (0, rows - 1), (columns - 1, rows - 1), ((columns - 1) / 2, (rows - 1) / 2)):
        w, jacobian = _jacobian(h, x, y)
        if w <= 0:
            return "it folds the image over the horizon"
        stretches = np.linalg.svd(jacobian, compute_uv=False)
        if np.linalg.det(jacobian) <= 0:
            return "it mirrors the image"
        if stretches[0] > MAX_SCALE or stretches[1] < 1 / MAX_SCALE:
            return f"scale change ×{stretches[0]:.3g}/×{stretches[1]:.3g}, beyond ×{MAX_SCALE:g}"
        if stretches[0] > MAX_ANISOTROPY * stretches[1]:
            return f"it stretches one direction {stretches[0] / stretches[1]:.3g} times more than the other"
    gx, gy = np.meshgrid(np.linspace(0, columns - 1, 65), np.linspace(0, rows - 1, 65))
    tx, ty = _project(h, gx, gy)
    overlap = float(np.mean((tx >= 0) & (tx <= target_shape[1] - 1) & (ty >= 0) & (ty <= target_shape[0] - 1)))
    if overlap < MIN_OVERLAP:
        return f"the target covers only {100 * overlap:.0f} % of REFERENCE (need ≥ {100 * MIN_OVERLAP:.0f} %)"
    return None


def _normalise_locally(y: np.ndarray, sigma: float) -> np.ndarray:
    """(y − local mean) / local standard deviation (Gaussian windows of σ pixels), floored at a
    tenth of the global deviation so that flat regions stay flat."""
    detail = y - cv2.GaussianBlur(y, (0, 0), sigma)
    spread = np.sqrt(cv2.GaussianBlur(detail * detail, (0, 0), sigma))
    return detail / (spread + np.float32(0.1 * float(detail.std()) + 1e-6))


def _flow_nodes(reference_y: np.ndarray, target_y: np.ndarray, homography: np.ndarray) -> np.ndarray:
    """Flow nodes (every ``FLOW_STEP`` reference pixels) from DIS optical flow between the
    reference and the homography-warped target at the flow scale, smoothed, in target pixels."""
    reference_small, (sx, sy) = _downscale(reference_y, FLOW_SIDE)
    rows, columns = reference_small.shape
    # the target downscaled as much as the homography's mean scale asks (no aliasing when warped)
    stretch = math.sqrt(
        abs(np.linalg.det(_jacobian(homography, (reference_y.shape[1] - 1) / 2, (reference_y.shape[0] - 1) / 2)[1]))
    )
    target_small, (tx, ty) = _downscale(target_y, round(max(target_y.shape) * min(1.0, max(sx, sy) * stretch)))
    small_to_full = np.array([[1 / sx, 0, 0.5 / sx - 0.5], [0, 1 / sy, 0.5 / sy - 0.5], [0, 0, 1]])
    full_to_target_small = np.array([[tx, 0, 0.5 * tx - 0.5], [0, ty, 0.5 * ty - 0.5], [0, 0, 1]])
    h_small = full_to_target_small @ homography @ small_to_full
    mx, my = _project(
        h_small, np.arange(columns, dtype=np.float64)[None, :], np.arange(rows, dtype=np.float64)[:, None]
    )
    mx, my = mx.astype(np.float32), my.astype(np.float32)
    inside = (mx >= 0) & (mx <= target_small.shape[1] - 1) & (my >= 0) & (my <= target_small.shape[0] - 1)
    warped = np.where(inside, _remap(target_small, mx, my), reference_small)
    reference_small, warped = _match_sharpness(reference_small, warped, inside)
    encode = [
        np.clip(128 + 40 * _normalise_locally(image, NORMALISE_PX), 0, 255).astype(np.uint8)
        for image in (reference_small, warped)
    ]
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    dis.setFinestScale(0)
    flow = dis.calc(encode[0], encode[1], None)
    flow = cv2.GaussianBlur(flow, (0, 0), FLOW_SMOOTH_PX)
    # nodes: reference pixel p → small grid u → u + f(u) → back to full resolution p' → H(p') − H(p)
    ny, nx = node_positions(reference_y.shape[0], FLOW_STEP), node_positions(reference_y.shape[1], FLOW_STEP)
    px, py = np.meshgrid(nx.astype(np.float64), ny.astype(np.float64))
    ux, uy = (sx * (px + 0.5) - 0.5).astype(np.float32), (sy * (py + 0.5) - 0.5).astype(np.float32)
    f = cv2.remap(flow, ux, uy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    shifted = _project(homography, px + f[:, :, 0] / sx, py + f[:, :, 1] / sy)
    direct = _project(homography, px, py)
    return np.stack([shifted[0] - direct[0], shifted[1] - direct[1]], axis=2).astype(np.float32)


def _tps_nodes(
    p: np.ndarray, q: np.ndarray, homography: np.ndarray, shape: tuple[int, int], reach: float
) -> np.ndarray:
    """Flow nodes (every ``TPS_STEP`` reference pixels) of a smoothing thin-plate spline through
    the residuals q − H(p) of the matches within ``reach`` target pixels, binned on a
    ``TPS_BINS``² grid (median per bin)."""
    rows, columns = shape
    hx, hy = _project(homography, p[:, 0].astype(np.float64), p[:, 1].astype(np.float64))
    residual = q - np.stack([hx, hy], axis=1)
    near = np.hypot(residual[:, 0], residual[:, 1]) < reach
    p, residual = p[near].astype(np.float64), residual[near]
    bins = (
        np.clip(p[:, 1] * TPS_BINS // rows, 0, TPS_BINS - 1) * TPS_BINS
        + np.clip(p[:, 0] * TPS_BINS // columns, 0, TPS_BINS - 1)
    ).astype(np.int64)
    order = np.argsort(bins, kind="stable")
    groups = np.split(order, np.flatnonzero(np.diff(bins[order])) + 1)
    centres = np.array([p[g].mean(axis=0) for g in groups]) / max(rows, columns)
    values = np.array([np.median(residual[g], axis=0) for g in groups])
    n = len(centres)
    kernel = _tps_kernel(centres, centres) + TPS_SMOOTHING * np.eye(n)
    affine = np.hstack([np.ones((n, 1)), centres])
    system = np.block([[kernel, affine], [affine.T, np.zeros((3, 3))]])
    coefficients = np.linalg.lstsq(system, np.vstack([values, np.zeros((3, 2))]), rcond=None)[0]
    ny, nx = node_positions(rows, TPS_STEP), node_positions(columns, TPS_STEP)
    gx, gy = np.meshgrid(nx, ny)
    nodes = np.stack([gx.ravel(), gy.ravel()], axis=1) / max(rows, columns)
    fitted = (
        _tps_kernel(nodes, centres) @ coefficients[:n] + np.hstack([np.ones((len(nodes), 1)), nodes]) @ coefficients[n:]
    )
    return fitted.reshape(ny.size, nx.size, 2).astype(np.float32)


def _tps_kernel(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """U(r) = r² log r between the points of ``a`` and ``b`` (0 at r = 0)."""
    r2 = np.maximum(np.sum(a * a, axis=1)[:, None] + np.sum(b * b, axis=1)[None, :] - 2 * a @ b.T, 0)
    return 0.5 * r2 * np.log(np.where(r2 > 1e-24, r2, 1.0))
