"""Parse lengths typed by users (``4mm``, ``450nm``, ``1.85um``, ``inf``) into SI metres, and
durations (``90s``, ``30min``, ``2h``, ``1d``, ``inf``) into seconds.

Grammar (whitespace ignored, units case-sensitive as written below):

- a length: ``NUMBER UNIT`` with UNIT one of ``pm nm um µm μm mm cm m km``, or ``inf``
  where infinity is allowed; NUMBER is written with ASCII digits (``4``, ``1.85``, ``.5``,
  ``1e3``);
- a list: lengths separated by commas (``45mm,inf``), at most :data:`MAX_LIST_VALUES` values
  in all;
- a range: ``START:STOP:STEP UNIT`` (``430:645:5nm``, inclusive end) or with a unit on
  every part (``40mm:50mm`` is a two-value interval, see :func:`parse_interval`).

Lengths must be finite-or-inf, positive and non-zero. A length is the float nearest to the
decimal value typed (``1.1nm == 1.1e-09``, ``395nm == 3.95e-07``), and each value of a range
is the float nearest to the exact decimal ``START + i·STEP``, so ``430:645:5nm`` holds the
same floats as typing ``430nm,435nm,…,645nm``. Pure Python: no numpy, so that commands which
only need closed forms start fast.
"""

from __future__ import annotations

import math
import re

from metalens_cli import arguments
from metalens_cli.errors import InputError

# Decimal exponent of each unit: a length is scaled by shifting its decimal exponent, then
# rounded once to the nearest float (395nm == 3.95e-07, 1.1nm == 1.1e-09).
UNIT_EXPONENTS = {
    "pm": -12,
    "nm": -9,
    "um": -6,
    "µm": -6,  # micro sign U+00B5
    "μm": -6,  # Greek mu U+03BC
    "mm": -3,
    "cm": -2,
    "m": 0,
    "km": 3,
}
UNITS_M = {unit: 10.0**exp for unit, exp in UNIT_EXPONENTS.items()}

# ASCII digits only: ``\d`` would also take Arabic-Indic or full-width digits. Each digit can
# be matched one way only (not ``\d+\.?\d*``, which backtracks quadratically on a long run of
# digits without a unit).
_NUMBER = r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?"
_NUMBER_PARTS_RE = re.compile(r"([+-]?)([0-9]*)(?:\.([0-9]*))?(?:[eE]([+-]?)([0-9]+))?")
_LENGTH_RE = re.compile(rf"({_NUMBER})\s*([a-zµμ]+)")
_RANGE_RE = re.compile(rf"({_NUMBER})([a-zµμ]*):({_NUMBER})([a-zµμ]*):({_NUMBER})\s*([a-zµμ]+)")

LENGTH_FORM = "a number with a unit (pm, nm, um, µm, mm, cm, m, km), e.g. 4mm or 450nm"
LENGTH_OR_INF_FORM = LENGTH_FORM + ", or inf"
LIST_FORM = "lengths with units separated by commas (45mm,inf) or a range START:STOP:STEP with a unit (430:645:5nm)"
INTERVAL_FORM = "a length (45mm) or an interval LO:HI with units (40mm:50mm)"

# Guard against a range or list that would expand into an absurd number of values.
MAX_RANGE_VALUES = 100_000
MAX_LIST_VALUES = MAX_RANGE_VALUES
# The start, stop and step of a range are computed with exactly; more significant digits than
# this (a float has 17) would only make that arithmetic slow.
MAX_RANGE_DIGITS = 40
# An exponent with more digits than this is out of float range whatever its mantissa (which
# would need as many digits to compensate), so it is clamped instead of converted to int.
_MAX_EXPONENT_DIGITS = 15


def _expected(allow_inf: bool) -> str:
    return LENGTH_OR_INF_FORM if allow_inf else LENGTH_FORM


def _quote(text) -> str:
    """``repr`` of the user's text (one line), shortened when it is long."""
    s = str(text)
    return repr(s) if len(s) <= 60 else f"{s[:50]!r}… ({len(s)} characters)"


