"""Parse lengths typed by users (``4mm``, ``450nm``, ``1.85um``, ``inf``) into SI metres.

Grammar (whitespace ignored, units case-sensitive as written below):

- a length: ``NUMBER UNIT`` with UNIT one of ``pm nm um µm μm mm cm m km``, or ``inf``
  where infinity is allowed;
- a list: lengths separated by commas (``45mm,inf``);
- a range: ``START:STOP:STEP UNIT`` (``430:645:5nm``, inclusive end) or with a unit on
  every part (``40mm:50mm`` is a two-value interval, see :func:`parse_interval`).

Lengths must be finite-or-inf, positive and non-zero. Pure Python: no numpy, so that
commands which only need closed forms start fast.
"""

from __future__ import annotations

import math
import re

from metalens_cli.errors import InputError

# Decimal exponent of each unit; scaling by an exact power of ten keeps 395nm == 3.95e-07.
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


def _scale(number: float, unit: str) -> float:
    exp = UNIT_EXPONENTS[unit]
    return number * 10.0**exp if exp >= 0 else number / 10.0 ** (-exp)


_NUMBER = r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?"
_LENGTH_RE = re.compile(rf"^({_NUMBER})\s*([a-zµμ]+)$")
_RANGE_RE = re.compile(rf"^({_NUMBER})([a-zµμ]*):({_NUMBER})([a-zµμ]*):({_NUMBER})\s*([a-zµμ]+)$")

LENGTH_FORM = "a number with a unit (pm, nm, um, µm, mm, cm, m, km), e.g. 4mm or 450nm"
LENGTH_OR_INF_FORM = LENGTH_FORM + ", or inf"
LIST_FORM = "lengths with units separated by commas (45mm,inf) or a range START:STOP:STEP with a unit (430:645:5nm)"
INTERVAL_FORM = "a length (45mm) or an interval LO:HI with units (40mm:50mm)"

# Guard against a range that would expand into an absurd number of values.
MAX_RANGE_VALUES = 100_000


def _expected(allow_inf: bool) -> str:
    return LENGTH_OR_INF_FORM if allow_inf else LENGTH_FORM


def parse_length(text: str, field: str, *, allow_inf: bool = False) -> float:
    """Parse one length into metres; ``inf`` gives ``math.inf`` where allowed.

    Raises :class:`InputError` naming ``field`` for a bare number, an unknown unit,
    NaN, zero or a negative value.
    """
    s = str(text).strip().replace(" ", "")
    if s.lower() in {"inf", "+inf", "infinity"}:
        if allow_inf:
            return math.inf
        raise InputError(field, "infinity is not allowed here", LENGTH_FORM)
    if s.lower() in {"nan", "-inf"} or "nan" in s.lower():
        raise InputError(field, f"{text!r} is not a length", _expected(allow_inf))
    m = _LENGTH_RE.match(s)
    if m is None:
        if re.fullmatch(_NUMBER, s):
            raise InputError(field, f"{text!r} has no unit", _expected(allow_inf))
        raise InputError(field, f"{text!r} is not a length", _expected(allow_inf))
    number, unit = m.groups()
    if unit not in UNITS_M:
        raise InputError(field, f"unknown unit {unit!r} in {text!r}", _expected(allow_inf))
    value = _scale(float(number), unit)
    if not math.isfinite(value):
        raise InputError(field, f"{text!r} overflows", _expected(allow_inf))
    if value <= 0.0:
        raise InputError(field, f"{text!r} must be positive and non-zero", _expected(allow_inf))
    return value


def parse_range(text: str, field: str) -> list[float]:
    """Expand ``START:STOP:STEP UNIT`` (inclusive end) into metres.

    The unit may be given once at the end (``430:645:5nm``) or on every part
    (``430nm:645nm:5nm``). The stop is included when it lies on the grid to within
    1e-9 of a step.
    """
    s = str(text).strip().replace(" ", "")
    m = _RANGE_RE.match(s)
    if m is None:
        raise InputError(field, f"{text!r} is not a range", LIST_FORM)
    start_n, start_u, stop_n, stop_u, step_n, unit = m.groups()
    parts = []
    for number, own_unit in ((start_n, start_u), (stop_n, stop_u), (step_n, unit)):
        parts.append(parse_length(number + (own_unit or unit), field))
    start, stop, step = parts
    if stop < start:
        raise InputError(field, f"range {text!r} ends before it starts", LIST_FORM)
    count = math.floor((stop - start) / step + 1e-9) + 1
    if count > MAX_RANGE_VALUES:
        raise InputError(field, f"range {text!r} has {count} values (at most {MAX_RANGE_VALUES})", LIST_FORM)
    # Round to 12 significant digits so that 430:645:5nm gives 6.35e-07, not 6.350000000000001e-07.
    return [float(f"{start + i * step:.12g}") for i in range(count)]


def parse_length_list(text: str, field: str, *, allow_inf: bool = False) -> list[float]:
    """Parse a comma-separated list whose items are lengths or ranges, in metres."""
    items = [item.strip() for item in str(text).split(",")]
    if not items or any(not item for item in items):
        raise InputError(field, f"{text!r} has an empty item", LIST_FORM)
    values: list[float] = []
    for item in items:
        if item.count(":") == 2:
            values.extend(parse_range(item, field))
        else:
            values.append(parse_length(item, field, allow_inf=allow_inf))
    return values


def parse_interval(text: str, field: str, *, allow_inf: bool = False) -> tuple[float, float]:
    """Parse ``LO:HI`` (each with a unit) or a single length, returning ``(lo, hi)``."""
    parts = str(text).split(":")
    if len(parts) == 1:
        value = parse_length(parts[0], field, allow_inf=allow_inf)
        return value, value
    if len(parts) != 2:
        raise InputError(field, f"{text!r} is not an interval", INTERVAL_FORM)
    lo_text, hi_text = parts
    # Allow a shared trailing unit: 40:50mm.
    unit_match = re.search(r"[a-zµμ]+$", hi_text.strip())
    if unit_match and re.fullmatch(_NUMBER, lo_text.strip()):
        lo_text = lo_text.strip() + unit_match.group(0)
    lo = parse_length(lo_text, field, allow_inf=allow_inf)
    hi = parse_length(hi_text, field, allow_inf=allow_inf)
    if hi < lo:
        raise InputError(field, f"interval {text!r} has its upper end below its lower end", INTERVAL_FORM)
    return lo, hi


def format_length(value_m: float, unit: str = "auto", digits: int = 4) -> str:
    """Render metres for humans: ``0.004`` → ``4 mm``; ``inf`` → ``inf``."""
    if math.isinf(value_m):
        return "inf"
    if unit == "auto":
        magnitude = abs(value_m)
        for candidate in ("km", "m", "mm", "um", "nm"):
            if magnitude >= UNITS_M[candidate] or candidate == "nm":
                unit = candidate
                break
    return f"{value_m * 10.0 ** -UNIT_EXPONENTS[unit]:.{digits}g} {unit.replace('um', 'µm')}"
