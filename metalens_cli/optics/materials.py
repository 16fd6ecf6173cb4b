"""Optical materials: the complex refractive index n + ik of the nanofin and its substrate.

Conventions, as in :mod:`metalens_cli.optics.lens`: fields vary in time as exp(−iωt), so a plane
wave in a medium is exp(i(ñ·k₀·z − ωt)) with ñ = n + ik, and an absorbing medium has k > 0 (its
amplitude decays as exp(−k·k₀·z)); the relative permittivity is ε = ñ² = ε₁ + iε₂ with ε₂ ≥ 0.
Wavelengths are vacuum wavelengths in SI metres at every interface; the dispersion formulas of
the literature take micrometres or electron-volts, converted inside each model.

Every material is an immutable object with a ``name``, a ``source`` (the publication, or
``"user"``), the wavelength range ``valid_m`` over which its model holds (``None``: every
wavelength), and ``index(wavelengths_m)``: complex128 of the input's shape, refusing wavelengths
outside that range, and values that are no refractive index (n ≤ 0; n < 1 for the models of
transparent dielectrics, Cauchy and Sellmeier), with :class:`InputError`. ``describe()`` gives
a JSON-able summary.

Models: :class:`Constant`, :class:`Cauchy`, :class:`Sellmeier`, :class:`Tabulated` (linear in
wavelength) and :class:`TaucLorentz` (amorphous semiconductors). Built-ins, by lower-case name,
are in :data:`BUILTIN`. This module reads no files: user tables are parsed by
:mod:`metalens_cli.io.materials`. numpy only.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from metalens_cli.errors import InputError

HC_EV_M = 6.62607015e-34 * 299792458.0 / 1.602176634e-19
"""h·c/e in eV·m (exact SI values): photon energy E[eV] = HC_EV_M / λ[m]."""

RANGE_SLACK = 1e-9
"""Relative slack of the valid-range check, so that a wavelength one rounding error beyond a
range's end (``700 * 1e-9`` against a table ending at ``700e-9``) is accepted; a table is flat
(its end value) within it."""

_UM = 1e-6
_FIELD = "material"  # field of the errors raised while building a model; io relabels it


def _nm(value_m: float) -> str:
    return f"{value_m * 1e9:.6g}"


def _finite(value, what: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise InputError(_FIELD, f"{what} {value!r} is not a number", "finite real numbers") from None
    if not math.isfinite(number):
        raise InputError(_FIELD, f"{what} {value!r} is not finite", "finite real numbers")
    return number


def _check_range(valid_m) -> tuple[float, float] | None:
    if valid_m is None:
        return None
    try:
        lo, hi = (float(v) for v in valid_m)
    except (TypeError, ValueError):
        raise InputError(_FIELD, f"valid range {valid_m!r} is not two numbers", "(lo, hi) in metres") from None
    if not (0 < lo < hi and math.isfinite(hi)):
        raise InputError(_FIELD, f"valid range {lo:g}-{hi:g} m is empty or not positive", "0 < lo < hi, in metres")
    return lo, hi


class Material(ABC):
    """A material's complex refractive index n + ik (k ≥ 0 absorbing, exp(−iωt)) versus vacuum
    wavelength in metres. Subclasses are frozen dataclasses with fields ``name`` and ``source``
    and implement ``_index`` (on a 1-D array of checked wavelengths) and ``_parameters``."""

    kind: ClassVar[str]
    transparent: ClassVar[bool] = False  # a model of a transparent dielectric (Cauchy, Sellmeier): n ≥ 1 where used
    name: str
    source: str
    valid_m: tuple[float, float] | None  # (lo, hi) in metres, inclusive; None: every wavelength

    @abstractmethod
    def _index(self, wavelengths_m: np.ndarray) -> np.ndarray:
        """n + ik at a 1-D array of positive wavelengths (metres) inside ``valid_m``."""

    @abstractmethod
    def _parameters(self) -> dict[str, Any]:
        """The model's parameters, JSON-able."""

    def index(self, wavelengths_m, field: str = "wavelength") -> np.ndarray:
        """n + ik (complex128, the shape of ``wavelengths_m``) at vacuum wavelengths in metres.

        Raises :class:`InputError` naming ``field`` for a wavelength that is not positive and
        finite or lies outside ``valid_m``, and where a user model gives no refractive index
        (n ≤ 0, or n² ≤ 0 in a Sellmeier model) or, for a model of a transparent dielectric, n < 1
        (a lossless index below vacuum's: a fit used beyond the wavelengths it was made for)."""
        lam = np.asarray(wavelengths_m, dtype=np.float64)
        flat = lam.ravel()
        if flat.size == 0:
            return np.zeros(lam.shape, dtype=np.complex128)
        bad = ~(np.isfinite(flat) & (flat > 0))
        if bad.any():
            value = flat[np.argmax(bad)]
            raise InputError(field, f"{value!r} m is not a wavelength", "positive, finite wavelengths in metres")
        valid = self.valid_m
        if valid is not None:
            lo, hi = valid
            # inclusive, with a relative slack of RANGE_SLACK for rounding (700 * 1e-9 > 700e-9)
            outside = (flat < lo * (1 - RANGE_SLACK)) | (flat > hi * (1 + RANGE_SLACK))
            if outside.any():
                value = flat[np.argmax(outside)]
                raise InputError(
                    field,
                    f"{_nm(value)} nm is outside the range of {self.name} ({self._cited()})",
                    f"wavelengths within {_nm(lo)}-{_nm(hi)} nm",
                )
        out = np.asarray(self._index(flat), dtype=np.complex128)
        wrong = ~(np.isfinite(out) & ((out.real >= 1) if self.transparent else (out.real > 0)))
        if wrong.any():
            i = int(np.argmax(wrong))
            what = " of a transparent dielectric" if self.transparent else ""
            raise InputError(
                field,
                f"{self.name} gives n = {out[i]:.4g} at {_nm(flat[i])} nm, not a refractive index{what}",
                f"wavelengths where the model gives n {'≥ 1' if self.transparent else '> 0'}",
            )
        return out.reshape(lam.shape)

    def permittivity(self, wavelengths_m, field: str = "wavelength") -> np.ndarray:
        """Relative permittivity ε = (n + ik)² (complex128, ε₂ ≥ 0 absorbing), as :meth:`index`."""
        return self.index(wavelengths_m, field) ** 2

    def describe(self) -> dict[str, Any]:
        """JSON-able summary: kind, name, parameters, source and valid range in metres (null:
        every wavelength)."""
        valid = self.valid_m
        return {
            "kind": self.kind,
            "name": self.name,
            "parameters": self._parameters(),
            "source": self.source,
            "valid_m": None if valid is None else [valid[0], valid[1]],
        }

    def _cited(self) -> str:
        return self.source if len(self.source) <= 60 else self.source[:57] + "…"