def _decimal(number: str, unit: str) -> tuple[bool, str, int]:
    """The exact value of ``number`` in ``unit`` as metres: ``(negative, digits, exponent)``
    meaning ``±int(digits)·10**exponent``; ``digits`` has no leading or trailing zeros and is
    empty for zero."""
    m = _NUMBER_PARTS_RE.fullmatch(number)
    assert m is not None  # number matched _NUMBER
    sign, whole, fraction, exp_sign, exp_digits = m.groups(default="")
    exp_digits = (exp_digits or "0").lstrip("0") or "0"
    if len(exp_digits) > _MAX_EXPONENT_DIGITS:
        exp_digits = "1" + "0" * _MAX_EXPONENT_DIGITS
    exponent = (-1 if exp_sign == "-" else 1) * int(exp_digits) - len(fraction) + UNIT_EXPONENTS[unit]
    digits = (whole + fraction).lstrip("0")
    stripped = digits.rstrip("0")
    exponent += len(digits) - len(stripped)
    return sign == "-", stripped, exponent


def _length(number: str, unit: str, text, field: str, allow_inf: bool) -> tuple[float, str, int]:
    """Check and round one length; also returns its exact ``(digits, exponent)``."""
    negative, digits, exponent = _decimal(number, unit)
    if negative or not digits:
        raise InputError(field, f"{_quote(text)} must be positive and non-zero", _expected(allow_inf))
    value = float(f"{digits}e{exponent}")  # correctly rounded, whatever the number of digits
    if math.isinf(value):
        raise InputError(
            field, f"{_quote(text)} overflows (more than {1.7976931348623157e308:.4g} m)", _expected(allow_inf)
        )
    if value == 0.0:
        raise InputError(field, f"{_quote(text)} is too small (it rounds to zero)", _expected(allow_inf))
    return value, digits, exponent


def _parse_length(text, field: str, allow_inf: bool) -> tuple[float, str, int] | None:
    """:func:`parse_length` with the exact decimal of a finite value (``None`` for inf). Spaces
    may separate the number from its unit (``1 mm``), never split the number (``4 5mm``)."""
    s = str(text).strip()
    low = s.lower()
    if low in {"inf", "+inf", "infinity"}:
        if allow_inf:
            return None
        raise InputError(field, "infinity is not allowed here", LENGTH_FORM)
    if "nan" in low or "inf" in low:
        raise InputError(field, f"{_quote(text)} is not a length", _expected(allow_inf))
    m = _LENGTH_RE.fullmatch(s)
    if m is None:
        if re.fullmatch(_NUMBER, s):
            raise InputError(field, f"{_quote(text)} has no unit", _expected(allow_inf))
        raise InputError(field, f"{_quote(text)} is not a length", _expected(allow_inf))
    number, unit = m.groups()
    if unit not in UNITS_M:
        raise InputError(field, f"unknown unit {_quote(unit)} in {_quote(text)}", _expected(allow_inf))
    return _length(number, unit, text, field, allow_inf)


def parse_length(text: str, field: str, *, allow_inf: bool = False) -> float:
    """Parse one length into metres; ``inf`` gives ``math.inf`` where allowed.

    The result is the float nearest to the decimal value typed.

    Args:
        text: a number with a unit (pm, nm, um, µm, mm, cm, m, km), e.g. ``4mm`` or ``450nm``.
        field: the option or TOML key the text came from, named in errors.
        allow_inf: accept ``inf`` (a source at infinity).

    Returns:
        The length in metres, positive and finite, or ``math.inf``.

    Raises:
        InputError: naming ``field``, for a bare number, an unknown unit, NaN, zero, a negative
            value, or a value outside the float range.

    Examples:
        >>> parse_length("450nm", "--wavelength")
        4.5e-07
        >>> parse_length("4 mm", "--focal-length")
        0.004
        >>> parse_length("inf", "--depth", allow_inf=True)
        inf
    """
    parsed = _parse_length(arguments.instance(text, field, str, LENGTH_FORM), field, allow_inf)
    return math.inf if parsed is None else parsed[0]


def _is_zero(number: str) -> bool:
    """Whether a typed number is zero (``0``, ``0.0``, ``+.0``)."""
    return bool(re.fullmatch(r"\+?0*\.?0*", number)) and "0" in number


