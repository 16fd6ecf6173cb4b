"""PSF sets over the field (``imaging.field_psfs``) and captures formed with them (``pipeline``):
the isoplanatic test, the set's geometry and cache, and the physics a capture must keep."""

import dataclasses
import math

import numpy as np
import pytest
import torch

from metalens_cli.errors import InputError
from metalens_cli.imaging.channel_psfs import channel_psfs
from metalens_cli.imaging.field_psfs import corner_pixels, estimate_field_psfs, field_channel_psfs, field_dependence
from metalens_cli.imaging.pipeline import capture_psfs, simulate_captures
from metalens_cli.io.designs import resolve_design
from metalens_cli.optics import lens as L

PITCH = 1.85e-6
LAMS = [float(x) for x in np.arange(420e-9, 681e-9, 20e-9)]


def small(radial=True):
    design = resolve_design("hyperbolic:532nm", None, f_m=200e-6, aperture_m=100e-6, pitch_m=None)
    if radial:
        return design
    return dataclasses.replace(design, lens=L.hyperbolic(532e-9, 200e-6, 100e-6, design.lens.pitch_m, radial=False))


def test_isoplanatic_test_follows_the_geometric_spot():
    design = small()
    wide, narrow = field_dependence(design, 64, PITCH), field_dependence(design, 4, PITCH)
    # a lens perfect at 532 nm: its spot at 530 nm is a tenth of a pixel; coma grows with the corner's angle
    assert wide["rms_spot_axis_m"] < 0.1 * PITCH and wide["rms_spot_corner_m"] > wide["rms_spot_axis_m"] + PITCH
    assert wide["field_dependent"] and not narrow["field_dependent"]
    assert wide["corner_field_deg"] == pytest.approx(math.degrees(math.atan(corner_pixels(64) * PITCH / 200e-6)))


def test_field_set_is_pixel_aligned_cached_and_on_axis_at_its_centre(tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path))
    design = small()
    first = field_channel_psfs(design, 0.01, 1.0, LAMS, PITCH, 64, wavelengths_per_channel=2)
    assert first.near.heights_px == (0, 46) and not first.cached
    assert first.angles_rad[1] == pytest.approx(math.atan(46 * PITCH / 200e-6))
    axis = channel_psfs(design, 0.01, 1.0, LAMS, PITCH)
    for field_set, on_axis in ((first.near, axis.near), (first.far, axis.far)):
        n, m = field_set.psfs.shape[-1], on_axis.shape[-1]
        lo = n // 2 - m // 2
        torch.testing.assert_close(field_set.psfs[0, :, lo : lo + m, lo : lo + m], on_axis.float())
        assert field_set.psfs.shape[-1] % 2 == 1
    # the corner's coma needs a larger window than the axis, and the windows keep the light
    assert first.far.psfs.shape[-1] >= axis.far.shape[-1] and first.near.psfs.shape[-1] >= axis.near.shape[-1]
    assert min(min(k) for k in first.kept["far"]) > 0.99
    # the set's single angle margin against field_psf's doubled one, measured at the corner
    assert 0 < first.sampling_error < 2e-3 and first.report()["sampling_error"] == first.sampling_error
    assert first.report()["height_error"]["far"] == {"heights_px": [], "error": []}  # no height between
    again = field_channel_psfs(design, 0.01, 1.0, LAMS, PITCH, 64, wavelengths_per_channel=2)
    assert again.cached and torch.equal(again.far.psfs, first.far.psfs)
    assert again.sampling_error == first.sampling_error


def test_field_set_estimate_plans_the_psfs_the_set_computes(tmp_path, monkeypatch):
    """The estimate plans each off-axis PSF at the set's wavelengths (not 400-700 nm, which refused a
    learned lens whose set fits), field angles and margin, in a window at least the set's."""
    import metalens_cli.optics.field as field

    monkeypatch.setenv("METALENS_CACHE", str(tmp_path))
    calls = {"set": [], "estimate": []}

    def spy(name, run):
        def wrapped(lens, grid, angle, **kw):
            calls[name].append(
                (list(grid.wavelengths_m), list(grid.depths_m), grid.pixels, angle, kw.get("oversample", 1.0))
            )
            return run(lens, grid, angle, **kw)

        return wrapped

    monkeypatch.setattr(field, "field_psf", spy("set", field.field_psf))
    monkeypatch.setattr(field, "estimate_field_psf", spy("estimate", field.estimate_field_psf))
    design = small()
    field_channel_psfs(design, 0.01, 1.0, LAMS, PITCH, 64)
    estimate_field_psfs(design, 64, PITCH, [0.01, 1.0], LAMS)
    assert len(calls["set"]) == len(calls["estimate"]) == 2  # one off-axis height and the corner's check
    assert max(calls["set"][0][0]) < 680e-9  # the strata's longest wavelength, not the band's edge
    for planned, computed in zip(calls["estimate"], calls["set"]):
        assert planned[0] == pytest.approx(computed[0], rel=1e-12) and planned[1] == computed[1]
        assert planned[3] == pytest.approx(computed[3]) and planned[4] == computed[4]
        assert planned[2] >= computed[2]