@dataclass(frozen=True)
class Constant(Material):
    """A non-dispersive index ``n`` (complex: n + ik with n > 0, k ≥ 0), valid at every wavelength."""

    n: complex
    name: str = field(default="constant", kw_only=True)
    source: str = field(default="user", kw_only=True)
    valid_m: ClassVar[None] = None
    kind: ClassVar[str] = "constant"

    def __post_init__(self):
        try:
            n = complex(self.n)
        except (TypeError, ValueError):
            raise InputError(_FIELD, f"{self.n!r} is not a number", "a refractive index n + ik") from None
        if not (math.isfinite(n.real) and math.isfinite(n.imag)):
            raise InputError(_FIELD, f"index {n} is not finite", "a finite refractive index n + ik")
        if not n.real > 0:
            raise InputError(_FIELD, f"index {n} has n <= 0", "n > 0")
        if n.imag < 0:
            raise InputError(_FIELD, f"index {n} has k < 0 (gain)", "k >= 0 (absorbing, exp(-iωt) convention)")
        object.__setattr__(self, "n", n)

    def _index(self, wavelengths_m):
        return np.full(wavelengths_m.shape, self.n, dtype=np.complex128)

    def _parameters(self):
        return {"n": self.n.real, "k": self.n.imag}


@dataclass(frozen=True)
class Cauchy(Material):
    """Cauchy's dispersion n(λ) = A + B/λ² + C/λ⁴, λ in µm (B in µm², C in µm⁴), real (k = 0):
    a transparent dielectric, so a wavelength where n < 1 is refused.

    ``valid_m``: the range of the fit the coefficients come from (``None``: unchecked)."""

    a: float
    b: float
    c: float = 0.0
    valid_m: tuple[float, float] | None = field(default=None, kw_only=True)
    name: str = field(default="cauchy", kw_only=True)
    source: str = field(default="user", kw_only=True)
    kind: ClassVar[str] = "cauchy"
    transparent: ClassVar[bool] = True

    def __post_init__(self):
        a, b, c = (
            _finite(v, f"Cauchy coefficient {label}") for v, label in ((self.a, "A"), (self.b, "B"), (self.c, "C"))
        )
        if not a > 0:
            raise InputError(
                _FIELD, f"Cauchy coefficient A = {a:g} is not positive", "A > 0 (the index at long wavelengths)"
            )
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "valid_m", _check_range(self.valid_m))

    def _index(self, wavelengths_m):
        inv2 = (wavelengths_m / _UM) ** -2
        return self.a + self.b * inv2 + self.c * inv2 * inv2

    def _parameters(self):
        return {"A": self.a, "B_um2": self.b, "C_um4": self.c}