def _expand_range(text: str, field: str, limit: int, *, zero_start: bool = False) -> list[float]:
    """:func:`parse_range` with at most ``limit`` values; ``zero_start``: START may be zero."""
    # spaces around the colons only; a regex \s*:\s* was quadratic on a long run of spaces
    s = ":".join(part.strip() for part in str(text).strip().split(":"))
    m = _RANGE_RE.fullmatch(s)
    if m is None:
        raise InputError(field, f"{_quote(text)} is not a range", LIST_FORM)
    start_n, start_u, stop_n, stop_u, step_n, unit = m.groups()
    parts = []
    for index, (number, own_unit) in enumerate(((start_n, start_u), (stop_n, stop_u), (step_n, unit))):
        if zero_start and index == 0 and _is_zero(number) and (own_unit or unit) in UNITS_M:
            parts.append((0.0, "0", 0))
            continue
        parsed = _parse_length(number + (own_unit or unit), field, False)
        assert parsed is not None  # allow_inf=False
        if len(parsed[1]) > MAX_RANGE_DIGITS:
            raise InputError(
                field,
                f"range {_quote(text)} has a part with more than {MAX_RANGE_DIGITS} significant digits",
                LIST_FORM,
            )
        parts.append(parsed)
    # Exact integer arithmetic on a common decimal exponent: START = a·10**e, STEP = d·10**e.
    e = min(exponent for _, _, exponent in parts)
    a, b, d = (int(digits) * 10 ** (exponent - e) for _, digits, exponent in parts)
    if b < a:
        raise InputError(field, f"range {_quote(text)} ends before it starts", LIST_FORM)
    count = (b - a) // d + 1
    if count > limit:
        raise InputError(field, f"range {_quote(text)} has too many values (at most {MAX_RANGE_VALUES})", LIST_FORM)
    if e >= 0:
        scale = 10**e
        values = [float((a + i * d) * scale) for i in range(count)]
    else:
        scale = 10**-e
        values = [(a + i * d) / scale for i in range(count)]  # int / int is correctly rounded
    for prev, value in zip(values, values[1:]):
        if value <= prev:
            raise InputError(
                field, f"range {_quote(text)} has a step too small to tell its values apart as floats", LIST_FORM
            )
    return values


def parse_range(text: str, field: str) -> list[float]:
    """Expand ``START:STOP:STEP UNIT`` (inclusive end) into metres.

    The values are ``START + i·STEP`` computed exactly in decimal, each then rounded to the
    nearest float; the stop is included when it lies on the grid.

    Args:
        text: the range; the unit may be given once at the end (``430:645:5nm``) or on every
            part (``430nm:645nm:5nm``).
        field: the option or TOML key the text came from, named in errors.

    Returns:
        The values in metres, ascending; at most :data:`MAX_RANGE_VALUES`.

    Raises:
        InputError: naming ``field``, for a malformed range, a stop below the start, too many
            values, or a step too fine to give distinct floats.

    Examples:
        >>> parse_range("430:450:10nm", "--wavelengths")
        [4.3e-07, 4.4e-07, 4.5e-07]
        >>> parse_range("1mm:2mm:0.5mm", "--depths")
        [0.001, 0.0015, 0.002]
    """
    return _expand_range(arguments.instance(text, field, str, LIST_FORM), field, MAX_RANGE_VALUES)


ZERO_LENGTH = re.compile(r"[+-]?0*\.?0+\s*(pm|nm|um|µm|mm|cm|m)")
SIGNED_LENGTH_FORM = "a length with a unit that may be negative or zero, e.g. 10nm, -5nm or 0nm"


def parse_signed_length(text: str, field: str) -> float:
    """A length that may be negative or zero (a fabrication bias), in metres.

    Examples:
        >>> parse_signed_length("-5nm", "--width-bias"), parse_signed_length("0nm", "--width-bias")
        (-5e-09, 0.0)
    """
    text = arguments.instance(text, field, str, SIGNED_LENGTH_FORM).strip()
    if ZERO_LENGTH.fullmatch(text):
        return 0.0
    sign = -1.0 if text.startswith("-") else 1.0
    try:
        return sign * parse_length(text[1:] if text[:1] in "+-" else text, field)
    except InputError as exc:
        raise InputError(field, exc.message, SIGNED_LENGTH_FORM) from None


