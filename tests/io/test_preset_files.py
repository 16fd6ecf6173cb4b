"""One validation before any work: every file a preset names is opened and checked when the
preset loads (paths relative to the preset file), and a filter to learn has limits that admit
one; each refusal names the key and the bound (issue 60)."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from metalens_cli.cli.main import run
from metalens_cli.errors import InputError
from metalens_cli.io.presets import load_preset

PRESETS = Path(__file__).parents[2] / "presets"
JOINT = (PRESETS / "quick-joint-filter.toml").read_text()
HEADER = "name,center_nm,fwhm_nm,edge_nm,peak\n"
NARROW = "narrow,450,12,1.5,90\nnarrow,535,14,1.5,90\nnarrow,640,16,1.5,90\n"  # passes at 25.7° (the paper's does not)


def _joint(folder: Path, extra: str = "", **keys: str) -> Path:
    """quick-joint-filter.toml in ``folder``/sub with ``extra`` added to [filter] and ``keys`` replaced."""
    text = JOINT.replace("learn = true ", f"{extra}\nlearn = true ", 1)
    for key, value in keys.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.M)
    path = folder / "sub" / "preset.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    return path


def _refused(path: Path, key: str) -> str:
    with pytest.raises(InputError) as error:
        load_preset(path)
    assert error.value.field.endswith(key), error.value
    return str(error.value)


@pytest.mark.parametrize(
    "content, message",
    [
        (None, "no such file"),
        ("folder", "is a folder"),
        (b"", "header"),
        ("latin", "not UTF-8"),
        (HEADER + "a,457,nan,2,0.9\n", "row 2"),
        (HEADER + NARROW + "narrow,535,14,1.5,90\n", "row 5 repeats row 3"),
        (HEADER + "wide,450,40,2,0.9\nwide,480,40,2,0.9\nwide,640,20,2,0.9\n", "overlap"),
        (HEADER + "dual,480,20,2,0.9\ndual,600,20,2,0.9\n", "no 3-band filter"),
        (HEADER + "paper,457,22,2,0.9\npaper,530,20,2,0.9\npaper,628,28,2,0.9\n", "meets the split-spectrum"),
    ],
)
def test_a_catalogue_that_would_fail_after_training_is_refused_at_load(tmp_path, content, message):
    preset = _joint(tmp_path, 'catalogue = "cat.csv"')
    catalogue = preset.parent / "cat.csv"
    if content == "folder":
        catalogue.mkdir()
    elif content == "latin":
        catalogue.write_bytes((HEADER + "b\xe9ta,457,22,2,0.9\n").encode("latin-1"))
    elif content is not None:
        catalogue.write_bytes(content if isinstance(content, bytes) else content.encode())
    assert message in _refused(preset, "filter.catalogue")


def test_a_device_as_catalogue_is_refused(tmp_path):
    assert "not a regular file" in _refused(_joint(tmp_path, 'catalogue = "/dev/zero"'), "filter.catalogue")


def test_a_catalogue_path_is_relative_to_the_preset_not_the_working_directory(tmp_path, monkeypatch):
    preset = _joint(tmp_path, 'catalogue = "cat.csv"')
    (preset.parent / "cat.csv").write_text(HEADER + NARROW)
    (tmp_path / "cat.csv").write_text(HEADER)  # what the working directory holds: not read
    monkeypatch.chdir(tmp_path)
    assert load_preset(preset).filter.catalogue == str((preset.parent / "cat.csv").resolve())


def test_preset_show_and_optimize_refuse_before_any_step(tmp_path, capsys):
    preset = _joint(tmp_path, 'catalogue = "cat.csv"')
    (preset.parent / "cat.csv").write_text(HEADER + NARROW + "narrow,640,16,1.5,90\n")
    assert run(["preset", "show", str(preset)]) == 2
    assert "filter.catalogue" in capsys.readouterr().err
    assert run(["optimize", str(preset), "-o", str(tmp_path / "run"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "filter.catalogue" in err and "filter.centers" not in err and not (tmp_path / "run").exists()


def test_a_min_gap_that_pushes_bands_out_of_the_sensor_range_is_refused_with_the_bound(tmp_path):
    text = _refused(_joint(tmp_path, min_gap='"200nm"'), "filter.min_gap")
    assert "holds 300 nm" in text and "min_gap at most 135 nm" in text
    text = _refused(_joint(tmp_path, min_width='"101nm"', max_width='"120nm"'), "filter.min_width")
    assert "min_width at most 100 nm" in text


def test_a_split_margin_no_filter_keeps_is_refused_with_the_largest_one(tmp_path):
    text = _refused(_joint(tmp_path, split_margin='"100nm"'), "filter.split_margin")
    assert "at most 13.84 nm" in text and "filter.max_incidence" in text
    load_preset(_joint(tmp_path, split_margin='"13.8nm"'))
    text = _refused(_joint(tmp_path, max_incidence='"89deg"', n_eff="1.0"), "filter.learn")
    assert "meets the split-spectrum conditions" in text


# ------------------------------------------------------------------------------ other files


def _quick(folder: Path, section: str, line: str) -> Path:
    """quick-split-spectrum.toml in ``folder``/sub with ``line`` (key = value) set in ``section``."""
    text = (PRESETS / "quick-split-spectrum.toml").read_text()
    key = line.split("=")[0].strip()
    if re.search(rf"^{key} = ", text, flags=re.M):
        text = re.sub(rf"^{key} = .*$", line, text, count=1, flags=re.M)
    else:
        text = text.replace(f"[{section}]", f"[{section}]\n{line}", 1)
    if section == "nanofin":
        text = "\n".join(t for t in text.splitlines() if not t.startswith(("efficiency =", "efficiency_wavelengths")))
    path = folder / "sub" / "preset.toml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text)
    return path


BAD_CSV = "wavelength_nm,value\n450,0.5\n440,0.6\n"  # wavelengths must increase


@pytest.mark.parametrize(
    "section, line, key",
    [
        ("nanofin", 'efficiency_csv = "t.csv"', "nanofin.efficiency_csv"),
        ("sensor", 'camera_response = "t.csv"', "sensor.camera_response"),
        ("loss", 'domain_adaptation_weights = "t.csv"', "loss.domain_adaptation_weights"),
    ],
)
def test_every_table_and_model_a_preset_names_is_read_at_load(tmp_path, section, line, key):
    preset = _quick(tmp_path, section, line)
    (preset.parent / "t.csv").write_text(BAD_CSV if "csv" in key or "camera" in key else "not a checkpoint")
    _refused(preset, key)


def test_a_measured_filter_table_is_read_at_load(tmp_path):
    text = (PRESETS / "quick-split-spectrum.toml").read_text()
    start, end = text.index("[filter]"), text.index("[sensor]")
    path = tmp_path / "p.toml"
    path.write_text(text[:start] + '[filter]\ncsv = "t.csv"\n\n' + text[end:])
    (tmp_path / "t.csv").write_text(BAD_CSV)
    _refused(path, "filter.csv")
    (tmp_path / "t.csv").write_text("wavelength_nm,transmission\n400,0\n450,0.9\n700,0\n")
    assert load_preset(path).filter.csv == str(tmp_path / "t.csv")


def test_training_images_and_obstruction_files_are_checked_at_load(tmp_path, monkeypatch):
    images = tmp_path / "sub" / "photos"
    images.mkdir(parents=True)
    preset = _quick(tmp_path, "optimize", 'images = "photos"')
    assert "holds no images" in _refused(preset, "optimize.images")
    (images / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    assert "not a readable image" in _refused(preset, "optimize.images")
    from metalens_cli.io.image_files import write_png

    write_png(images / "a.png", np.full((8, 8, 3), 0.5, dtype=np.float32))
    assert load_preset(preset).optimize.images == str(images.resolve())
    preset = _quick(tmp_path, "optimize", 'obstructions = ["dirt", "file:mask.png"]')
    _refused(preset, "optimize.obstructions")
    write_png(preset.parent / "mask.png", np.zeros((8, 8, 3), dtype=np.float32))
    monkeypatch.chdir(tmp_path)  # resolved against the preset's folder, not the working directory
    assert load_preset(preset).optimize.obstructions[1] == f"file:{(preset.parent / 'mask.png').resolve()}"


def test_the_learned_report_says_whether_the_margin_asked_for_was_kept(tmp_path):
    from metalens_cli.design.filter_learning import _conditions, check_filter

    joint = load_preset(PRESETS / "quick-joint-filter.toml")
    report = _conditions(check_filter(joint.filter, joint, incidence=1.0), 6e-9)
    assert report["ok"] and report["split_margin_m"] == 6e-9 and not report["split_margin_met"]
    assert min(report["margins_m"].values()) == pytest.approx(5.2e-9, abs=1e-11)
    assert _conditions(check_filter(joint.filter, joint, incidence=1.0), 0.5e-9)["split_margin_met"]
    assert json.dumps(report)


def test_a_reconstruction_presets_images_and_masks_are_checked_at_load(tmp_path):
    from metalens_cli.io.reconstruct_presets import load_reconstruct_preset

    text = (PRESETS / "quick-reconstruct.toml").read_text().replace("[data]", '[data]\nimages = "photos"', 1)
    preset = tmp_path / "r.toml"
    preset.write_text(text)
    (tmp_path / "photos").mkdir()
    with pytest.raises(InputError, match="data.images: .* holds no images"):
        load_reconstruct_preset(preset)
    (tmp_path / "photos" / "a.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(InputError, match="data.images: .*not a readable image"):
        load_reconstruct_preset(preset)