@dataclass(frozen=True)
class Sellmeier(Material):
    """Sellmeier's dispersion n² = 1 + Σᵢ Bᵢ λ²/(λ² − Cᵢ), λ in µm, Cᵢ in µm² (real, k = 0:
    a transparent dielectric, so a wavelength where n < 1 is refused).

    ``b``, ``c``: the coefficients, equal lengths; ``valid_m``: (lo, hi) in metres, the range of
    the data the coefficients were fitted to, which must hold no pole (λ² = Cᵢ)."""

    b: tuple[float, ...]
    c: tuple[float, ...]
    valid_m: tuple[float, float]
    name: str = field(default="sellmeier", kw_only=True)
    source: str = field(default="user", kw_only=True)
    kind: ClassVar[str] = "sellmeier"
    transparent: ClassVar[bool] = True

    def __post_init__(self):
        b = tuple(_finite(v, "Sellmeier coefficient B") for v in self.b)
        c = tuple(_finite(v, "Sellmeier coefficient C") for v in self.c)
        if not b or len(b) != len(c):
            raise InputError(
                _FIELD, f"{len(b)} B and {len(c)} C coefficients", "as many B as C coefficients, at least one"
            )
        if any(v < 0 for v in c):
            raise InputError(
                _FIELD, "a Sellmeier C coefficient is negative", "C_i >= 0 (µm², the square of a resonance wavelength)"
            )
        valid = _check_range(self.valid_m)
        if valid is None:
            raise InputError(_FIELD, "a Sellmeier model needs its valid range", "(lo, hi) in metres")
        for v in c:
            if valid[0] <= math.sqrt(v) * _UM <= valid[1]:
                raise InputError(
                    _FIELD, f"the pole at {math.sqrt(v) * 1e3:.6g} nm lies in the valid range", "a range free of poles"
                )
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "valid_m", valid)

    def _index(self, wavelengths_m):
        lam2 = (wavelengths_m / _UM) ** 2
        n2 = 1.0 + sum(bi * lam2 / (lam2 - ci) for bi, ci in zip(self.b, self.c))
        # n² ≤ 0 has no real index: NaN, which index() refuses
        return np.sqrt(np.where(n2 > 0, n2, np.nan))

    def _parameters(self):
        return {"B": list(self.b), "C_um2": list(self.c)}


