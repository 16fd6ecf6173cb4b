"""The facts and enumerations several layers share, in one place, importable without torch.

The paper's lens, filter and sensor (Suppl. Notes 1-4 of the paper; presets/split-spectrum.toml
holds the same values as a preset): SI metres throughout. The enumerations are the accepted
values of options and preset keys; the modules that act on them check against these.
"""

from __future__ import annotations

__version__ = "0.9.0.dev0"  # the package version (pyproject reads it here); files this tool writes record it

# The paper's lens and meta-atom
PAPER_FOCAL_LENGTH_M = 4e-3
PAPER_PITCH_M = 395e-9  # meta-atom lattice period
PAPER_FIN_HEIGHT_M = 700e-9  # SiNx nanofin height

# The paper's tri-band filter: (centre, FWHM) per band, blue to red
PAPER_BANDS_M = ((457e-9, 22e-9), (530e-9, 20e-9), (628e-9, 28e-9))

# The sensor's spectral range and the paper's depth ranges (near: the cover glass, far: the scene)
SENSOR_RANGE_M = (400e-9, 700e-9)
SENSOR_PIXELS = 512  # the paper's sensor side (pixels of 1.85 µm); smaller captures are its centre
PAPER_Z_NEAR_M = (0.040, 0.050)
PAPER_Z_FAR_M = (1.0, 20.0)

# The camera of a verdict (imaging.camera): light levels in electrons a full-scale white pixel collects
# before the filter through an ideal lens, the read noise, and the share of the unconverted light an
# analyzer passes (an achromatic quarter-wave plate and a linear polariser, the paper's setup:
# retardance errors of λ/30 over 450-650 nm leave sin²(π/30) ≈ 0.011 of it)
LIGHT_NAMES = {"dim": 250.0, "indoor": 2000.0, "daylight": 20000.0}
DEFAULT_READ_ELECTRONS = 2.5  # rms; current CMOS sensors read 1-3 e⁻
DEFAULT_ZERO_ORDER_LEAK = 0.01

# Environment variable naming the folder of the LPIPS weight files (--lpips-weights reads it too)
LPIPS_WEIGHTS_ENV = "METALENS_LPIPS_WEIGHTS"

# Enumerations
OBSTRUCTION_KINDS = ("dirt", "fence", "drops", "rain")  # built-in procedural obstructions
REFINEMENTS = ("flow", "tps", "none")  # align: refinement after the homography

__all__ = [
    "DEFAULT_READ_ELECTRONS",
    "DEFAULT_ZERO_ORDER_LEAK",
    "LIGHT_NAMES",
    "LPIPS_WEIGHTS_ENV",
    "OBSTRUCTION_KINDS",
    "PAPER_BANDS_M",
    "PAPER_FIN_HEIGHT_M",
    "PAPER_FOCAL_LENGTH_M",
    "PAPER_PITCH_M",
    "PAPER_Z_FAR_M",
    "PAPER_Z_NEAR_M",
    "REFINEMENTS",
    "SENSOR_PIXELS",
    "SENSOR_RANGE_M",
]
