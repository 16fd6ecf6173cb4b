"""Property tests (hypothesis) for the parsers of lengths, lists, ranges and intervals.

Reference values are computed independently of :mod:`metalens_cli.io.units`, with exact
decimal/rational arithmetic (``decimal``, ``fractions``) and Python's correctly rounded
``float(str)``/``float(Fraction)``. The settings below are fixed and database-free
(``derandomize=True``), so every run tries the same examples.
"""

import math
from decimal import Context, Decimal
from fractions import Fraction

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from metalens_cli.errors import InputError
from metalens_cli.io import units

PROPS = settings(max_examples=150, deadline=None, derandomize=True, database=None, print_blob=False)
FEW = settings(PROPS, max_examples=40)

UNITS = sorted(units.UNIT_EXPONENTS)
FIELD = "--some-field"
MAX_FLOAT = 1.7976931348623157e308
EXACT = Context(prec=200, Emax=10**6, Emin=-(10**6))  # exact for the short numbers below

# Round trips through a float formatted in a unit lose at most one rounding on each side:
# |parsed - x| <= (2**-53 + 2**-53 + 2**-106)·|x|; a hair above 2**-52 relative.
REL_TOL = 2**-52 * 1.001

units_st = st.sampled_from(UNITS)
# Floats whose value in every unit (×1e-15 … ×1e12) stays a normal, finite float.
normal_lengths = st.floats(min_value=1e-280, max_value=1e280, allow_nan=False, allow_infinity=False)
# Numbers as users type them (and worse): digits, a point, an exponent, a sign.
number_texts = st.from_regex(r"[+-]?[0-9]{1,25}(\.[0-9]{0,25})?([eE][+-]?[0-9]{1,3})?", fullmatch=True)
# Pieces of the grammar glued at random: near misses reach deeper than st.text().
TOKENS = [
    "0",
    "1",
    "4",
    "9",
    ".",
    "e",
    "E",
    "-",
    "+",
    " ",
    "\t",
    "\n",
    ":",
    ",",
    "inf",
    "Inf",
    "nan",
    "infinity",
    "mm",
    "nm",
    "um",
    "µm",
    "μm",
    "pm",
    "cm",
    "m",
    "km",
    "M",
    "µ",
    "e308",
    "e309",
    "e-324",
    "e-400",
    "e99999999999999999999",
    "1" * 30,
    "0" * 30,
    "5e-324",
    "1.7976931348623157e308",
    "٤",
    "４",
    "\u00a0",
    "\u2028",
    "\x00",
]
grammarish = st.lists(st.sampled_from(TOKENS), max_size=12).map("".join)
hostile = st.one_of(st.text(), grammarish)


def exact_metres(number: str, unit: str) -> Decimal:
    """The exact decimal value of ``number`` ``unit`` in metres."""
    return Decimal(number).scaleb(units.UNIT_EXPONENTS[unit], context=EXACT)


def in_unit(x: float, unit: str) -> str:
    """The exact decimal text of the float ``x`` (metres) expressed in ``unit``."""
    sign, digits, exponent = Decimal(x).as_tuple()
    return str(Decimal((sign, digits, exponent - units.UNIT_EXPONENTS[unit]))) + unit


def outcome(parse, text, **kwargs):
    """The parser's result, or None for an InputError (checked for form); any other
    exception propagates and fails the test."""
    try:
        return parse(text, FIELD, **kwargs)
    except InputError as exc:
        message = str(exc)
        assert exc.field == FIELD and message.startswith(FIELD + ": ") and exc.expected
        assert len(message.splitlines()) == 1 and "\n" not in message
        assert len(message) < 500  # long input is shortened, not echoed whole
        return None


def check_length(value: float, allow_inf: bool):
    assert isinstance(value, float) and not math.isnan(value)
    assert value > 0.0
    assert math.isfinite(value) or (allow_inf and value == math.inf)


# -- single lengths ----------------------------------------------------------------------------