def test_field_set_refuses_a_2d_design():
    with pytest.raises(InputError, match="radially symmetric"):
        field_channel_psfs(small(radial=False), 0.01, 1.0, LAMS, PITCH, 64)


class _Image:
    def __init__(self, linear, margin):
        self.name, self.linear, self.margin = "grey", linear, margin
        self.sensor = linear[:, margin:-margin, margin:-margin]


@pytest.mark.parametrize("model", ["auto", "on-axis"])
def test_grey_wall_stays_grey_with_field_psfs(model, tmp_path, monkeypatch):
    monkeypatch.setenv("METALENS_CACHE", str(tmp_path))
    monkeypatch.setattr("metalens_cli.imaging.field_psfs.DEFAULT_WAVELENGTHS_PER_CHANNEL", 2)
    design = small()
    psfs = capture_psfs(design, 0.01, 1.0, LAMS, PITCH, 64, field_model=model)
    assert (psfs.field_psfs is not None) == (model == "auto")
    assert psfs.report()["field"]["model"] == ("field" if model == "auto" else "on-axis")
    m = psfs.margin
    grey = np.full((3, 64 + 2 * m, 64 + 2 * m), 0.18, np.float32)
    (capture,) = simulate_captures([_Image(grey, m)], "dirt", psfs, 200e-6, PITCH, seed=3)
    # the unobstructed capture of a uniform wall is that wall (float32 rounding)
    np.testing.assert_allclose(capture.unobstructed, 0.18, rtol=2e-5)
    assert capture.obstructed.std() > 0  # the dirt shows


def test_capture_psfs_refuses_an_unknown_model():
    with pytest.raises(InputError, match="--field"):
        capture_psfs(small(), 0.01, 1.0, LAMS, PITCH, 64, field_model="everywhere")


def test_evaluate_prepares_the_field_transforms_once_per_design(tmp_path, monkeypatch):
    """Two seeds drawing the same depths and two obstruction kinds share one PSF set and one
    near and far field transform per design (they were made per seed and kind: the expansion's
    minutes and gigabytes four times over), at the tolerance asked for; the units keep their order
    (kind, seed, design)."""
    from metalens_cli.imaging import pipeline
    from metalens_cli.imaging.evaluation import EvaluationSettings, evaluate

    monkeypatch.setenv("METALENS_CACHE", str(tmp_path))
    monkeypatch.setattr("metalens_cli.imaging.field_psfs.DEFAULT_WAVELENGTHS_PER_CHANNEL", 2)
    made, real = [], pipeline.field_transform
    monkeypatch.setattr(
        pipeline, "field_transform", lambda s, sensor, **options: made.append(sensor) or real(s, sensor, **options)
    )
    settings = EvaluationSettings(
        64, PITCH, (0.01, 0.01), (1.0, 1.0), LAMS, images="charts", limit=2, field_model="auto", field_tolerance=0.02
    )
    designs = [small(), resolve_design("hyperbolic:560nm", None, f_m=200e-6, aperture_m=100e-6, pitch_m=None)]
    result = evaluate(designs, ["dirt", "fence"], [0, 1], settings)
    assert made == [(64, 64)] * 4  # near and far, per design
    order = [(u["obstruction"], u["seed"], u["design"]) for u in result.units]
    assert order == sorted(
        order, key=lambda k: (["dirt", "fence"].index(k[0]), k[1], [d.spec for d in designs].index(k[2]))
    )
    assert len(order) == 2 * 2 * 2 * 2  # kinds × seeds × designs × images
    expansion = result.psfs[0]["field"]["expansion"]
    assert expansion["near"]["tolerance"] == expansion["far"]["tolerance"] == 0.02
    assert expansion["near"]["error"] <= 0.02 and expansion["far"]["eigen_psfs"] > 0 and expansion["seconds"] > 0
    formation = result.psfs[0]["field"]["formation"]  # the seeds share one set: all their captures
    assert formation["captures"] == 2 * 2 * 2 and 0 < formation["median_seconds"] < expansion["seconds"]
