"""The paper's split-spectrum checks from Python, without the CLI."""

from metalens_cli.analysis.bands import bands_from_centers, check_bands
from metalens_cli.analysis.symmetry import depth_for_wavelength
from metalens_cli.io.presets import load_preset

preset = load_preset("presets/split-spectrum.toml")
bands = bands_from_centers(list(preset.filter.centers_m), list(preset.filter.widths_m))
report = check_bands(bands, preset.lens.focal_length_m, preset.scene.z_near_m)
for condition in report.conditions:
    print(f"{condition.name:28s} margin {condition.margin_m * 1e9:+6.2f} nm  {'ok' if condition.ok else 'FAILS'}")
lo, hi = report.z_near_window_m
print(f"z_near window: {lo * 1e3:.1f}-{hi * 1e3:.1f} mm")
row = depth_for_wavelength(480e-9, 450e-9, preset.lens.focal_length_m)
print(f"480 nm focuses from {row.depth_m * 1e3:.1f} mm through a 450 nm lens")