@PROPS
@given(x=normal_lengths, unit=units_st)
def test_round_trip_through_a_float_in_a_unit(x, unit):
    """Formatting x in the unit as a float (repr), then parsing, gives x within ~1 ulp."""
    exponent = units.UNIT_EXPONENTS[unit]
    in_u = x * 10.0**-exponent if exponent < 0 else x / 10.0**exponent  # one rounding: 10**k is exact
    parsed = units.parse_length(f"{in_u!r}{unit}", FIELD)
    assert math.isclose(parsed, x, rel_tol=REL_TOL), (parsed, x)


@PROPS
@given(x=st.floats(min_value=5e-324, max_value=MAX_FLOAT), unit=units_st)
@example(x=5e-324, unit="km")
@example(x=MAX_FLOAT, unit="pm")
def test_round_trip_of_the_exact_decimal_is_exact(x, unit):
    """The exact decimal value of a float, in any unit, parses back to that very float."""
    assert units.parse_length(in_unit(x, unit), FIELD) == x


@PROPS
@given(number=number_texts, unit=units_st, allow_inf=st.booleans())
@example(number="1.1", unit="nm", allow_inf=False)  # was 1.1000000000000001e-09
@example(number="0.01", unit="nm", allow_inf=False)  # was 1.0000000000000001e-11
@example(number="1e-330", unit="km", allow_inf=False)  # rounds to zero
@example(number="1.7976931348623158e308", unit="m", allow_inf=False)  # rounds down to the largest float
def test_a_number_with_a_unit_is_the_nearest_float(number, unit, allow_inf):
    """NUMBER UNIT parses to the float nearest to its exact value in metres, or is refused
    when that is zero, negative, or out of the float range."""
    exact = exact_metres(number, unit)
    nearest = float(exact)
    parsed = outcome(units.parse_length, number + unit, allow_inf=allow_inf)
    if exact > 0 and 0.0 < nearest < math.inf:
        assert parsed == nearest
        assert units.parse_length(f" {number} {unit} ", FIELD) == nearest
    else:
        assert parsed is None


@PROPS
@given(text=hostile, allow_inf=st.booleans())
@example(text="1e99999999999999999999mm", allow_inf=True)
@example(text="1" * 5000 + "nm", allow_inf=False)
@example(text="0." + "0" * 5000 + "1e5000m", allow_inf=False)
@example(text="٤mm", allow_inf=False)
@example(text="-inf", allow_inf=True)
@example(text="nan", allow_inf=True)
@example(text="1e309m", allow_inf=True)
def test_any_text_is_a_positive_length_or_an_input_error(text, allow_inf):
    value = outcome(units.parse_length, text, allow_inf=allow_inf)
    if value is not None:
        check_length(value, allow_inf)


@PROPS
@given(digits=st.text("0123456789", min_size=1, max_size=60), unit=units_st)
def test_ascii_digits_with_a_unit(digits, unit):
    assert outcome(units.parse_length, digits + unit) == (float(exact_metres(digits, unit)) or None)


@pytest.mark.parametrize("text", ["٤mm", "４mm", "1٤mm", "१nm", "1.٥um"])
def test_only_ascii_digits_make_a_number(text):
    """Python's float() would also take digits of other scripts."""
    assert outcome(units.parse_length, text) is None


N = 50_000
LONG_TEXTS = [
    "1" * N,
    "1" * N + "x",
    "1" * N + "e",
    "1" * N + ".",
    "." + "1" * N,
    "1e" + "1" * N,
    "1." + "1" * N + "e1",
    "1:1:" + "1" * N,
    "1" * N + ":1:1",
    "1:" + "1" * N + ":1",
    "1mm:" + "1" * N,
    "1" * N + ":1mm",
    "1" * N + "mm:",
    "1." * N,
    "1e1" * N,
    "1mm" * N,
    ":" * N,
    "1:" * N,
    "1 " * N,
    "1µ" * N,
    "1" * N + "e-" + "0" * N + "1nm",
    "1:" + "m" * N + "1",
    "1:" + "m" * N + "1mm",
    "1" + "\t" * N + "m1",
    "1" + "m" * N + ":1mm:1mm",
]