@dataclass(frozen=True, eq=False)
class Tabulated(Material):
    """n and k tabulated at strictly increasing wavelengths (metres), interpolated linearly in
    wavelength (n and k separately); wavelengths outside the table are refused.

    Checked on construction (:class:`InputError`): 1-D arrays of one length, at least 2 points,
    finite, wavelengths positive and strictly increasing, n > 0, k ≥ 0 (``k=None``: 0). Stored as
    read-only float64 arrays."""

    wavelengths_m: np.ndarray
    n: np.ndarray
    k: np.ndarray | None = None
    name: str = field(default="table", kw_only=True)
    source: str = field(default="user", kw_only=True)
    valid_m: tuple[float, float] = field(init=False, default=None)  # the table's first and last wavelengths
    kind: ClassVar[str] = "tabulated"

    def __post_init__(self):
        columns = []
        for label, values in (
            ("wavelengths", self.wavelengths_m),
            ("n", self.n),
            ("k", np.zeros(np.shape(self.n)) if self.k is None else self.k),
        ):
            try:
                array = np.array(values, dtype=np.float64)
            except (TypeError, ValueError):
                raise InputError(_FIELD, f"table {label} are not numbers", "real numbers") from None
            if array.ndim != 1:
                raise InputError(_FIELD, f"table {label} have shape {array.shape}", "1-D columns")
            if not np.isfinite(array).all():
                raise InputError(_FIELD, f"table {label} are not all finite", "finite numbers")
            array.setflags(write=False)
            columns.append(array)
        lam, n, k = columns
        if not (len(lam) == len(n) == len(k)):
            raise InputError(
                _FIELD, f"{len(lam)} wavelengths, {len(n)} n and {len(k)} k values", "one n and k per wavelength"
            )
        if len(lam) < 2:
            raise InputError(_FIELD, f"{len(lam)} table rows", "at least 2 rows")
        if not lam[0] > 0:
            raise InputError(_FIELD, f"table wavelength {lam[0]!r} m is not positive", "positive wavelengths")
        steps = np.diff(lam) <= 0
        if steps.any():
            i = int(np.argmax(steps)) + 1
            raise InputError(
                _FIELD,
                f"table wavelengths not strictly increasing at {_nm(lam[i])} nm",
                "one row per wavelength, ascending",
            )
        if not (n > 0).all():
            i = int(np.argmax(~(n > 0)))
            raise InputError(_FIELD, f"n = {n[i]:g} at {_nm(lam[i])} nm", "n > 0")
        if not (k >= 0).all():
            i = int(np.argmax(~(k >= 0)))
            raise InputError(
                _FIELD, f"k = {k[i]:g} at {_nm(lam[i])} nm (gain)", "k >= 0 (absorbing, exp(-iωt) convention)"
            )
        object.__setattr__(self, "wavelengths_m", lam)
        object.__setattr__(self, "n", n)
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "valid_m", (float(lam[0]), float(lam[-1])))

    def _index(self, wavelengths_m):
        n = np.interp(wavelengths_m, self.wavelengths_m, self.n)
        k = np.interp(wavelengths_m, self.wavelengths_m, self.k)
        return n + 1j * k

    def _parameters(self):
        return {"points": int(len(self.wavelengths_m)), "absorbing": bool((self.k > 0).any())}


