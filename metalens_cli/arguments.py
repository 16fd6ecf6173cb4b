"""Checks of the public API's arguments: the CLI's contract for Python callers.

A public function checks what it is given before any work: a value that is missing (None),
not a number (NaN), infinite where a finite one is needed, out of its range, or a size whose
arrays would not fit in the memory the device has free, is an :class:`InputError` naming the
parameter and the accepted form; a value of the wrong type is a ``TypeError`` naming it. Lengths
are SI metres, angles radians. Pure Python (numpy and torch are imported only to recognise
their scalars and devices).
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Iterable
from typing import Any

from metalens_cli.errors import InputError
from metalens_cli.machine import MEMORY_SHARE, device_memory, format_bytes

DEVICE_FORM = "cpu, cuda, cuda:N or mps (a device this machine has)"
DEVICE_PATTERN = r"cpu|cuda(:\d{1,3})?|mps"


def number(
    value: Any,
    name: str,
    *,
    lo: float | None = None,
    hi: float | None = None,
    open_lo: bool = False,
    open_hi: bool = False,
    allow_inf: bool = False,
    form: str | None = None,
) -> float:
    """``value`` as a float in the range [lo, hi] (ends open as asked; ±inf only with
    ``allow_inf``). A 0-d numpy array or tensor counts as a number."""
    form = form or _range_form(lo, hi, open_lo, open_hi)
    if value is None:
        raise InputError(name, "is None", form)
    if isinstance(value, bool) or not _is_real(value):
        raise TypeError(f"{name}: expected a number ({form}), got {type(value).__name__}")
    x = float(value.detach() if hasattr(value, "detach") else value)  # a learned band edge: its value
    if math.isnan(x):
        raise InputError(name, "is NaN", form)
    if math.isinf(x) and not allow_inf:
        raise InputError(name, f"is {x}", f"a finite number, {form}")
    below = lo is not None and (x <= lo if open_lo else x < lo)
    above = hi is not None and (x >= hi if open_hi else x > hi)
    if below or above:
        raise InputError(name, f"{x:g} is out of range", form)
    return x


def positive(value: Any, name: str, *, allow_inf: bool = False, unit: str = "m") -> float:
    """A number > 0 (a length in metres unless ``unit`` says otherwise)."""
    return number(value, name, lo=0.0, open_lo=True, allow_inf=allow_inf, form=f"a positive number ({unit})")


def count(value: Any, name: str, *, lo: int = 1, hi: int | None = None) -> int:
    """An integer in [lo, hi] (a float that is a whole number is taken)."""
    form = f"an integer ≥ {lo}" if hi is None else f"an integer in [{lo}, {hi}]"
    if value is None:
        raise InputError(name, "is None", form)
    if isinstance(value, bool) or not _is_real(value):
        raise TypeError(f"{name}: expected {form}, got {type(value).__name__}")
    x = float(value)
    if not math.isfinite(x) or x != int(x):
        raise InputError(name, f"{value!r} is not a whole number", form)
    if x < lo or (hi is not None and x > hi):
        raise InputError(name, f"{int(x)} is out of range", form)
    return int(x)


def numbers_of(values: Any, name: str, *, lo=None, open_lo=False, allow_inf=False, form=None) -> list[float]:
    """A non-empty list of numbers (one number is a list of one), each checked as :func:`number`."""
    if values is None:
        raise InputError(name, "is None", form or "a number or a list of numbers")
    items = list(values) if _is_iterable(values) else [values]
    if not items:
        raise InputError(name, "is empty", form or "at least one number")
    return [number(v, name, lo=lo, open_lo=open_lo, allow_inf=allow_inf, form=form) for v in items]


def lengths(values: Any, name: str, *, allow_inf: bool = False) -> list[float]:
    """A non-empty list of positive lengths (m), ``inf`` only with ``allow_inf`` (a far depth)."""
    form = "positive lengths in metres" + (" (inf: infinitely far)" if allow_inf else "")
    return numbers_of(values, name, lo=0.0, open_lo=True, allow_inf=allow_inf, form=form)


def path(value: Any, name: str, form: str = "a file path") -> str:
    """A file path (str or os.PathLike) as a str; None is an InputError, another type a TypeError."""
    import os

    if value is None:
        raise InputError(name, "is None", form)
    if not isinstance(value, (str, os.PathLike)):
        raise TypeError(f"{name}: expected {form}, got {type(value).__name__}")
    text = os.fspath(value)
    if not isinstance(text, str) or not text.strip():
        raise InputError(name, f"{text!r} is empty" if isinstance(text, str) else "is not text", form)
    return text


def interval(value: Any, name: str, *, allow_inf: bool = False) -> tuple[float, float]:
    """A (lo, hi) pair of positive lengths (m) with lo ≤ hi (``inf`` only with ``allow_inf``)."""
    pair = instance(value, name, (tuple, list), "(lo, hi) in m")
    if len(pair) != 2:
        raise InputError(name, f"{pair!r}", "(lo, hi) in m")
    lo, hi = (positive(v, name, allow_inf=allow_inf) for v in pair)
    if hi < lo:
        raise InputError(name, f"{pair!r} ends below its start", "(lo, hi) with lo ≤ hi")
    return lo, hi


def instance(value: Any, name: str, kind: type | tuple[type, ...], form: str) -> Any:
    """``value`` if it is a ``kind``; None is an :class:`InputError`, another type a TypeError."""
    if value is None:
        raise InputError(name, "is None", form)
    if not isinstance(value, kind):
        raise TypeError(f"{name}: expected {form}, got {type(value).__name__}")
    return value


def array(value: Any, name: str, *, ndim: int | tuple[int, ...] | None = None, form: str = "an array") -> Any:
    """A numpy array or tensor of finite numbers (``ndim`` dimensions when given); lists are taken
    as numpy arrays. A tensor that requires grad is an optimiser's own (a NaN there is a training
    failure its loop reports): its values are not read, which would cost a pass and a device sync
    every step."""
    import numpy as np

    if value is None:
        raise InputError(name, "is None", form)
    if isinstance(value, (list, tuple)):
        try:
            value = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            raise TypeError(f"{name}: expected {form}, got a list that is not numbers") from None
    if not hasattr(value, "shape") or not hasattr(value, "dtype"):
        raise TypeError(f"{name}: expected {form}, got {type(value).__name__}")
    dims = (ndim,) if isinstance(ndim, int) else ndim
    if dims is not None and len(value.shape) not in dims:
        raise InputError(name, f"has {len(value.shape)} dimensions, shape {tuple(value.shape)}", form)
    if not getattr(value, "requires_grad", False) and not _all_finite(value):
        raise InputError(name, "holds NaN or infinite values", f"{form} of finite numbers")
    return value


def shaped(value: Any, name: str, *, min_ndim: int = 0, form: str = "an array") -> Any:
    """A numpy array or tensor of at least ``min_ndim`` dimensions, its values unread (for work
    that only slices or reshapes, where a NaN passes through as it came)."""
    if value is None:
        raise InputError(name, "is None", form)
    if not hasattr(value, "shape") or not hasattr(value, "dtype"):
        raise TypeError(f"{name}: expected {form}, got {type(value).__name__}")
    if len(value.shape) < min_ndim:
        raise InputError(name, f"has shape {tuple(value.shape)}", form)
    return value


def same_shape(a: Any, b: Any, names: tuple[str, str]) -> None:
    """Two arrays of one shape."""
    if tuple(a.shape) != tuple(b.shape):
        raise InputError(
            names[1], f"shape {tuple(b.shape)} differs from {names[0]}'s {tuple(a.shape)}", f"the shape of {names[0]}"
        )


def device(value: Any, name: str = "device"):
    """A torch.device this machine has: CUDA or MPS that is not there is an InputError."""
    import torch

    if value is None:
        raise InputError(name, "is None", DEVICE_FORM)
    if isinstance(value, torch.device):
        value = str(value)
    if not isinstance(value, str):
        raise TypeError(f"{name}: expected a device name ({DEVICE_FORM}), got {type(value).__name__}")
    if not re.fullmatch(DEVICE_PATTERN, value):
        raise InputError(name, f"unknown device {value!r}", DEVICE_FORM)
    chosen = torch.device(value)
    if chosen.type == "cuda" and not torch.cuda.is_available():
        raise InputError(name, "CUDA is not available on this machine", "cpu")
    if chosen.type == "cuda" and (chosen.index or 0) >= torch.cuda.device_count():
        raise InputError(
            name, f"{value!r}: this machine has {torch.cuda.device_count()} CUDA device(s)", "cuda:0 … cuda:N-1"
        )
    if chosen.type == "mps" and not torch.backends.mps.is_available():
        raise InputError(name, "MPS is not available on this machine", "cpu")
    return chosen


def fits_in_memory(nbytes: float, name: str, what: str, on_device=None) -> None:
    """Refuse, before allocating, work whose arrays (``nbytes``, from the caller's estimate) would
    take more than the share of memory a job may plan on (``machine.MEMORY_SHARE`` of what
    ``on_device`` has free, as the CLI's checks); ``name`` is the parameter that sizes it."""
    free, which = device_memory(on_device)
    if free is not None and nbytes > MEMORY_SHARE * free:
        raise InputError(
            name,
            f"{what} needs about {format_bytes(nbytes)} of memory; {which} is {format_bytes(free)}",
            f"a smaller {name}",
        )


def _is_real(value: Any) -> bool:
    if isinstance(value, numbers.Real):
        return True
    shape, kind = getattr(value, "shape", None), getattr(getattr(value, "dtype", None), "kind", None)
    if shape == () and kind in ("f", "i", "u"):  # a 0-d numpy array
        return True
    is_floating = getattr(value, "is_floating_point", None)
    return shape is not None and tuple(shape) == () and callable(is_floating) and not value.is_complex()


def _is_iterable(value: Any) -> bool:
    if isinstance(value, (str, bytes)):
        return False
    if getattr(value, "shape", None) == () or (hasattr(value, "shape") and tuple(value.shape) == ()):
        return False
    return isinstance(value, Iterable)


def _all_finite(value: Any) -> bool:
    """Whether every value is finite: first from the sum (one pass, no mask: NaN or ±inf make it
    non-finite), and only when the sum is not finite from the values themselves (a sum can
    overflow on finite values), so large arrays cost a reduction, not a comparison per value."""
    import numpy as np

    if hasattr(value, "is_floating_point"):  # a tensor
        import torch

        if not (value.is_floating_point() or value.is_complex()) or value.numel() == 0:
            return True
        return bool(torch.isfinite(value.sum())) or bool(torch.isfinite(value).all())
    values = np.asarray(value)
    if values.dtype.kind not in "fciu":
        raise TypeError(f"expected numbers, got an array of {values.dtype}")
    if values.dtype.kind in "iu" or values.size == 0:
        return True
    with np.errstate(over="ignore", invalid="ignore"):
        return bool(np.isfinite(values.sum())) or bool(np.isfinite(values).all())


def _range_form(lo, hi, open_lo, open_hi) -> str:
    if lo is None and hi is None:
        return "a number"
    left = "-inf" if lo is None else f"{lo:g}"
    right = "inf" if hi is None else f"{hi:g}"
    return f"a number in {'(' if open_lo or lo is None else '['}{left}, {right}{')' if open_hi or hi is None else ']'}"
