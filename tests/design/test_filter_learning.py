"""The filter learned with the lens: band quadrature, constraints, conditions, catalogue, runs."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from metalens_cli.analysis.bands import bands_from_centers, check_bands
from metalens_cli.cli.main import run as run_cli
from metalens_cli.design.filter_learning import (
    LearnedFilter,
    band_nodes,
    band_sampler,
    band_weights,
    check_filter,
    make_feasible,
    snap_to_catalogue,
    split_penalty,
)
from metalens_cli.design.training import train
from metalens_cli.errors import InputError, ResultFailed
from metalens_cli.io.filter_catalogue import read_catalogue
from metalens_cli.io.presets import load_preset, preset_from_dict, preset_incidence_factor, read_toml
from metalens_cli.optics import spectra
from metalens_cli.optics.split_spectrum import incidence_factor

NM = 1e-9
TINY = Path(__file__).with_name("tiny.toml")
JOINT = Path(__file__).parents[2] / "presets" / "quick-joint-filter.toml"


@pytest.fixture(scope="module")
def joint():
    return load_preset(JOINT)


def _with(preset, **filter_fields):
    return dataclasses.replace(preset, filter=dataclasses.replace(preset.filter, **filter_fields))


# ------------------------------------------------------------------------------ quadrature


def test_band_weights_equal_the_exact_quadrature_of_a_fixed_filter(joint):
    # nodes over the whole range: the hat quadrature on the 0.1 nm grid against the exact
    # piecewise-linear integral of optics.spectra.quadrature_weights (an independent path)
    sampler = band_sampler(joint)
    nodes = np.arange(402.5, 700, 5.0) * NM
    weights = band_weights(nodes, sampler.fine_m, sampler.base, sampler.band_filter.transmission(sampler.fine_m))
    sensitivity = spectra.SpectralSensitivity(
        sampler.fine_m, sampler.base * sampler.band_filter.transmission(sampler.fine_m).detach().numpy()
    )
    exact = spectra.quadrature_weights(sensitivity, nodes)
    np.testing.assert_allclose(weights.detach().sum(1).numpy(), 1.0, atol=1e-12)
    np.testing.assert_allclose(weights.detach().numpy(), exact.weights, atol=2e-3)


def test_moving_a_band_moves_its_channel_mean_wavelength_as_the_integral_does(joint):
    # Σ_j w_cj·λ_j is exact for f(λ) = λ (linear between nodes): its gradient in the G band's
    # centre must be the derivative of ∫S_G·λ/∫S_G, here by central differences of numpy sums
    sampler = band_sampler(joint, LearnedFilter(joint.filter))
    c, w, e = sampler.band_filter.values()
    nodes = band_nodes(c, w, e, 6, None)
    lam = torch.from_numpy(nodes)
    mean = band_weights(nodes, sampler.fine_m, sampler.base, sampler.band_filter.transmission(sampler.fine_m)) @ lam
    (grad,) = torch.autograd.grad(mean[1], sampler.band_filter.centres_nm)

    def g_mean(shift_nm):
        centres = np.array(c) + np.array([0, shift_nm, 0]) * NM
        t = spectra.bandpass_transmission(sampler.fine_m, centres, w, edge_width_m=e, peak=0.9)
        s = sampler.base[1] * t
        return (s * sampler.fine_m).sum() / s.sum()

    h = 1e-3
    numeric = (g_mean(h) - g_mean(-h)) / (2 * h)
    assert float(grad[1]) == pytest.approx(numeric, rel=0.02)
    assert float(grad[1]) > 0.5 * NM  # most of G's signal moves with its band


def test_stratified_nodes_cover_each_band_and_its_edges():
    rng = np.random.default_rng(1)
    nodes = band_nodes([457 * NM, 530 * NM], [22 * NM, 20 * NM], 2 * NM, 4, rng)
    assert nodes.size == 8 and np.all(np.diff(nodes) > 0)
    for band in (nodes[:4], nodes[4:]):
        strata = np.floor((band - band[0]) / (band[-1] - band[0] + 1e-30))
        assert band.size == 4 and np.ptp(band) < 30 * NM and strata.size == 4


# ------------------------------------------------------------------------------ constraints


def test_projection_restores_every_limit(joint):
    f = joint.filter
    model = LearnedFilter(f)
    with torch.no_grad():
        model.centres_nm.copy_(torch.tensor([395.0, 405.0, 702.0], dtype=torch.float64))
        model.widths_nm.copy_(torch.tensor([3.0, 80.0, 25.0], dtype=torch.float64))
        model.edge_nm.fill_(0.2)
    model.project(f, joint.sensor.wavelength_range_m)
    centres, widths, edge = model.values()
    assert all(f.min_width_m - 1e-15 <= w <= f.max_width_m + 1e-15 for w in widths)
    assert f.min_edge_width_m - 1e-15 <= edge <= min(widths) / 0.81
    lo = [c - w / 2 for c, w in zip(centres, widths)]
    hi = [c + w / 2 for c, w in zip(centres, widths)]
    assert lo[0] >= 400 * NM - 1e-15 and hi[-1] <= 700 * NM + 1e-15
    assert all(b - a >= f.min_gap_m - 1e-12 for a, b in zip(hi, lo[1:]))
    spectra.bandpass_transmission(np.linspace(400, 700, 11) * NM, centres, widths, edge_width_m=edge)  # a valid filter


def test_penalty_is_zero_exactly_when_bands_check_passes_with_the_margin(joint):
    k = preset_incidence_factor(joint)
    assert k == pytest.approx(incidence_factor(np.radians(25.7), 1.8))
    paper = LearnedFilter(joint.filter)
    report = check_filter(joint.filter, joint)
    assert not report.ok  # oblique rays at 25.7° break the paper's filter at 40-50 mm (docs/filter.md)
    penalty = split_penalty(paper, joint, k)
    shortfall = sum(max(0.0, joint.filter.split_margin_m - c.margin_m) ** 2 for c in report.conditions) / NM**2
    assert float(penalty.detach()) == pytest.approx(shortfall, rel=1e-9)
    # a filter that passes with room: no penalty and bands check agrees
    roomy = dataclasses.replace(joint.filter, centers_m=(450e-9, 535e-9, 640e-9), widths_m=(12e-9, 14e-9, 16e-9))
    assert check_filter(roomy, joint).ok
    assert float(split_penalty(LearnedFilter(roomy), joint, k).detach()) == 0.0


def test_penalty_gradient_steps_towards_the_conditions(joint):
    model = LearnedFilter(joint.filter)
    k = preset_incidence_factor(joint)
    optimiser = torch.optim.SGD(model.parameters(), lr=0.01)
    before = float(split_penalty(model, joint, k).detach())
    for _ in range(20):
        optimiser.zero_grad()
        split_penalty(model, joint, k).backward()
        optimiser.step()
        model.project(joint.filter, joint.sensor.wavelength_range_m)
    assert float(split_penalty(model, joint, k).detach()) < 0.5 * before


def test_an_infeasible_start_is_moved_just_inside_before_theta_learns(joint):
    model = LearnedFilter(joint.filter)
    done = make_feasible(model, joint, preset_incidence_factor(joint))
    assert done["penalty_before_nm2"] > 100 and done["penalty_after_nm2"] == 0 and 0 < done["steps"] < 1000
    moved = LearnedFilter(joint.filter)
    report = check_filter(model.to_config(joint.filter), joint)
    assert report.ok and min(c.margin_m for c in report.conditions) < 2 * joint.filter.split_margin_m  # just inside
    for a, b in zip(model.bands(), moved.bands()):  # each edge moved by a few nm, not redrawn
        assert abs(float((a.lo_m - b.lo_m).detach())) < 6 * NM and abs(float((a.hi_m - b.hi_m).detach())) < 6 * NM
    assert make_feasible(model, joint, preset_incidence_factor(joint))["steps"] == 0


# ------------------------------------------------------------------------------ catalogue


CATALOGUE = """name,center_nm,fwhm_nm,edge_nm,peak
paper tri-band,457,22,2,0.9
paper tri-band,530,20,2,0.9
paper tri-band,628,28,2,0.9
narrow tri-band,450,12,1.5,90
narrow tri-band,535,14,1.5,90
narrow tri-band,640,16,1.5,90
dual,480,20,2,0.9
dual,600,20,2,0.9
"""


def test_snapping_gives_the_nearest_listed_filter_that_passes(joint, tmp_path):
    path = tmp_path / "catalogue.csv"
    path.write_text(CATALOGUE)
    listed = read_catalogue(path)
    assert [f.name for f in listed] == ["paper tri-band", "narrow tri-band", "dual"] and listed[
        1
    ].peak_transmission == 0.9
    # the paper's filter is nearer to itself but fails at 25.7°: the narrow one is chosen
    entry, distance = snap_to_catalogue(joint.filter, listed, joint)
    assert entry.name == "narrow tri-band" and distance > 0
    assert (
        entry in listed
        and check_filter(
            dataclasses.replace(joint.filter, centers_m=entry.centers_m, widths_m=entry.widths_m), joint
        ).ok
    )
    normal = _with(joint, max_incidence="0deg")
    assert snap_to_catalogue(normal.filter, listed, normal)[0].name == "paper tri-band"
    with pytest.raises(InputError, match="filter.catalogue"):
        snap_to_catalogue(joint.filter, listed[:1], joint)


@pytest.mark.parametrize(
    "text, message",
    [
        ("centre,fwhm\n457,22\n", "header"),
        ("name,center_nm,fwhm_nm,edge_nm,peak\na,457,twenty,2,0.9\n", "not a number"),
        ("name,center_nm,fwhm_nm,edge_nm,peak\na,457,22,2,0.9\na,530,20,3,0.9\n", "different edges"),
        ("name,center_nm,fwhm_nm,edge_nm,peak\n", "no filter"),
    ],
)
def test_a_bad_catalogue_is_refused_naming_the_field(tmp_path, text, message):
    path = tmp_path / "c.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as error:
        read_catalogue(path)
    assert error.value.field == "filter.catalogue"


# ------------------------------------------------------------------------------ presets


def test_a_learned_filter_needs_bands_and_the_band_quadrature():
    data = read_toml(TINY)
    data["filter"]["learn"] = True
    with pytest.raises(InputError, match="optimize.spectral_sampling"):
        preset_from_dict(data)
    data["optimize"]["spectral_sampling"] = "bands"
    preset_from_dict(data)
    data["filter"]["min_width"], data["filter"]["max_width"] = "30nm", "20nm"
    with pytest.raises(InputError, match="filter.max_width"):
        preset_from_dict(data)
    data = read_toml(TINY)
    data["filter"]["learn"] = "yes"
    with pytest.raises(InputError, match="filter.learn"):
        preset_from_dict(data)
    data = read_toml(TINY)
    data["filter"]["max_incidence"] = "sideways"
    with pytest.raises(InputError, match="filter.max_incidence"):
        preset_from_dict(data)


# ------------------------------------------------------------------------------ runs


def _tiny_joint(**filter_fields):
    data = read_toml(TINY)
    data["filter"].update({"learn": True, "learning_rate": 1.0, **filter_fields})
    data["optimize"].update({"spectral_sampling": "bands", "steps": 4, "t_max": 4})
    data["scene"]["z_near"] = "40mm:50mm"  # the tiny lens has f = 1 mm: s = 1.02-1.025
    return preset_from_dict(data, name="tiny-joint")


def bands_check(capsys, *args) -> tuple[int, dict]:
    code = run_cli(["bands", "check", *map(str, args), "--json"])
    return code, json.loads(capsys.readouterr().out)


def test_a_joint_run_keeps_its_limits_and_writes_the_filter_every_command_uses(tmp_path, capsys):
    preset = _tiny_joint(
        centers=["455nm", "530nm", "620nm"],
        widths=["8nm", "8nm", "8nm"],
        min_width="6nm",
        split_margin="0.5nm",
        split_weight=10.0,
    )
    assert check_filter(preset.filter, preset).ok
    summary = train(preset, tmp_path / "run")
    run = tmp_path / "run"
    f = preset.filter
    for row in summary.history:  # the limits hold after every step
        widths = [row[f"filter_width_{i}_nm"] * NM for i in range(3)]
        centres = [row[f"filter_center_{i}_nm"] * NM for i in range(3)]
        assert all(f.min_width_m - 1e-15 <= w <= f.max_width_m + 1e-15 for w in widths)
        assert row["filter_edge_nm"] * NM >= f.min_edge_width_m - 1e-15
        assert all(
            (c2 - w2 / 2) - (c1 + w1 / 2) >= f.min_gap_m - 1e-12
            for c1, w1, c2, w2 in zip(centres, widths, centres[1:], widths[1:])
        )
    moved = summary.history[-1]
    assert any(abs(moved[f"filter_center_{i}_nm"] - c / NM) > 1e-3 for i, c in enumerate(f.centers_m))
    learned = load_preset(run / "preset.toml").filter
    np.testing.assert_allclose(
        np.array(learned.centers_m) / NM, [moved[f"filter_center_{i}_nm"] for i in range(3)], atol=1e-9
    )
    assert learned.learn and learned.edge_width_m == pytest.approx(moved["filter_edge_nm"] * NM)
    header, *rows = (run / "filter.csv").read_text().splitlines()
    assert header == "wavelength_nm,transmission" and len(rows) == 601 and rows[1].startswith("400.5,")
    report = json.loads((run / "run.json").read_text())["filter"]
    assert report["learned"]["conditions"]["ok"] and set(report["learned"]["throughput"]) == {"R", "G", "B"}
    assert "filter_center_0_nm" in (run / "loss.csv").read_text().splitlines()[0] and (run / "filter.png").is_file()
    code, checked = bands_check(capsys, "--preset", run / "preset.toml")
    assert code == 0 and checked["ok"]


def test_a_learned_filter_that_fails_the_conditions_is_refused_not_written(tmp_path):
    # no penalty (so no feasible start either) and a start that fails at 40-50 mm: the run ends
    # refused, preset.toml untouched
    preset = _tiny_joint(
        centers=["500nm", "530nm", "560nm"], widths=["20nm", "20nm", "20nm"], split_weight=0.0, learning_rate=0.0
    )
    assert not check_filter(preset.filter, preset).ok
    with pytest.raises(ResultFailed, match="fails the split-spectrum conditions"):
        train(preset, tmp_path / "run")
    assert not (tmp_path / "run" / "filter.csv").exists()
    written = load_preset(tmp_path / "run" / "preset.toml").filter
    assert written.centers_m == preset.filter.centers_m


def test_bands_check_takes_oblique_rays_from_the_preset_and_the_options(joint, capsys):
    bands = bands_from_centers(list(joint.filter.centers_m), list(joint.filter.widths_m))
    assert check_bands(bands, 4e-3, (0.04, 0.05)).ok
    assert not check_bands(bands, 4e-3, (0.04, 0.05), incidence=incidence_factor(np.radians(25.7), 1.8)).ok
    code, checked = bands_check(capsys, "--preset", JOINT)
    assert code == 1 and checked["incidence_factor"] < 0.98 and not checked["ok"]
    code, checked = bands_check(capsys, "--preset", JOINT, "--max-incidence", "0deg")
    assert code == 0 and checked["incidence_factor"] == 1.0


# ------------------------------------------------------------------------------ light and noise


def test_throughput_of_a_filter_that_passes_everything_is_its_peak(joint):
    from metalens_cli.io.preset_spectra import channel_throughput

    open_filter = _with(joint, centers_m=(550e-9,), widths_m=(400e-9,), edge_width_m=0.5e-9, peak_transmission=0.8)
    np.testing.assert_allclose(channel_throughput(open_filter), 0.8, rtol=1e-6)
    np.testing.assert_array_equal(channel_throughput(dataclasses.replace(joint, filter=None)), 1.0)


def test_the_samplers_differentiable_throughput_matches_the_presets(joint):
    from metalens_cli.io.preset_spectra import channel_throughput

    sampler = band_sampler(joint, LearnedFilter(joint.filter))
    share = sampler.throughput()
    np.testing.assert_allclose(share.detach().numpy(), channel_throughput(joint), rtol=2e-3)
    (grad,) = torch.autograd.grad(share.sum(), sampler.band_filter.widths_nm)
    assert torch.all(grad > 0)  # a wider band passes more light: the noise term pays for narrow bands


def test_per_channel_photons_set_each_channels_shot_noise():
    from metalens_cli.imaging.formation import add_noise

    image = torch.full((2, 3, 128, 128), 0.5)
    photons = torch.tensor([100.0, 400.0, 1600.0]).reshape(3, 1, 1)
    noisy = add_noise(image, photons, read_noise=0.0, generator=0)
    std = (noisy - image).std(dim=(0, 2, 3))
    np.testing.assert_allclose(std.numpy(), np.sqrt(0.5 / np.array([100, 400, 1600])), rtol=0.03)


def test_evaluation_gives_each_design_its_filters_share_of_the_light(joint):
    from metalens_cli.imaging.evaluation import EvaluationSettings, design_photons
    from metalens_cli.io.preset_spectra import channel_throughput

    class Design:
        preset = joint

    settings = EvaluationSettings(64, 1.85e-6, (0.04, 0.05), (1.0, 20.0), [530e-9], photons=2000)
    assert design_photons(Design, settings) == 2000
    before = dataclasses.replace(settings, photons_before_filter=True)
    np.testing.assert_allclose(design_photons(Design, before), 2000 * channel_throughput(joint))


def test_two_bands_per_channel_learn_like_three(joint):
    # six interleaved bands (the paper's suggestion): labelled band1..band6, sampled and checked alike
    six = _with(joint, centers_m=tuple(np.array([440, 468, 520, 548, 612, 645]) * NM), widths_m=(10 * NM,) * 6)
    model = LearnedFilter(six.filter)
    sampler = band_sampler(six, model)
    wavelengths, weights, _ = sampler.draw(np.random.default_rng(0))
    assert wavelengths.size == 6 * six.optimize.wavelengths_per_channel and weights.shape == (3, wavelengths.size)
    penalty = split_penalty(model, six, preset_incidence_factor(six))
    report = check_filter(six.filter, six)
    assert [b.label for b in report.bands] == [f"band{i}" for i in range(1, 7)]
    shortfall = sum(max(0.0, six.filter.split_margin_m - c.margin_m) ** 2 for c in report.conditions) / NM**2
    assert float(penalty.detach()) == pytest.approx(shortfall, rel=1e-9) and shortfall > 0
    penalty.backward()
    assert torch.isfinite(model.centres_nm.grad).all()


def test_the_light_term_rewards_wider_bands_by_their_light(joint):
    model = LearnedFilter(joint.filter)
    sampler = band_sampler(joint, model)
    light = sampler.light_loss()
    assert float(light.detach()) == pytest.approx(-np.log(sampler.throughput().detach().numpy()).mean(), rel=1e-12)
    (grad,) = torch.autograd.grad(light, model.widths_nm)
    assert torch.all(grad < 0)
    # halving R's band: the change equals the numpy throughput's of the two filters (crosstalk included)
    from metalens_cli.io.preset_spectra import channel_throughput

    with torch.no_grad():
        model.widths_nm[2] /= 2
    halved = _with(joint, widths_m=joint.filter.widths_m[:2] + (joint.filter.widths_m[2] / 2,))
    expected = -np.log(channel_throughput(halved)).mean() + np.log(channel_throughput(joint)).mean()
    assert float(sampler.light_loss().detach()) - float(light.detach()) == pytest.approx(expected, rel=5e-3)