@dataclass(frozen=True)
class TaucLorentz(Material):
    """The Tauc–Lorentz dielectric function of amorphous semiconductors (G. E. Jellison Jr. and
    F. A. Modine, Appl. Phys. Lett. 69, 371 (1996); erratum 69, 2137 (1996)). Photon energy E in eV:

        ε₂(E) = A·E₀·C·(E − E_g)² / [((E² − E₀²)² + C²E²)·E]   for E > E_g,  0 for E ≤ E_g,

    and ε₁ = ε₁(∞) + (2/π)·P∫_{E_g}^∞ ξ·ε₂(ξ)/(ξ² − E²) dξ, evaluated in Jellison and Modine's
    closed form (:meth:`eps1`). ``a_ev`` (A, eV), ``e0_ev`` (peak transition energy E₀),
    ``c_ev`` (broadening C, below √2·E₀ for the closed form), ``eg_ev`` (Tauc gap E_g),
    ``eps_inf`` (ε₁(∞)); ``valid_m``: (lo, hi) in metres. No absorption below the gap (no Urbach tail).
    """

    a_ev: float
    e0_ev: float
    c_ev: float
    eg_ev: float
    eps_inf: float
    valid_m: tuple[float, float]
    name: str = field(default="tauc-lorentz", kw_only=True)
    source: str = field(default="user", kw_only=True)
    kind: ClassVar[str] = "tauc-lorentz"

    def __post_init__(self):
        values = {}
        for label in ("a_ev", "e0_ev", "c_ev", "eg_ev", "eps_inf"):
            values[label] = _finite(getattr(self, label), f"Tauc-Lorentz {label}")
            object.__setattr__(self, label, values[label])
        if not all(values[label] > 0 for label in ("a_ev", "e0_ev", "c_ev", "eg_ev")):
            raise InputError(_FIELD, "Tauc-Lorentz A, E0, C and Eg must be positive", "positive energies in eV")
        if not values["c_ev"] < math.sqrt(2.0) * values["e0_ev"]:
            raise InputError(_FIELD, "Tauc-Lorentz C >= sqrt(2)·E0", "C < sqrt(2)·E0 (an underdamped oscillator)")
        valid = _check_range(self.valid_m)
        if valid is None:
            raise InputError(_FIELD, "a Tauc-Lorentz model needs its valid range", "(lo, hi) in metres")
        object.__setattr__(self, "valid_m", valid)

    def eps2(self, energy_ev) -> np.ndarray:
        """ε₂ at photon energies in eV (any shape)."""
        e = np.asarray(energy_ev, dtype=np.float64)
        a, e0, c, eg = self.a_ev, self.e0_ev, self.c_ev, self.eg_ev
        above = e > eg
        x = np.where(above, e, 2.0 * eg + 1.0)  # a harmless stand-in where ε₂ = 0
        value = a * e0 * c * (x - eg) ** 2 / (((x * x - e0 * e0) ** 2 + c * c * x * x) * x)
        return np.where(above, value, 0.0)

    def eps1(self, energy_ev) -> np.ndarray:
        """ε₁ at photon energies in eV (any shape, E > 0): Jellison and Modine's closed form of the
        Kramers–Kronig integral of :meth:`eps2` (as corrected in their erratum)."""
        e = np.asarray(energy_ev, dtype=np.float64)
        a, e0, c, eg = self.a_ev, self.e0_ev, self.c_ev, self.eg_ev
        alpha = math.sqrt(4.0 * e0 * e0 - c * c)
        gamma2 = e0 * e0 - c * c / 2.0
        e2 = e * e
        zeta4 = (e2 - gamma2) ** 2 + alpha * alpha * c * c / 4.0  # = (E² − E₀²)² + C²E²
        a_ln = (eg * eg - e0 * e0) * e2 + eg * eg * c * c - e0 * e0 * (e0 * e0 + 3.0 * eg * eg)
        a_atan = (e2 - e0 * e0) * (e0 * e0 + eg * eg) + eg * eg * c * c
        term_ln = (
            a
            * c
            * a_ln
            / (2.0 * math.pi * zeta4 * alpha * e0)
            * math.log((e0 * e0 + eg * eg + alpha * eg) / (e0 * e0 + eg * eg - alpha * eg))
        )
        term_atan = (
            -a
            * a_atan
            / (math.pi * zeta4 * e0)
            * (math.pi - math.atan((2.0 * eg + alpha) / c) + math.atan((alpha - 2.0 * eg) / c))
        )
        term_gamma = (
            2.0
            * a
            * e0
            * eg
            * (e2 - gamma2)
            / (math.pi * zeta4 * alpha)
            * (math.pi + 2.0 * math.atan(2.0 * (gamma2 - eg * eg) / (alpha * c)))
        )
        # The last two terms of the paper, −(E² + E_g²)/E·ln(|E − E_g|/(E + E_g)) +
        # 2E_g·ln(|E − E_g|(E + E_g)/√((E₀² − E_g²)² + E_g²C²)), regrouped (identically) so that
        # the (E − E_g)²·ln|E − E_g| factor is finite, 0, at E = E_g.
        d = np.abs(e - eg)
        d_log_d = np.where(d > 0, d * d * np.log(np.where(d > 0, d, 1.0)), 0.0)
        s = e + eg
        logs = (-d_log_d + s * s * np.log(s)) / e - eg * math.log((e0 * e0 - eg * eg) ** 2 + eg * eg * c * c)
        term_logs = a * e0 * c / (math.pi * zeta4) * logs
        return self.eps_inf + term_ln + term_atan + term_gamma + term_logs

    def _index(self, wavelengths_m):
        e = HC_EV_M / wavelengths_m
        return np.sqrt(self.eps1(e) + 1j * self.eps2(e))  # principal root: n > 0, k ≥ 0 as ε₂ ≥ 0

    def _parameters(self):
        return {"A_eV": self.a_ev, "E0_eV": self.e0_ev, "C_eV": self.c_ev, "Eg_eV": self.eg_ev, "eps_inf": self.eps_inf}