def parse_length_list(text: str, field: str, *, allow_inf: bool = False) -> list[float]:
    """Parse a comma-separated list whose items are lengths or ranges, in metres, in the
    order given (at most :data:`MAX_LIST_VALUES` values in all)."""
    text = str(text)
    if text.count(",") >= MAX_LIST_VALUES:
        raise InputError(field, f"{_quote(text)} has more than {MAX_LIST_VALUES} items", LIST_FORM)
    items = [item.strip() for item in text.split(",")]
    if any(not item for item in items):
        raise InputError(field, f"{_quote(text)} has an empty item", LIST_FORM)
    values: list[float] = []
    for item in items:
        if item.count(":") == 2:
            values.extend(_expand_range(item, field, MAX_LIST_VALUES - len(values)))
        elif len(values) >= MAX_LIST_VALUES:
            raise InputError(field, f"{_quote(text)} has more than {MAX_LIST_VALUES} values", LIST_FORM)
        else:
            values.append(parse_length(item, field, allow_inf=allow_inf))
    return values


def parse_height_list(text: str, field: str) -> list[float]:
    """:func:`parse_length_list` that also takes a zero length (``0um``: the axis), e.g. sensor
    heights ``0um,100:500:100um`` → metres."""
    values: list[float] = []
    for item in str(text).split(","):
        m = _LENGTH_RE.fullmatch(item.strip())
        if m is not None and m.group(2) in UNITS_M and _is_zero(m.group(1)):
            values.append(0.0)
        elif item.count(":") == 2:
            values += _expand_range(item, field, MAX_LIST_VALUES - len(values), zero_start=True)
        else:
            values += parse_length_list(item, field)
    return values


def parse_interval(text: str, field: str, *, allow_inf: bool = False) -> tuple[float, float]:
    """Parse ``LO:HI`` (each with a unit) or a single length, returning ``(lo, hi)``."""
    parts = str(text).split(":")
    if len(parts) == 1:
        value = parse_length(parts[0], field, allow_inf=allow_inf)
        return value, value
    if len(parts) != 2:
        raise InputError(field, f"{_quote(text)} is not an interval", INTERVAL_FORM)
    lo_text, hi_text = parts
    # Allow a shared trailing unit: 40:50mm (but not 40:inf, where inf is no unit). Anchored
    # matches only: re.search(r"[a-z]+$") is quadratic on a long run of letters.
    hi_match = _LENGTH_RE.fullmatch(hi_text.strip())
    if hi_match and hi_match.group(2) in UNITS_M and re.fullmatch(_NUMBER, lo_text.strip()):
        lo_text = lo_text.strip() + hi_match.group(2)
    lo = parse_length(lo_text, field, allow_inf=allow_inf)
    hi = parse_length(hi_text, field, allow_inf=allow_inf)
    if hi < lo:
        raise InputError(field, f"interval {_quote(text)} has its upper end below its lower end", INTERVAL_FORM)
    return lo, hi


MIN_DURATION_S = 1e-3  # the shortest limit that means something: estimates are whole milliseconds at best
DURATION_SECONDS = {"": 1.0, "s": 1.0, "min": 60.0, "h": 3600.0, "d": 86400.0}
DURATION_FORM = "a duration in seconds or with a unit (s, min, h, d), e.g. 90s, 30min or 2h, or inf"
_DURATION_RE = re.compile(rf"\s*({_NUMBER})\s*([a-z]*)\s*")


def parse_duration(text: str, field: str) -> float:
    """``90s``, ``30min``, ``2h``, ``1d`` (a bare number is seconds) or ``inf`` → seconds, > 0."""
    if str(text).strip() == "inf":
        return math.inf
    match = _DURATION_RE.fullmatch(str(text))
    if not match or match.group(2) not in DURATION_SECONDS:
        raise InputError(field, f"{_quote(text)} is not a duration", DURATION_FORM)
    seconds = float(match.group(1)) * DURATION_SECONDS[match.group(2)]
    if not 0 < seconds < math.inf:
        raise InputError(field, f"{_quote(text)} is not a positive, finite duration", DURATION_FORM)
    if seconds < MIN_DURATION_S:
        raise InputError(field, f"{_quote(text)} is below {MIN_DURATION_S * 1e3:g} ms", f"{DURATION_FORM}, from 1 ms")
    return seconds


ANGLE_FORM = "an angle with a unit (deg or rad), e.g. 12deg"
_ANGLE_RE = re.compile(rf"\s*({_NUMBER})\s*(deg|rad)\s*")