@pytest.mark.parametrize("text", LONG_TEXTS, ids=lambda t: f"{t[:6]!r}x{len(t)}")
def test_long_text_is_handled_in_linear_time(text):
    """Regexes that could match a run of digits (or letters) in several ways took minutes on
    50 000 characters."""
    import time

    started = time.perf_counter()
    for parse in (units.parse_length, units.parse_length_list, units.parse_interval, units.parse_range):
        outcome(parse, text)
    assert time.perf_counter() - started < 5.0


def test_infinity_only_where_allowed():
    for text in ("inf", "Inf", " +inf ", "infinity"):
        assert units.parse_length(text, FIELD, allow_inf=True) == math.inf
        assert outcome(units.parse_length, text) is None
    for text in ("-inf", "infmm", "1e999m", "inf:inf"):
        assert outcome(units.parse_length, text, allow_inf=True) is None


@FEW
@given(x=normal_lengths)
def test_format_length_round_trips(x):
    """format_length with 17 significant digits (its µm, its space) parses back within ~1 ulp."""
    assert math.isclose(units.parse_length(units.format_length(x, digits=17), FIELD), x, rel_tol=REL_TOL)


# -- ranges ------------------------------------------------------------------------------------


def decimal_text(n: int, places: int) -> str:
    """n·10**-places written in plain decimal (``decimal_text(4305, 1) == '430.5'``)."""
    return str(Decimal(n).scaleb(-places))


@PROPS
@given(
    start=st.integers(1, 10**7),
    step=st.integers(1, 10**5),
    steps=st.integers(0, 300),
    extra=st.floats(0, 1, exclude_max=True),
    places=st.integers(0, 4),
    unit=units_st,
    unit_everywhere=st.booleans(),
)
@example(start=430, step=5, steps=43, extra=0.0, places=0, unit="nm", unit_everywhere=False)
def test_range_values_are_the_grid_as_if_typed(start, step, steps, extra, places, unit, unit_everywhere):
    """a:b:s gives a, a+s, … up to b inclusive, each the float nearest to its exact decimal,
    i.e. exactly what typing that value gives; sorted, strictly increasing, ending at b when
    b−a is a multiple of s and below b otherwise."""
    stop = start + steps * step + int(extra * step)
    a, b, s = (decimal_text(n, places) for n in (start, stop, step))
    text = f"{a}{unit}:{b}{unit}:{s}{unit}" if unit_everywhere else f"{a}:{b}:{s}{unit}"
    values = units.parse_range(text, FIELD)
    assert values == units.parse_length_list(text, FIELD)
    assert len(values) == steps + 1
    assert values == [
        units.parse_length(decimal_text(start + i * step, places) + unit, FIELD) for i in range(steps + 1)
    ]
    assert values[0] == units.parse_length(a + unit, FIELD)
    assert all(p < q for p, q in zip(values, values[1:]))
    last = units.parse_length(b + unit, FIELD)
    assert values[-1] <= last
    assert (values[-1] == last) == (int(extra * step) == 0)


def exact_part(number: str, unit: str) -> Fraction:
    return Fraction(number) * Fraction(10) ** units.UNIT_EXPONENTS[unit]


