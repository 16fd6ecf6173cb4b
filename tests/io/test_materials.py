"""Parsing the material a user names: built-ins, constant indices, Cauchy coefficients, CSV tables."""

import numpy as np
import pytest

from metalens_cli.errors import InputError
from metalens_cli.io.input_files import MAX_TEXT_BYTES
from metalens_cli.io.materials import MATERIAL_FORM, parse_material
from metalens_cli.optics.materials import BUILTIN, Cauchy, Constant, Tabulated

NM = 1e-9
FIELD = "--material"


@pytest.mark.parametrize(
    "text, name",
    [
        ("sinx", "sinx"),
        ("fused-silica", "fused-silica"),
        ("tio2", "tio2"),
        ("a-si", "a-si"),
        ("air", "air"),
        (" SiNx ", "sinx"),
        ("vacuum", "vacuum"),
    ],
)
def test_builtin_names(text, name):
    assert parse_material(text, FIELD) is BUILTIN[name]


@pytest.mark.parametrize(
    "text, index",
    [
        ("2.0", 2.0),
        ("2", 2.0),
        ("2.0+0.01j", 2.0 + 0.01j),
        ("1.5 + 1e-3j", 1.5 + 1e-3j),
        ("2.0+0j", 2.0),
        ("3.5+0.2J", 3.5 + 0.2j),
    ],
)
def test_numbers_are_constant_indices(text, index):
    material = parse_material(text, FIELD)
    assert isinstance(material, Constant)
    assert material.index(532 * NM) == index


@pytest.mark.parametrize(
    "text, coefficients",
    [
        ("cauchy:1.9,0.012", (1.9, 0.012, 0.0)),
        ("cauchy: 1.9, 0.012, 1e-4", (1.9, 0.012, 1e-4)),
        ("Cauchy:1.5,.004", (1.5, 0.004, 0.0)),
    ],
)
def test_cauchy(text, coefficients):
    material = parse_material(text, FIELD)
    assert isinstance(material, Cauchy)
    assert (material.a, material.b, material.c) == coefficients


def write(tmp_path, text, name="film.csv"):
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def test_csv_table_round_trips(tmp_path):
    wavelengths_nm = np.array([400.0, 450.5, 532.0, 700.0])
    n, k = np.array([2.10, 2.07, 2.04, 2.01]), np.array([0.03, 0.01, 0.0, 0.0])
    lines = ["# PECVD SiNx, ellipsometry", "wavelength_nm,n,k"] + [
        f"{w!r},{a!r},{b!r}" for w, a, b in zip(wavelengths_nm.tolist(), n.tolist(), k.tolist())
    ]
    material = parse_material(str(write(tmp_path, "\n".join(lines) + "\n")), FIELD)
    assert isinstance(material, Tabulated)
    assert np.array_equal(material.index(wavelengths_nm / 1e9), n + 1j * k)
    assert material.index(425.25 * NM) == pytest.approx((2.10 + 2.07) / 2 + 0.02j, abs=1e-14)
    assert material.source.endswith("film.csv")


def test_csv_without_k_or_header(tmp_path):
    material = parse_material(str(write(tmp_path, "400,2.0\n\n700,1.9\n")), FIELD)
    assert material.index([400 * NM, 700 * NM]).tolist() == [2.0, 1.9]


@pytest.mark.parametrize(
    "table",
    [
        '"Wavelength",K,N\n400,0.03,2.10\n700,0.0,2.04\n',
        "n,k,wavelength_nm\n2.10,0.03,400\n2.04,0.0,700\n",
        "Wavelength (nm),n,k\n400,2.10,0.03\n700,2.04,0.0\n",
    ],
)
def test_csv_columns_are_read_by_their_header(tmp_path, table):
    """Names in any order and case, quoted or with a unit: each column is what its header says."""
    material = parse_material(str(write(tmp_path, table)), FIELD)
    np.testing.assert_allclose(material.index([400 * NM, 700 * NM]), [2.10 + 0.03j, 2.04], rtol=1e-15)


@pytest.mark.parametrize(
    "header, why",
    [
        ("lam,index", "does not name its columns"),
        ("wavelength_nm,k", "lacks n"),
        ("wavelength_nm,n,n", "does not name its columns"),
        ("wavelength_nm,n,eps2", "does not name its columns"),
    ],
)
def test_a_header_that_does_not_name_the_columns_is_refused(tmp_path, header, why):
    k = ",0.0" if header.count(",") == 2 else ""
    path = write(tmp_path, f"{header}\n400,2.0{k}\n700,1.9{k}\n")
    message = check_one_line_error(str(path), f"film.csv: header {header!r} {why}")
    assert "wavelength_nm: wavelength_nm or wavelength or lambda_nm" in message and "n: n; k (optional): k" in message


