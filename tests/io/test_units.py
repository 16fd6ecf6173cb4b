"""Parsing lengths with units into SI metres."""

import math

import pytest

from metalens_cli.errors import InputError
from metalens_cli.io import units


@pytest.mark.parametrize(
    "text, metres",
    [
        ("4mm", 4e-3),
        ("450nm", 450e-9),
        ("1.85um", 1.85e-6),
        ("1.85µm", 1.85e-6),
        ("1.85μm", 1.85e-6),
        ("0.045m", 0.045),
        ("2.516 mm", 2.516e-3),
        ("1e3nm", 1e-6),
        ("395nm", 3.95e-7),
        ("1km", 1e3),
    ],
)
def test_lengths(text, metres):
    assert units.parse_length(text, "--x") == metres  # exact: scaled by exact powers of ten


def test_inf_only_where_allowed():
    assert units.parse_length("inf", "--depth", allow_inf=True) == math.inf
    with pytest.raises(InputError, match="--f: infinity"):
        units.parse_length("inf", "--f")


@pytest.mark.parametrize(
    "text, why",
    [
        ("4", "no unit"),
        ("4xm", "unknown unit"),
        ("-4mm", "positive"),
        ("0nm", "positive"),
        ("nan", "not a length"),
        ("nanmm", "not a length"),
        ("", "not a length"),
    ],
)
def test_bad_lengths_name_the_field_and_form(text, why):
    with pytest.raises(InputError) as info:
        units.parse_length(text, "--lambda-d")
    message = str(info.value)
    assert message.startswith("--lambda-d:") and why in message and "e.g. 4mm" in message
    assert "\n" not in message


def test_range_is_inclusive():
    values = units.parse_range("430:645:5nm", "--wavelengths")
    assert len(values) == 44 and values[0] == 430e-9 and values[-1] == 645e-9
    assert units.parse_length_list("430nm:440nm:5nm", "-w") == [430e-9, 435e-9, 440e-9]


def test_lists_mix_values_and_ranges():
    assert units.parse_length_list("45mm,inf", "--depths", allow_inf=True) == [0.045, math.inf]
    assert units.parse_length_list("400nm,500:510:10nm", "-w") == [400e-9, 500e-9, 510e-9]


def test_bad_ranges():
    with pytest.raises(InputError, match="ends before"):
        units.parse_range("645:430:5nm", "-w")
    with pytest.raises(InputError, match="empty item"):
        units.parse_length_list("45mm,,inf", "-d", allow_inf=True)
    with pytest.raises(InputError, match="at most"):
        units.parse_range("1:1000000:1nm", "-w")


def test_interval():
    assert units.parse_interval("40mm:50mm", "--z-near") == (0.04, 0.05)
    assert units.parse_interval("40:50mm", "--z-near") == (0.04, 0.05)
    assert units.parse_interval("45mm", "--z-near") == (0.045, 0.045)
    with pytest.raises(InputError, match="upper end"):
        units.parse_interval("50mm:40mm", "--z-near")


def test_format_length():
    assert units.format_length(4e-3) == "4 mm"
    assert units.format_length(1.85e-6) == "1.85 µm"
    assert units.format_length(math.inf) == "inf"


def test_spaces_separate_a_number_from_its_unit_but_never_split_it():
    assert units.parse_length(" 1 mm ", "x") == 1e-3
    assert units.parse_length_list("430 : 440 : 5nm", "x") == [430e-9, 435e-9, 440e-9]
    for text in ("4 5mm", "6 00nm", "1.8 5um"):
        with pytest.raises(InputError, match="is not a length"):
            units.parse_length(text, "x")


@pytest.mark.parametrize(
    "text, seconds",
    [
        ("90s", 90.0),
        ("90", 90.0),
        ("30min", 1800.0),
        ("1.5h", 5400.0),
        ("2d", 172800.0),
        (" 2 h ", 7200.0),
        ("inf", math.inf),
    ],
)
def test_durations(text, seconds):
    assert units.parse_duration(text, "--max-time") == seconds


@pytest.mark.parametrize("text", ["", "h", "2 hours", "0s", "-1h", "1e400s", "nan", "2H"])
def test_bad_durations_name_the_field_and_form(text):
    with pytest.raises(InputError, match=r"--max-time: .*") as info:
        units.parse_duration(text, "--max-time")
    assert "90s, 30min or 2h" in info.value.expected


def test_height_ranges_may_start_on_the_axis():
    """``0:40:10um`` as ``0um,10um,…,40um`` (a single ``0um`` was accepted, its range refused);
    a zero step or stop is still refused."""
    assert units.parse_height_list("0:40:10um", "--field-heights") == pytest.approx([0, 10e-6, 20e-6, 30e-6, 40e-6])
    assert units.parse_height_list("0um:0.2mm:100um", "--field-heights") == pytest.approx([0, 100e-6, 200e-6])
    for bad in ("0:40:0um", "-10:40:10um"):
        with pytest.raises(InputError, match="--field-heights"):
            units.parse_height_list(bad, "--field-heights")