def parse_angle(text: str, field: str, *, full_circle: bool = False) -> float:
    """Parse one angle, ``12deg`` or ``0.2rad``, into radians.

    Args:
        text: a number with the unit ``deg`` or ``rad``.
        field: the option or TOML key the text came from, named in errors.
        full_circle: accept [0, 2π) (an azimuth) instead of [0, π/2) (a field angle).

    Returns:
        The angle in radians, in [0, π/2), or in [0, 2π) with ``full_circle``.

    Raises:
        InputError: naming ``field``, for a malformed angle or one out of range.

    Examples:
        >>> parse_angle("0.2rad", "--field-angle")
        0.2
        >>> round(parse_angle("12deg", "--field-angle"), 6)
        0.20944
        >>> round(parse_angle("270deg", "--azimuth", full_circle=True), 6)
        4.712389
    """
    match = _ANGLE_RE.fullmatch(arguments.instance(text, field, str, ANGLE_FORM))
    if not match:
        raise InputError(field, f"{_quote(text)} is not an angle", ANGLE_FORM)
    value = float(match.group(1)) * (math.pi / 180 if match.group(2) == "deg" else 1.0)
    top, name = (2 * math.pi, "360") if full_circle else (math.pi / 2, "90")
    if not 0 <= value < top:
        raise InputError(field, f"{_quote(text)} is outside [0, {name}) degrees", ANGLE_FORM)
    return value


ANGLE_LIST_FORM = "angles and ranges with a unit, e.g. 0deg,3deg,6.75deg or 0:6:1.5deg"


def parse_angle_list(text: str, field: str, limit: int = 100) -> list[float]:
    """Comma-separated angles (``6.75deg``) and ranges ``START:STOP:STEP UNIT`` (inclusive end,
    the unit once at the end) → radians in [0, π/2), in the order given, at most ``limit``."""
    values: list[float] = []
    for item in (part.strip() for part in str(text).split(",")):
        if item.count(":") == 2:
            unit_match = re.fullmatch(rf"({_NUMBER}):({_NUMBER}):({_NUMBER})\s*(deg|rad)", item)
            if not unit_match:
                raise InputError(field, f"{_quote(item)} is not a range of angles", ANGLE_LIST_FORM)
            lo, hi, step = (parse_angle(unit_match.group(i) + unit_match.group(4), field) for i in (1, 2, 3))
            if step <= 0 or hi < lo:
                raise InputError(field, f"{_quote(item)} needs a positive step and STOP ≥ START", ANGLE_LIST_FORM)
            count = math.floor((hi - lo) / step * (1 + 1e-12)) + 1
            if len(values) + count > limit:
                raise InputError(field, f"{_quote(text)} has more than {limit} angles", ANGLE_LIST_FORM)
            values += [lo + i * step for i in range(count)]
        else:
            values.append(parse_angle(item, field))
        if len(values) > limit:
            raise InputError(field, f"{_quote(text)} has more than {limit} angles", ANGLE_LIST_FORM)
    return values


def format_length(value_m: float, unit: str = "auto", digits: int = 4) -> str:
    """Render metres for humans: ``0.004`` → ``4 mm``; ``inf`` → ``inf``.

    Args:
        value_m: the length (m), finite or ``inf``.
        unit: ``auto`` (the largest of km, m, mm, µm, nm not above the value; nm below 1 nm) or
            one of :data:`UNITS_M`.
        digits: significant digits, 1-17.

    Returns:
        The number and its unit (``um`` written ``µm``), or ``inf``.

    Examples:
        >>> format_length(0.004)
        '4 mm'
        >>> format_length(532e-9)
        '532 nm'
        >>> format_length(1.5e-6, "nm")
        '1500 nm'
        >>> format_length(0.00412345, digits=2)
        '4.1 mm'
        >>> format_length(float("inf"))
        'inf'
    """
    value_m = arguments.number(value_m, "value_m", allow_inf=True, form="a length in m")
    if unit != "auto" and unit not in UNIT_EXPONENTS:
        raise InputError("unit", f"{unit!r}", "auto or one of " + ", ".join(UNIT_EXPONENTS))
    digits = arguments.count(digits, "digits", hi=17)
    if math.isinf(value_m):
        return "inf"
    if unit == "auto":
        magnitude = abs(value_m)
        for candidate in ("km", "m", "mm", "um", "nm"):
            if magnitude >= UNITS_M[candidate] or candidate == "nm":
                unit = candidate
                break
    return f"{value_m * 10.0 ** -UNIT_EXPONENTS[unit]:.{digits}g} {unit.replace('um', 'µm')}"