FUSED_SILICA = Sellmeier(
    (0.6961663, 0.4079426, 0.8974794),
    (0.0684043**2, 0.1162414**2, 9.896161**2),
    (0.21 * _UM, 3.71 * _UM),
    name="fused-silica",
    source="I. H. Malitson, J. Opt. Soc. Am. 55, 1205 (1965)",
)
"""Fused silica at 20 °C: Malitson's three-term Sellmeier fit, 0.21-3.71 µm (n_d = 1.45846)."""

SINX = Sellmeier(
    (3.0249, 40314.0),
    (0.1353406**2, 1239.842**2),
    (0.31 * _UM, 5.504 * _UM),
    name="sinx",
    source="K. Luke et al., Opt. Lett. 40, 4823 (2015)",
)
"""Stoichiometric Si3N4 (LPCVD films): the Sellmeier fit of Luke et al., 0.31-5.504 µm
(n ≈ 1.996 at 1550 nm, 2.056 at 532 nm). PECVD SiNx, as a foundry deposits it for nanofins, has
a composition-dependent index that differs from this by several per cent (usually lower and
with some absorption in the blue): for a real process pass the measured table (CSV) or a Cauchy
fit instead."""

TIO2 = Sellmeier(
    (4.913 - 0.2441 / 0.0803, 0.2441 / 0.0803),
    (0.0, 0.0803),
    (0.43 * _UM, 1.53 * _UM),
    name="tio2",
    source="J. R. DeVore, J. Opt. Soc. Am. 41, 416 (1951) (rutile, ordinary ray)",
)
"""Crystalline rutile TiO2, ordinary ray: DeVore's n_o² = 5.913 + 0.2441/(λ² − 0.0803) (λ in µm),
0.43-1.53 µm (n_o ≈ 2.61 at 589 nm), written as a Sellmeier sum: 5.913 + 0.2441/(λ² − C) =
1 + B₀λ²/(λ² − 0) + B₁λ²/(λ² − C) with B₀ = 4.913 − 0.2441/C and B₁ = 0.2441/C, identical for
every λ. Rutile is birefringent and denser than the films used for visible metasurfaces: ALD
amorphous TiO2 has n ≈ 2.4 at 530 nm, clearly lower; use a measured table or a Cauchy fit of
the film for design work."""

A_SI = TaucLorentz(
    122.0,
    3.45,
    2.54,
    1.20,
    1.15,
    (0.2 * _UM, 2.0 * _UM),
    name="a-si",
    source="G. E. Jellison Jr. and F. A. Modine, Appl. Phys. Lett. 69, 371 (1996), a-Si Tauc-Lorentz fit",
)
"""Amorphous silicon: the Tauc–Lorentz parameters Jellison and Modine fitted to a-Si (A = 122 eV,
E₀ = 3.45 eV, C = 2.54 eV, E_g = 1.20 eV, ε₁(∞) = 1.15). Absorbing in the visible (k ≈ 0.5 at
600 nm); k = 0 beyond the Tauc gap (λ > 1033 nm), where real films keep a weak Urbach tail.
Valid range chosen here as 0.2-2 µm: the fit covered the interband region (visible to near UV),
beyond it the model is an extrapolation. Deposited a-Si(:H) varies with hydrogen content."""

AIR = Constant(1.0, name="air", source="n = 1 (vacuum; air's n − 1 ≈ 2.7e-4 in the visible is neglected)")

BUILTIN: dict[str, Material] = {
    "fused-silica": FUSED_SILICA,
    "sinx": SINX,
    "tio2": TIO2,
    "a-si": A_SI,
    "air": AIR,
    "vacuum": Constant(1.0, name="vacuum", source="n = 1 (vacuum)"),
}
"""Built-in materials by lower-case name (objects are immutable: share them)."""