@PROPS
@given(
    numbers=st.lists(st.from_regex(r"[0-9]{1,6}(\.[0-9]{1,6})?(e-?[0-9])?", fullmatch=True), min_size=3, max_size=3),
    parts_units=st.lists(units_st, min_size=3, max_size=3),
)
@example(numbers=["430", "645", "5"], parts_units=["nm", "um", "pm"])
def test_range_with_a_unit_on_each_part(numbers, parts_units):
    """Against exact rational arithmetic: the values are round(A + i·S) for i = 0 … ⌊(B−A)/S⌋,
    or the range is refused (empty, too long, zero step, steps closer than float resolution)."""
    text = ":".join(n + u for n, u in zip(numbers, parts_units))
    A, B, S = (exact_part(n, u) for n, u in zip(numbers, parts_units))
    values = outcome(units.parse_range, text)
    if A == 0 or B == 0 or S == 0 or B < A or (B - A) / S >= units.MAX_RANGE_VALUES:
        assert values is None
        return
    count = math.floor((B - A) / S) + 1
    # Every value for short ranges; the ends and a sample of the rest for long ones.
    checked = (
        range(count)
        if count <= 1000
        else sorted({*range(20), *range(count - 20, count), *range(0, count, count // 50)})
    )
    expected = [float(A + i * S) for i in checked]
    if len(set(expected)) < len(expected):
        assert values is None  # the step is below float resolution there
    elif values is None:  # only allowed where values left unchecked coincide as floats
        assert count > 1000
        with pytest.raises(InputError, match="step too small to tell its values apart"):
            units.parse_range(text, FIELD)
    else:
        assert len(values) == count
        assert [values[i] for i in checked] == expected
        assert all(p < q for p, q in zip(values, values[1:]))


@PROPS
@given(text=hostile)
@example(text="1:1e300:1e-300m")  # was OverflowError: cannot convert float infinity to integer
@example(text="1m:1.0000000000001m:0.00000000000001m")  # was ten copies of 1.0
@example(text="1.0000000000001m:1.0000000000002m:1m")  # was [1.0], below the start
@example(text="5e-324m:1e308m:5e-324m")
@example(text="1:" + "9" * 5000 + ":1nm")
def test_any_text_is_a_range_or_an_input_error(text):
    values = outcome(units.parse_range, text)
    if values is not None:
        assert 1 <= len(values) <= units.MAX_RANGE_VALUES
        for value in values:
            check_length(value, allow_inf=False)
        assert all(p < q for p, q in zip(values, values[1:]))


@pytest.mark.parametrize(
    "text",
    [
        "1nm:1m:1pm",
        "1:1000000:1nm",
        "1pm:1km:1pm",
        "5e-324m:1.7976931348623157e308m:5e-324m",
        "1:1e300:1e-300m",
        "1e-300m:1m:1e-300m",
    ],
)
def test_huge_ranges_are_refused_before_expanding(text):
    with pytest.raises(InputError, match="at most 100000"):
        units.parse_range(text, FIELD)


@FEW
@given(
    start=st.integers(1, 10**6),
    step=st.integers(1, 10**3),
    unit=units_st,
    bad_step=st.sampled_from(["0", "-1", "-0", "0.0", "-5e-3", "1e-400"]),
)
def test_zero_negative_or_backwards_ranges_are_refused(start, step, unit, bad_step):
    assert outcome(units.parse_range, f"{start}:{start + step}:{bad_step}{unit}") is None
    assert outcome(units.parse_range, f"{start + step}:{start}:{step}{unit}") is None
    assert units.parse_range(f"{start}:{start}:{step}{unit}", FIELD) == [units.parse_length(f"{start}{unit}", FIELD)]


# -- lists -------------------------------------------------------------------------------------

valid_items = st.one_of(
    st.builds(lambda x, u: in_unit(x, u), st.floats(min_value=5e-324, max_value=MAX_FLOAT), units_st),
    st.builds(lambda n, u: f"{n}{u}", st.integers(1, 10**9), units_st),
    st.builds(
        lambda a, k, s, u: f"{a}:{a + k * s}:{s}{u}",
        st.integers(1, 1000),
        st.integers(0, 20),
        st.integers(1, 100),
        units_st,
    ),
    st.just("inf"),
)


@PROPS
@given(
    items=st.lists(valid_items, min_size=1, max_size=8), allow_inf=st.booleans(), pad=st.sampled_from(["", " ", "  "])
)
def test_a_list_is_its_items_in_order(items, allow_inf, pad):
    text = ",".join(pad + item + pad for item in items)
    values = outcome(units.parse_length_list, text, allow_inf=allow_inf)
    if not allow_inf and "inf" in items:
        assert values is None
        return
    expected = []
    for item in items:
        expected += (
            units.parse_range(item, FIELD)
            if item.count(":") == 2
            else [units.parse_length(item, FIELD, allow_inf=True)]
        )
    assert values == expected


@PROPS
@given(text=hostile, allow_inf=st.booleans())
@example(text="45mm,,inf", allow_inf=True)
@example(text="1:100000:1nm,1nm", allow_inf=False)
@example(text="430:inf:5nm", allow_inf=True)
def test_any_text_is_a_list_or_an_input_error(text, allow_inf):
    values = outcome(units.parse_length_list, text, allow_inf=allow_inf)
    if values is not None:
        assert 1 <= len(values) <= units.MAX_LIST_VALUES
        for value in values:
            check_length(value, allow_inf)


def test_list_length_is_bounded():
    with pytest.raises(InputError, match="100000"):
        units.parse_length_list("1:100000:1nm,1nm", FIELD)
    with pytest.raises(InputError, match="100000"):
        units.parse_length_list("1nm,1:100000:1nm", FIELD)
    with pytest.raises(InputError, match="100000"):
        units.parse_length_list(",".join(["1mm"] * 100_001), FIELD)
    assert len(units.parse_length_list("1:99999:1nm,1mm", FIELD)) == 100_000


# -- intervals ---------------------------------------------------------------------------------

interval_ends = st.one_of(st.builds(lambda n, u: f"{n}{u}", number_texts, units_st), st.just("inf"))


@PROPS
@given(lo=interval_ends, hi=interval_ends, allow_inf=st.booleans())
@example(lo="40mm", hi="50mm", allow_inf=False)
def test_an_interval_is_its_two_ends_in_order(lo, hi, allow_inf):
    got = outcome(units.parse_interval, f"{lo}:{hi}", allow_inf=allow_inf)
    ends = [outcome(units.parse_length, end, allow_inf=allow_inf) for end in (lo, hi)]
    if None in ends or ends[1] < ends[0]:
        assert got is None
    else:
        assert got == tuple(ends)


@PROPS
@given(lo=st.integers(1, 10**6), hi=st.integers(1, 10**6), unit=units_st)
def test_an_interval_shares_a_trailing_unit(lo, hi, unit):
    got = outcome(units.parse_interval, f"{lo}:{hi}{unit}")
    assert got == (
        None if hi < lo else (units.parse_length(f"{lo}{unit}", FIELD), units.parse_length(f"{hi}{unit}", FIELD))
    )


@PROPS
@given(text=hostile, allow_inf=st.booleans())
@example(text="40:inf", allow_inf=True)  # was "unknown unit 'inf' in '40inf'"
@example(text="inf:inf", allow_inf=True)
@example(text="1e309m:inf", allow_inf=True)
def test_any_text_is_an_interval_or_an_input_error(text, allow_inf):
    got = outcome(units.parse_interval, text, allow_inf=allow_inf)
    if got is not None:
        lo, hi = got
        check_length(lo, allow_inf)
        check_length(hi, allow_inf)
        assert lo <= hi


def test_messages_are_one_short_line_naming_the_field_and_form():
    for parse, text in [
        (units.parse_length, "1" * 100_000),
        (units.parse_length, "1" + "x" * 10_000),
        (units.parse_length_list, "x\n" * 1000),
        (units.parse_interval, "40mm:\u2028"),
        (units.parse_range, "1:1e300:1e-300m"),
    ]:
        with pytest.raises(InputError) as info:
            parse(text, FIELD)
        message = str(info.value)
        assert message.startswith(FIELD + ": ") and "(expected " in message
        assert len(message.splitlines()) == 1 and len(message) < 500
