"""The public API's contract (docs/api.md), for every name in ``metalens_cli.__all__``: hostile
arguments (None, NaN, ±inf, negative and zero sizes, wrong types, a device this machine lacks)
raise ``InputError`` naming the parameter, or ``TypeError`` naming it for a wrong type; huge
sizes are refused from the memory estimate before anything large is allocated (issue 60)."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

import metalens_cli as ml

ROOT = Path(__file__).parents[1]
NAN, INF = math.nan, math.inf

# hostile values by the kind of parameter
LENGTH = [None, NAN, INF, -INF, -1e-3, 0.0, "1mm"]  # a positive finite length (m)
FAR = [None, NAN, -INF, -1.0, 0.0, "1m"]  # a depth: positive, inf allowed
OPTIONAL_LENGTH = [NAN, INF, -1e-3, 0.0, "1mm"]  # None means "the default"
LENGTHS = [None, [NAN], [INF], [-1e-9], [0.0], [], "532nm"]
DEPTHS = [None, [NAN], [-1.0], [0.0], [], "inf"]
ANGLE = [None, NAN, INF, -0.1, "5deg"]  # a field angle from 0
AZIMUTH = [None, NAN, INF, "0deg"]
COUNT = [None, -1, 0, 2.5, "64"]
OBJECT = [None, 3]


class NanInGood:
    """The good value of the parameter with a NaN in it."""

    def __repr__(self):
        return "nan-in-array"


NAN_IN = NanInGood()
ARRAY = [None, "x", NAN_IN]
NUMBER = [None, NAN, INF, "1"]
TEXT = [None, 5]
CHOICE = [None, 5, "nonsense"]
DEVICE = ["tpu", 5] + ([] if torch.cuda.is_available() else ["cuda"])

RESULT_TYPES = {  # made by the API and returned; callers read them, they do not build them
    "InputError",
    "ResultFailed",
    "BandsReport",
    "Capture",
    "Design",
    "FieldPsf",
    "FinResponse",
    "Preset",
    "PsfCube",
    "PsfResult",
    "RadialGrid",
    "SpectralSensitivity",
}
NOT_CALLABLE = {"__version__", "constants"}


class Good:
    """Valid arguments, built once."""

    def __init__(self):
        self.lens = ml.hyperbolic(532e-9, 1e-3, 40e-6, 400e-9)
        self.grid = ml.radial_grid(33, 0.5e-6)
        self.psf_grid = ml.PsfGrid([532e-9], [INF], 33, 0.5e-6)
        self.psf = ml.compute_psf(self.lens, self.psf_grid).psf.numpy()
        self.design = ml.resolve_design("hyperbolic:532nm", f_m=1e-3, aperture_m=40e-6, pitch_m=400e-9)
        self.preset = ml.load_preset(ROOT / "tests" / "design" / "tiny.toml")
        self.canvas = torch.full((3, 48, 48), 0.5, dtype=torch.float64)
        self.mask = torch.zeros((1, 48, 48), dtype=torch.float64)
        self.blur = torch.ones((3, 17, 17), dtype=torch.float64)
        self.image = torch.full((3, 16, 16), 0.5)
        self.bands = ml.bands_from_centers([457e-9, 530e-9, 628e-9], [22e-9, 20e-9, 28e-9])
        waves = np.linspace(400e-9, 700e-9, 31)
        self.sensitivity = ml.spectral_sensitivity(waves, np.ones((3, 31)))
        self.fin = ml.Fin(period_m=395e-9, height_m=700e-9, width_m=125e-9, length_m=305e-9)
        self.geometry = ml.FinGeometry(pitch_m=400e-9, width_m=125e-9, length_m=305e-9)
        self.psf_set = ml.FieldPsfSet((0, 4), torch.ones((2, 3, 9, 9), dtype=torch.float64))
        folder = Path(tempfile.mkdtemp())
        ml.write_psf_cube(folder / "c.exr", self.psf, np.array([532e-9]), np.array([INF]), 0.5e-6, "hyperbolic:532nm")
        self.cube = ml.read_psf_cube(folder / "c.exr")


GOOD = None


def good() -> Good:
    global GOOD
    GOOD = GOOD or Good()
    return GOOD


# name → (baseline call: a function of Good giving (args, kwargs); {parameter: hostile values}; aliases the error
# may use for a parameter)
CASES = {
    # the parsers name the field they are given ("--f"): that is how their caller names the text
    "parse_length": (lambda g: (("4mm", "--f"), {}), {"text": [None, 5, "nan", "-1mm", ""]}, {"text": "--f"}),
    "parse_range": (lambda g: (("430:650:10nm", "--w"), {}), {"text": [None, 5, "nan:1:2nm", ""]}, {"text": "--w"}),
    "parse_angle": (lambda g: (("5deg", "--a"), {}), {"text": [None, 5, "nandeg", ""]}, {"text": "--a"}),
    "format_length": (
        lambda g: ((4e-3,), {}),
        {"value_m": [None, NAN, "4mm"], "unit": CHOICE, "digits": [None, 0, -1, 2.5, "4"]},
    ),
    "hyperbolic": (
        lambda g: ((532e-9, 1e-3, 40e-6, 400e-9), {}),
        {"lambda_d_m": LENGTH, "focal_length_m": LENGTH, "aperture_m": LENGTH, "pitch_m": LENGTH},
    ),
    "Metalens": (
        lambda g: ((g.lens.theta, 400e-9, 40e-6), {"focal_length_m": 1e-3}),
        {"theta": ARRAY, "pitch_m": LENGTH, "aperture_m": LENGTH, "focal_length_m": OPTIONAL_LENGTH},
    ),
    "resolve_design": (
        lambda g: (("hyperbolic:532nm",), {"f_m": 1e-3, "aperture_m": 40e-6, "pitch_m": 400e-9}),
        {"spec": [None, 5, "nonsense:1"], "f_m": OPTIONAL_LENGTH, "aperture_m": OPTIONAL_LENGTH},
        {"spec": "--design"},  # a design spec is --design in every command
    ),
    "load_preset": (lambda g: ((ROOT / "tests" / "design" / "tiny.toml",), {}), {"path": [None, 5]}),
    # the PSF sampling: its fields are checked where a grid is built (the names psf_inputs used)
    "PsfGrid": (
        lambda g: (([532e-9], [INF], 33, 0.5e-6), {}),
        {
            "wavelengths_m": LENGTHS,
            "depths_m": DEPTHS,
            "pixels": COUNT,
            "pixel_pitch_m": LENGTH,
            "distance_m": OPTIONAL_LENGTH,
        },
    ),
    "compute_psf": (
        lambda g: ((g.lens, g.psf_grid), {}),
        {
            "lens": OBJECT,
            "grid": OBJECT,
            "propagator": CHOICE,
            "device": DEVICE,
            "oversample": [None, NAN, INF, 0.0, -1.0, "2"],
        },
    ),
    "estimate_psf": (
        lambda g: ((g.lens, g.psf_grid), {}),
        {"lens": OBJECT, "grid": OBJECT, "propagator": CHOICE, "oversample": [None, NAN, 0.0, "2"]},
    ),
    "field_psf": (
        lambda g: ((g.lens, g.psf_grid, 0.05), {}),
        {
            "lens": OBJECT,
            "grid": OBJECT,
            "angle_rad": ANGLE,
            "azimuth_rad": AZIMUTH,
            "propagator": CHOICE,
            "device": DEVICE,
        },
    ),
    "field_angle": (lambda g: ((1e-4, 1e-3), {}), {"height_m": [None, NAN, INF, -1e-3, "1mm"], "distance_m": LENGTH}),
    "chief_ray": (
        lambda g: ((g.lens, 532e-9, 0.05, 0.0, 1e-3), {}),
        {
            "lens": OBJECT,
            "wavelength_m": LENGTH,
            "angle_rad": [*ANGLE, math.pi / 2],
            "azimuth_rad": AZIMUTH,
            "distance_m": LENGTH,
        },
    ),
    "ray_landings": (
        lambda g: ((g.lens, 532e-9, 0.05, INF, 1e-3), {}),
        {
            "lens": OBJECT,
            "wavelength_m": LENGTH,
            "angle_rad": [*ANGLE, math.pi / 2],
            "depth_m": FAR,
            "distance_m": LENGTH,
            "azimuth_rad": AZIMUTH,
            "samples": COUNT,
        },
    ),
    "rms_spot": (lambda g: ((np.zeros((10, 2)),), {}), {"landings": ARRAY}),
    "crop_window": (lambda g: ((g.psf, 17), {}), {"psf": [None, "x", np.zeros(5)], "n": COUNT}),  # slicing only
    "read_psf_cube": (lambda g: (("x.exr",), {}), {"path": [None, 5]}),
    "write_psf_cube": (
        lambda g: (("{tmp}/c.exr", g.psf, np.array([532e-9]), np.array([INF]), 0.5e-6, "hyperbolic:532nm"), {}),
        {"path": [None, 5], "psf": ARRAY, "pixel_pitch_m": LENGTH, "wavelengths_m": LENGTHS, "depths_m": DEPTHS},
    ),
    "run_scan": (
        lambda g: ((g.design, g.psf_grid), {}),
        {"design": OBJECT, "grid": OBJECT, "propagator": CHOICE, "device": DEVICE},
    ),
    # the field scan: the same driver given field angles
    "run_scan fields": (
        lambda g: ((g.design, g.psf_grid), {"field_angles_rad": [0.0, 0.05]}),
        {
            "design": OBJECT,
            "grid": OBJECT,
            "field_angles_rad": [[NAN], [-0.1], [], "5deg"],
            "azimuth_rad": AZIMUTH,
            "propagator": ["radial", "rs", 5],
            "device": DEVICE,
        },
        {"propagator": "propagator"},
    ),
    "field_channel_psfs": (
        lambda g: ((g.design, 0.045, INF, [532e-9], 1.85e-6, 32), {}),
        {
            "design": OBJECT,
            "z_near_m": LENGTH,
            "z_far_m": FAR,
            "wavelengths_m": LENGTHS,
            "pixel_pitch_m": LENGTH,
            "sensor_pixels": COUNT,
            "device": DEVICE,
        },
    ),
    "FieldPsfSet": (
        lambda g: (((0, 4), torch.ones((2, 3, 9, 9), dtype=torch.float64)), {}),
        {"heights_px": [None, (NAN,), "0"], "psfs": ARRAY},
    ),
    "field_transform": (
        lambda g: ((g.psf_set, (16, 16)), {}),
        {"psf_set": OBJECT, "sensor_hw": [None, (0, 16), (16, NAN), "16"], "tolerance": NUMBER},
    ),
    "form_image_field": (
        lambda g: ((g.canvas, g.canvas, g.mask, g.psf_set, g.psf_set, 16), {}),
        {
            "clean": ARRAY,
            "obstruction": ARRAY,
            "mask": ARRAY,
            "near": OBJECT,
            "far": OBJECT,
            "margin": [None, -1, 2.5, "16"],
            "formation": CHOICE,
        },
    ),
    "form_image": (
        lambda g: ((g.canvas, g.canvas, g.mask, g.blur, g.blur, 16), {}),
        {
            "clean": ARRAY,
            "obstruction": ARRAY,
            "mask": ARRAY,
            "psf_near": ARRAY,
            "psf_far": ARRAY,
            "margin": [None, -1, 2.5, "16"],
            "formation": CHOICE,
            "alpha_gain": [NAN, INF, -1.0, "1"],
        },
    ),
    "spectral_sensitivity": (
        lambda g: ((np.linspace(400e-9, 700e-9, 31), np.ones((3, 31))), {}),
        {"wavelengths_m": ARRAY, "crf": ARRAY, "transmission": ["x", NAN_IN], "efficiency": ["x", NAN_IN]},
    ),
    "camera_response": (
        lambda g: ((np.linspace(400e-9, 700e-9, 31),), {}),
        {"wavelengths_m": ARRAY, "name": CHOICE},
    ),
    "bandpass_transmission": (
        lambda g: ((np.linspace(400e-9, 700e-9, 31), [530e-9], [20e-9]), {}),
        {
            "wavelengths_m": ARRAY,
            "centres_m": LENGTHS,
            "widths_m": LENGTHS,
            "edge_width_m": LENGTH,
            "peak": [None, NAN, -0.1, 1.5, "1"],
        },
    ),
    "quadrature_weights": (
        lambda g: ((g.sensitivity, np.array([450e-9, 550e-9, 650e-9])), {}),
        {"sensitivity": OBJECT, "nodes_m": ARRAY},
        {"nodes_m": "wavelengths"},  # the scan's wavelengths, as psf-scan names them
    ),
    "Band": (lambda g: (("G", 520e-9, 540e-9), {}), {"label": TEXT, "lo_m": LENGTH, "hi_m": LENGTH}),
    "bands_from_centers": (
        lambda g: (([457e-9, 530e-9], [22e-9, 20e-9]), {}),
        {"centers_m": LENGTHS, "widths_m": LENGTHS},
    ),
    "check_bands": (
        lambda g: ((g.bands, 4e-3, (0.04, 0.05)), {}),
        {
            "bands": [None, 3, ()],
            "f_m": LENGTH,
            "z_near_m": [None, (NAN, 0.05), (0.04, INF), (-1.0, 0.05), "45mm"],
            "sensor_range_m": [(NAN, 7e-7), (7e-7, 4e-7), "400nm:700nm"],
            "incidence": [None, NAN, 0.0, 1.5, "1"],
        },
    ),
    "depth_for_wavelength": (
        lambda g: ((550e-9, 532e-9, 4e-3), {}),
        {"wavelength_m": LENGTH, "lambda_d_m": LENGTH, "f_m": LENGTH},
    ),
    "wavelength_for_depth": (
        lambda g: ((0.045, 532e-9, 4e-3), {}),
        {"depth_m": FAR, "lambda_d_m": LENGTH, "f_m": LENGTH},
    ),
    "Fin": (
        lambda g: ((), {"period_m": 395e-9, "height_m": 700e-9, "width_m": 125e-9, "length_m": 305e-9}),
        {"period_m": LENGTH, "height_m": LENGTH, "width_m": LENGTH, "length_m": LENGTH},
    ),
    "fin_response": (
        lambda g: ((g.fin, np.full(1, 2.0 + 0j), np.full(1, 1.46 + 0j), np.array([530e-9]), 3), {}),
        {
            "fin": OBJECT,
            "fin_index": ARRAY,
            "substrate_index": ARRAY,
            "wavelengths_m": LENGTHS,
            "harmonics": [None, 0, 2, -1, 2.5, "3"],
            "solver": CHOICE,
            "device": DEVICE,
        },
    ),
    "add_noise": (
        lambda g: ((g.image,), {"photons": 100.0, "generator": 0}),
        {"image": ARRAY, "photons": [NAN, INF, -1.0, "100"], "read_noise": [None, NAN, INF, -0.1, "0"]},
    ),
    "psnr": (
        lambda g: ((g.image, g.image), {}),
        {"estimate": ARRAY, "reference": [*ARRAY, torch.zeros(3, 8, 8)], "data_range": LENGTH},
    ),
    "ssim": (
        lambda g: ((g.image, g.image), {}),
        {
            "estimate": ARRAY,
            "reference": [*ARRAY, torch.zeros(3, 8, 8)],
            "data_range": LENGTH,
            "window": COUNT,
            "sigma": LENGTH,
        },
    ),
    "EvaluationSettings": (
        lambda g: ((32, 1.85e-6, (0.04, 0.05), (1.0, 20.0), [532e-9]), {}),
        {
            "pixels": COUNT,
            "pixel_pitch_m": LENGTH,
            "z_near_interval_m": [None, (NAN, 0.05), (0.05, 0.04), "45mm"],
            "z_far_interval_m": [None, (NAN, 20.0), (-1.0, 2.0), "1m:20m"],
            "wavelengths_m": LENGTHS,
            "formation": CHOICE,
            "read_noise": [None, NAN, INF, -0.1],
        },
    ),
    "radial_grid": (lambda g: ((33, 0.5e-6), {}), {"n": COUNT, "pixel_pitch_m": LENGTH}),
    "psf_mtf": (lambda g: ((g.psf[0], g.grid), {}), {"psf": ARRAY, "grid": OBJECT}),
    "line_mtf": (
        lambda g: ((g.psf[0, 0], g.grid, 0.0), {}),
        {"psf": ARRAY, "grid": OBJECT, "angle_rad": [None, NAN, INF, "0deg"]},
    ),
    "diffraction_limited_mtf": (
        lambda g: ((g.grid, 0.02, np.array([532e-9])), {}),
        {"grid": OBJECT, "na": [None, NAN, 0.0, 1.5, "0.1"], "wavelengths_m": LENGTHS},
    ),
    "mtf50": (
        lambda g: ((g.grid.frequencies_lpmm, np.linspace(1, 0, g.grid.frequencies_lpmm.size)), {}),
        {"frequencies": ARRAY, "mtf": ARRAY, "level": [None, NAN, 0.0, 1.0, "0.5"]},
    ),
    "FinGeometry": (
        lambda g: ((), {"pitch_m": 400e-9, "width_m": 125e-9, "length_m": 305e-9}),
        {"pitch_m": LENGTH, "width_m": LENGTH, "length_m": LENGTH, "dbu_m": LENGTH, "layer": [None, -1, 2.5, "1"]},
    ),
    "export_layout": (
        lambda g: ((g.design, g.geometry, "{tmp}/l.gds"), {}),
        {"design": OBJECT, "geometry": OBJECT, "path": [None, 5], "fmt": CHOICE, "angles": [0, -1, 2.5, "8"]},
    ),
    "train": (
        lambda g: ((g.preset, "{tmp}/run"), {"steps": 0}),
        {"preset": OBJECT, "run_dir": [None, 5], "steps": [-1, 2.5, "2"], "seed": [-1, 2.5, "0"], "device": DEVICE},
    ),
}
CASES["cube_mtf"] = (lambda g: ((g.cube,), {}), {"cube": OBJECT})
CASES["field_mtf"] = (lambda g: ((g.cube, g.grid), {}), {"cube": OBJECT, "grid": OBJECT})

LOW_LEVEL = {  # propagation kernels, training and evaluation loops: their objects come from the API itself
    "asm_propagate": {"field": OBJECT, "grid": OBJECT, "transfer": OBJECT},
    "radial_propagate": {"field_r": OBJECT, "kernel": OBJECT, "transfer": OBJECT, "out_matrix": OBJECT},
    "rayleigh_sommerfeld": {"points_xy": OBJECT, "values": OBJECT, "out_xy": OBJECT},
    "channel_psf_stack": {"lens": OBJECT},
    "simulate_captures": {"psfs": OBJECT},
    "evaluate": {"settings": OBJECT},
    "train_reconstruction": {"design": OBJECT},
    "slanted_edge_sfr": {"image": ARRAY},
}


def test_every_public_name_is_classified():
    covered = {name.split()[0] for name in CASES} | set(LOW_LEVEL) | RESULT_TYPES | NOT_CALLABLE
    assert covered == set(ml.__all__), sorted(covered ^ set(ml.__all__))


def _hostile_cases():
    for name, (_, params, *_) in sorted(CASES.items()):
        for param, values in params.items():
            for value in values:
                yield pytest.param(name, param, value, id=f"{name}-{param}-{value!r}"[:90])


def _substitute(name, param, value, tmp_path):
    import inspect

    make = CASES[name][0]
    args, kwargs = make(good())
    args = [a.replace("{tmp}", str(tmp_path)) if isinstance(a, str) else a for a in args]
    kwargs = {k: v.replace("{tmp}", str(tmp_path)) if isinstance(v, str) else v for k, v in kwargs.items()}
    target = getattr(ml, name.split()[0])  # "run_scan fields": a second case of run_scan
    bound = inspect.signature(target).bind_partial(*args, **kwargs)
    if value is NAN_IN and param in bound.arguments:
        good_value = bound.arguments[param]
        if isinstance(good_value, torch.Tensor):
            value = good_value.clone()
            value.view(-1)[0] = NAN
        else:
            value = np.array(good_value, dtype=float if not np.iscomplexobj(good_value) else complex)
            value.flat[0] = NAN
    bound.arguments[param] = value
    return target, bound


@pytest.mark.parametrize("name, param, value", list(_hostile_cases()))
def test_a_hostile_argument_is_refused_naming_its_parameter(name, param, value, tmp_path):
    target, bound = _substitute(name, param, value, tmp_path)
    with pytest.raises((ml.InputError, TypeError)) as error:
        target(*bound.args, **bound.kwargs)
    alias = (CASES[name][2] if len(CASES[name]) > 2 else {}).get(param, param)
    assert _names(alias, str(error.value)), f"{type(error.value).__name__}: {error.value}"


def _names(param: str, message: str) -> bool:
    """Whether ``message`` names ``param``, with or without its unit suffix (``wavelengths`` for
    ``wavelengths_m``: the CLI maps that name to its option)."""
    return param in message or re.sub(r"_(m|rad|px)$", "", param) in message


@pytest.mark.parametrize("name", sorted(LOW_LEVEL))
def test_low_level_names_refuse_none_and_wrong_types(name):
    import inspect

    target = getattr(ml, name)
    signature = inspect.signature(target)
    for param, values in LOW_LEVEL[name].items():
        for value in values:
            arguments = {
                p.name: None for p in signature.parameters.values() if p.default is inspect.Parameter.empty
            } | {param: value}
            with pytest.raises((ml.InputError, TypeError)) as error:
                target(**arguments)
            assert param in str(error.value) or any(p in str(error.value) for p in arguments), error.value


def test_read_psf_cube_names_the_format_it_expected(tmp_path):
    for suffix, form in ((".npz", "npz"), (".mat", "MATLAB"), (".tif", "TIFF"), (".exr", "OpenEXR")):
        path = tmp_path / f"x{suffix}"
        path.write_bytes(b"not a cube")
        with pytest.raises(ml.InputError) as error:
            ml.read_psf_cube(path)
        assert form in str(error.value), (suffix, str(error.value))
    path = tmp_path / "x.csv"
    path.write_text("1,2\n")
    with pytest.raises(ml.InputError, match="exr, .npz, .mat"):
        ml.read_psf_cube(path)


HUGE = {  # name → a call whose arrays would not fit on any machine
    "ray_landings": "ml.ray_landings(lens, 532e-9, 0.05, math.inf, 1e-3, samples=10**7)",
    "radial_grid": "ml.radial_grid(10**9, 1e-6)",
    "compute_psf": "ml.compute_psf(lens, ml.PsfGrid([532e-9], [math.inf], 10**7, 0.5e-6))",
    "field_psf": "ml.field_psf(lens, ml.PsfGrid([532e-9], [math.inf], 10**7, 0.5e-6), 0.05)",
    "hyperbolic 2-D": "ml.hyperbolic(532e-9, 1e-3, 1.0, 400e-9, radial=False)",
    "crop_window": "ml.crop_window(np.zeros((1, 1, 5, 5)), 10**7)",
    "bandpass_transmission": "ml.bandpass_transmission(wide, wide, wide / 50)",  # 10⁶ wavelengths × 10⁶ bands
}


def test_huge_sizes_are_refused_before_any_large_allocation():
    """In a child whose address space is capped 3 GiB above what it holds after import: a huge
    allocation there is a MemoryError, not the InputError the contract asks for."""
    calls = "\n".join(
        f"""
