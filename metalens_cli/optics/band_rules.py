"""What a band filter model and a named camera must be (pure Python, no numpy: preset loading
and ``bands check`` use these without importing the numerical core)."""

from __future__ import annotations

import math

from metalens_cli.errors import InputError

CAMERA_NAMES = (
    "Nikon 5100 (NPL)",
    "Sigma SDMerill (NPL)",
)  # colour-science's MSDS_CAMERA_SENSITIVITIES used by optics.spectra


def check_bands(centres_m: list[float], widths_m: list[float], edge_width_m: float, peak: float) -> None:
    """Refuse malformed pass bands [c − w/2, c + w/2] (InputError on field ``filter``): unequal
    lengths, non-positive sizes, bands narrower than their logistic edges allow (FWHM ≥
    2·arccosh(3)/(2 ln 9) ≈ 0.80 × the 10-90 % edge width), overlapping bands."""
    if len(centres_m) != len(widths_m):
        raise InputError("filter", f"{len(centres_m)} centres but {len(widths_m)} widths", "one width per band centre")
    if not all(math.isfinite(c) and c > 0 for c in centres_m) or not all(w > 0 for w in widths_m):
        raise InputError("filter", "band centres and widths must be positive", "metres")
    if not (edge_width_m > 0 and 0 < peak <= 1):
        raise InputError("filter", f"edge width {edge_width_m} m, peak {peak}", "edge width > 0, 0 < peak <= 1")
    narrowest = 2.0 * math.acosh(3.0) * edge_width_m / (2.0 * math.log(9.0))
    if any(w < narrowest for w in widths_m):
        raise InputError("filter", f"a band is narrower than {narrowest * 1e9:.2f} nm", "FWHM >= 0.80 × edge width")
    bands = sorted((c - w / 2, c + w / 2) for c, w in zip(centres_m, widths_m))
    if any(low <= high for (_, high), (low, _) in zip(bands, bands[1:])):
        raise InputError("filter", "pass bands overlap", "disjoint bands [c - w/2, c + w/2]")