@pytest.mark.parametrize(
    ("text", "nm"), [("cauchy:1,-0.2809", 530), ("cauchy:1,-0.2809", 600), ("cauchy:1.5,0.004,-0.001", 200)]
)
def test_a_cauchy_fit_below_vacuums_index_is_refused_where_it_is_used(text, nm):
    """n = A + B/λ² + C/λ⁴: 1 − 0.2809/0.53² = 0 at 530 nm (rounding leaves 2e-16 > 0, which
    n > 0 let through), 0.22 at 600 nm; 1.5 + 0.1 − 0.625 = 0.975 at 200 nm for a fit with
    C < 0 that is fine in the visible. A transparent dielectric has n ≥ 1: refused at those
    wavelengths, naming the option."""
    material = parse_material(text, "--material")
    with pytest.raises(
        InputError,
        match=rf"^--material: {text} gives n = \S+ at {nm} nm, not a refractive index "
        r"of a transparent dielectric \(expected wavelengths where the model gives n ≥ 1\)$",
    ):
        material.index([nm * NM], "--material")
    if text.startswith("cauchy:1.5"):
        assert material.index(500 * NM).real == pytest.approx(1.5 + 0.004 / 0.25 - 0.001 / 0.0625)


def check_one_line_error(text, match, field=FIELD):
    with pytest.raises(InputError) as info:
        parse_material(text, field)
    message = str(info.value)
    assert info.value.field == field and message.startswith(f"{field}: ") and "\n" not in message
    assert match in message, message
    return message


def test_unknown_name_lists_the_accepted_forms():
    message = check_one_line_error("unobtainium", "'unobtainium' is not a material")
    assert message == f"{FIELD}: 'unobtainium' is not a material (expected {MATERIAL_FORM})"
    check_one_line_error("", "no material given", field="lens.material")


@pytest.mark.parametrize(
    "text, match",
    [
        ("2.0-0.1j", "gain"),
        ("0", "n > 0"),
        ("-1.5", "n > 0"),
        ("nan", "not a finite"),
        ("inf", "not a finite"),
        ("2.0+infj", "not a finite"),
        ("1e400", "not a finite"),
        ("0.01j", "not a material"),
    ],
)
def test_bad_numbers(text, match):
    check_one_line_error(text, match)


@pytest.mark.parametrize(
    "text, match",
    [
        ("cauchy:1.5", "1 coefficient"),
        ("cauchy:a,b", "'a' in 'cauchy:a,b' is not a number"),
        ("cauchy:1,2,3,4", "4 coefficients"),
        ("cauchy:", "1 coefficient"),
        ("cauchy:nan,0.01", "is not a number"),
        ("cauchy:-1.5,0.01", "not positive"),
        ("cauchy:1.5,1e999", "out of float range"),
    ],
)
def test_bad_cauchy(text, match):
    assert "cauchy:A,B[,C]" in check_one_line_error(text, match)


@pytest.mark.parametrize(
    "content, match",
    [
        ("wavelength_nm,n,k\nfoo,bar,baz\n", "not a number"),
        ("wavelength_nm,n\n500,2.0\n", "fewer than 2 data rows"),
        ("wavelength_nm,n\n600,2.0\n500,2.1\n", "not strictly increasing"),
        ("wavelength_nm,n\n500,2.0\n500,2.1\n", "not strictly increasing"),
        ("wavelength_nm,n\n400,2.0\n500,-2.1\n", "n = -2.1 at 500 nm"),
        ("wavelength_nm,n,k\n400,2.0,0.0\n500,2.0,-0.01\n", "k = -0.01 at 500 nm"),
        ("wavelength_nm,n,k\n400,2.0,0\n500,2.0\n", "2 columns"),
        ("wavelength_um,n\n0.4,2.0\n0.5,2.1\n", "header 'wavelength_um,n' does not name its columns"),
        ("wavelength_nm,n\n400,nan\n500,2.1\n", "non-finite"),
        ("wavelength_nm\n400\n", "header 'wavelength_nm' lacks n"),
        ("400\n500\n", "1 columns and no header"),
        ("# only a comment\n", "fewer than 2 data rows"),
        (b"\xff\xfe garbage", "not UTF-8"),
    ],
)
def test_bad_csv_tables(tmp_path, content, match):
    path = tmp_path / "bad.csv"
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    check_one_line_error(str(path), match)


def test_missing_and_oversized_csv(tmp_path):
    check_one_line_error(str(tmp_path / "missing.csv"), "no such file")
    check_one_line_error(str(tmp_path), "is a folder")
    big = tmp_path / "big.csv"
    row = "500,2.0\n"
    big.write_text("wavelength_nm,n\n" + row * (MAX_TEXT_BYTES // len(row) + 1))
    check_one_line_error(str(big), "larger than 4 MiB")