try:
    {call}
    print({name!r}, 'ran')
except ml.InputError as e:
    print({name!r}, 'InputError', e)
except BaseException as e:
    print({name!r}, type(e).__name__, e)"""
        for name, call in HUGE.items()
    )
    script = (
        textwrap.dedent(
            """
        import math, resource
        import numpy as np, torch
        import metalens_cli as ml
        lens = ml.hyperbolic(532e-9, 1e-3, 40e-6, 400e-9)
        wide = np.full(10**6, 5e-7)
        ml.compute_psf(lens, ml.PsfGrid([532e-9], [math.inf], 9, 0.5e-6))  # every module loaded
        held = int(open('/proc/self/statm').read().split()[0]) * resource.getpagesize()
        resource.setrlimit(resource.RLIMIT_AS, (held + (3 << 30), resource.RLIM_INFINITY))
        """
        )
        + calls
    )
    result = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=300,
        env=os.environ | {"OMP_NUM_THREADS": "1"},
    )
    lines = result.stdout.splitlines()
    assert len(lines) == len(HUGE), result.stdout + result.stderr
    wrong = [line for line in lines if " InputError " not in line]
    assert not wrong, wrong


def test_the_finiteness_check_reads_a_sum_and_never_refuses_finite_values():
    """arguments.array tests a sum first (one reduction) and the values only when the sum is not
    finite: finite values whose sum overflows pass, a NaN or inf anywhere does not."""
    from metalens_cli import arguments

    huge = np.full(4, np.finfo(np.float32).max, dtype=np.float32)  # its sum overflows to inf
    assert arguments.array(huge, "x") is huge and arguments.array(torch.from_numpy(huge), "x") is not None
    for bad in (np.array([1.0, np.nan]), np.array([np.inf, -np.inf]), torch.tensor([0.0, -math.inf])):
        with pytest.raises(ml.InputError, match="x: holds NaN or infinite values"):
            arguments.array(bad, "x")
