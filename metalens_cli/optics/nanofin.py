"""Conversion efficiency of a rectangular nanofin (the meta-atom) by RCWA.

Two solvers give the same quantities. :func:`fin_response` uses :mod:`metalens_cli.optics.fin_modes`,
this package's RCWA of this one geometry, which splits the eigenproblem by the fin's two
mirror symmetries and batches wavelengths and fins (torch; ``device``; timings in
docs/benchmarks.md). :func:`fin_response_meent` runs the maintained
package meent, the slower reference it is tested against (tests/optics/test_fin_modes.py); the
two agree within 4e-4 on η at N = 21 and converge to the same limit.

Geometry. A square lattice of period p; in each cell a rectangular fin of width w along x and
length l along y, height h, of material ``fin`` surrounded by air, standing on a substrate.
Light arrives at normal incidence from the substrate side and leaves into air (meent's upper
half-space is the substrate, its lower one air). meent builds the permittivity's Fourier
matrices with Li's factorisation rules, which converge for this high-contrast grating where the
plain Laurent rule does not (issue 17); so does fin_modes, which also treats x and y alike.

Jones coefficients. ``t_xx`` is the zeroth transmitted order's x field for x-polarised
incidence, ``t_yy`` likewise for y; both are scaled by √(n_out/n_in) so that |t|² is a fraction
of the incident power. For a fin with its axes on x and y the cross terms vanish. The
geometric-phase (Pancharatnam-Berry) conversion efficiency, the power carried into the
opposite circular polarisation, is η = |t_xx − t_yy|²/4; the co-polarised fraction is
|t_xx + t_yy|²/4; ``transmittance`` T and ``reflectance`` R sum all propagating orders (for
unpolarised light: the mean of the x and y cases). For a lossless fin T + R = 1.

meent's conventions, translated here: fields vary as e^{+iωt} (an absorbing index is n − ik;
this package's, e^{−iωt}, writes n + ik: indices go in conjugated, amplitudes come out
conjugated); at normal incidence with φ = 0 its TE channel is y and its TM channel x, and its
TM amplitudes carry a factor i relative to its TE ones (its p-polarised unit vector), removed
here. The homogeneous layer (w = l = p), where t_xx = t_yy must hold, fixes that sign, and an
absorbing fin losing power fixes the time convention (tests/optics/test_nanofin.py). The
substrate is taken lossless (its real index).

Symmetry. fin_modes converts exactly nothing with a square fin and swaps t_xx and t_yy exactly
for a fin turned by 90°. meent's factorisation does not treat x and y alike at finite N: a square fin
converts 2e-5 at N = 5, 2e-6 at N = 9, 4e-7 at N = 13 (0 in the limit), and turning the paper's
fin by 90° changes η by 5e-3, 2e-3, 1e-3 at N = 5, 9, 13. Both vanish as N grows.

Cost per wavelength on 2 cores: fin_modes solves two eigenproblems of (N² + 1)/2 (real for a
lossless fin): 0.03 s at N = 17, 0.19 s at N = 25; meent one of 2·N²: 1.2 s at N = 17, 9.5 s at
N = 25 (meent 0.13, numpy backend, the fin given as a rectangle rather than a raster).
"""

from __future__ import annotations

import math
import time

import numpy as np

from metalens_cli.arguments import array, instance, lengths
from metalens_cli.arguments import device as checked_device
from metalens_cli.errors import InputError
from metalens_cli.optics.fin import NM, Fin, FinResponse, check_harmonics

SOLVER = "fin_modes/1"  # names the numbers a cache entry holds: change it when they change
SOLVERS = {  # the solvers fin_response takes, as reports name them
    "modes": "fin_modes (this package's RCWA, mirror symmetries, Li's factorisation)",
    "meent": "meent (RCWA, Li's factorisation; the reference)",
}
# fin_modes, one wavelength and fin, both polarisations, on 2 cores: SOLVE_SECONDS + SOLVE_SCALE·u^2.4
# for u = (N² + 1)/2 unknowns (measured N = 5…35: 2.6 ms at N = 9, 0.18 s at N = 25, 0.94 s at
# N = 35, each within 25 %; eig and LU scale below u³ at these sizes; a lossy fin ×1.7)
SOLVE_SECONDS, SOLVE_SCALE = 5e-4, 1.9e-7
MEENT_SECONDS_PER_UNKNOWN_CUBED = 7e-9  # meent, per (2·N²)³: 1.3 s at N = 17 (meent 0.13, vector cell, 2 cores)
FIRST_HARMONICS = 5  # converge's first N: N = 5, 7, 9 are the fewest whose η can be compared with N − 2 and N − 4
DEFAULT_HARMONICS = 25  # η of the paper's fin within 8e-4 of N = 41 at 24 wavelengths (docs/benchmarks.md)
PROGRESS_CHUNK = 8  # wavelengths per batch when a progress callback is given


def estimate_seconds(harmonics: int, wavelengths: int, solver: str = "modes") -> float:
    """Wall seconds of :func:`fin_response` (``solver`` "modes") or :func:`fin_response_meent`
    ("meent") for ``wavelengths`` solves (2 cores)."""
    if solver == "meent":
        return MEENT_SECONDS_PER_UNKNOWN_CUBED * (2 * harmonics**2) ** 3 * wavelengths
    return (SOLVE_SECONDS + SOLVE_SCALE * ((harmonics**2 + 1) / 2) ** 2.4) * wavelengths


def convergence_seconds(stop: int, wavelengths: int, solver: str = "modes", start: int = FIRST_HARMONICS) -> float:
    """Wall seconds of :func:`converge` when it ends at N = ``stop``."""
    return sum(estimate_seconds(n, wavelengths, solver) for n in range(start, stop + 1, 2))


def estimate_bytes(harmonics: int, solver: str = "modes") -> int:
    """Peak bytes of one solve batch: complex128 matrices of the unknowns squared (about 16 held
    at once by fin_modes over its batch of problems, 12 by meent)."""
    if solver == "meent":
        return 16 * 12 * (2 * harmonics**2) ** 2
    from metalens_cli.optics.fin_modes import CHUNK_ELEMENTS

    return 16 * 16 * max(CHUNK_ELEMENTS, ((harmonics**2 + 1) // 2) ** 2)


def fin_response(
    fin: Fin,
    fin_index: np.ndarray,
    substrate_index: np.ndarray,
    wavelengths_m,
    harmonics: int,
    *,
    on_progress=None,
    device=None,
    solver: str = "modes",
) -> FinResponse:
    """The Jones coefficients and efficiencies of ``fin`` at each wavelength (see the module
    docstring).

    Args:
        fin: the nanofin cell (:class:`Fin`, lengths in m).
        fin_index: (W,) complex refractive index of the fin, n + ik (k ≥ 0 for loss), one per
            wavelength.
        substrate_index: (W,) complex refractive index of the substrate, likewise.
        wavelengths_m: (W,) wavelengths (m).
        harmonics: N, odd: Fourier orders −(N−1)/2 … (N−1)/2 per axis.
        on_progress: ``on_progress(done, total)`` is called after each batch of wavelengths.
        device: torch device of the "modes" solver.
        solver: "modes" (fin_modes, on torch ``device``) or "meent" (the reference, CPU).

    Returns:
        The :class:`FinResponse` (power fractions, complex Jones coefficients).
    """
    instance(fin, "fin", Fin, "a Fin")
    waves = lengths(wavelengths_m, "wavelengths_m")
    for name, index in (("fin_index", fin_index), ("substrate_index", substrate_index)):
        values = np.asarray(array(index, name, form="complex refractive indices n + ik"))
        if values.size not in (1, len(waves)):
            raise InputError(name, f"{values.size} indices for {len(waves)} wavelengths", "one per wavelength")
    check_harmonics(harmonics)
    if solver not in SOLVERS:
        raise InputError("solver", f"{solver!r}", " or ".join(SOLVERS))
    device = None if device is None else checked_device(device)
    if solver == "meent":
        return fin_response_meent(fin, fin_index, substrate_index, wavelengths_m, harmonics, on_progress)
    from metalens_cli.optics.fin_modes import fin_response_symmetric

    wavelengths = np.atleast_1d(np.asarray(wavelengths_m, dtype=float))
    n_fin, n_sub = (
        np.broadcast_to(np.asarray(v, dtype=complex), wavelengths.shape) for v in (fin_index, substrate_index)
    )
    step = PROGRESS_CHUNK if on_progress is not None else max(1, wavelengths.size)
    parts = []
    for first in range(0, wavelengths.size, step):
        part = slice(first, first + step)
        parts.append(fin_response_symmetric(fin, n_fin[part], n_sub[part], wavelengths[part], harmonics, device))
        if on_progress is not None:
            on_progress(min(first + step, wavelengths.size), wavelengths.size)
    if len(parts) == 1:
        return parts[0]
    joined = {
        key: np.concatenate([getattr(r, key) for r in parts])
        for key in (
            "wavelengths_m",
            "t_xx",
            "t_yy",
            "conversion",
            "co_polarized",
            "transmittance",
            "reflectance",
            "seconds",
        )
    }
    return FinResponse(harmonics=harmonics, **joined)


def fin_response_meent(
    fin: Fin, fin_index: np.ndarray, substrate_index: np.ndarray, wavelengths_m, harmonics: int, on_progress=None
) -> FinResponse:
    """:func:`fin_response` by meent: one wavelength at a time, on the CPU."""
    import meent

    check_harmonics(harmonics)
    wavelengths = np.atleast_1d(np.asarray(wavelengths_m, dtype=float))
    order = (harmonics - 1) // 2
    p = float(fin.period_m * NM)  # meent tests type(x) is float: numpy scalars would not do
    out = {key: [] for key in ("t_xx", "t_yy", "transmittance", "reflectance", "seconds")}
    for k, wavelength in enumerate(wavelengths):
        start = time.perf_counter()
        n_fin, n_sub = complex(fin_index[k]), complex(substrate_index[k])
        cell = [
            [
                1.0,
                [["rectangle", p / 2, p / 2, float(fin.width_m * NM), float(fin.length_m * NM), n_fin.conjugate(), 0]],
            ]
        ]
        solver = meent.call_mee(
            backend=0,
            pol=0,
            n_top=n_sub.real,
            n_bot=1.0,
            theta=0,
            phi=0,
            fto=[order, order],
            wavelength=wavelength * NM,
            period=[p, p],
            ucell=cell,
            thickness=[fin.height_m * NM],
        )
        result = solver.conv_solve()
        te, tm = result.res_te_inc, result.res_tm_inc
        scale = math.sqrt(1.0 / n_sub.real)  # √(n_out/n_in): field ratio → power amplitude
        out["t_yy"].append(np.conj(te.T_s[order, order]) * scale)  # meent's e^{+iωt} → e^{−iωt}
        out["t_xx"].append(np.conj(-1j * tm.T_p[order, order]) * scale)
        out["transmittance"].append(0.5 * (te.de_ti.sum() + tm.de_ti.sum()))
        out["reflectance"].append(0.5 * (te.de_ri.sum() + tm.de_ri.sum()))
        out["seconds"].append(time.perf_counter() - start)
        if on_progress is not None:
            on_progress(k + 1, wavelengths.size)
    t_xx, t_yy = np.array(out["t_xx"]), np.array(out["t_yy"])
    return FinResponse(
        wavelengths,
        t_xx,
        t_yy,
        np.abs(t_xx - t_yy) ** 2 / 4,
        np.abs(t_xx + t_yy) ** 2 / 4,
        np.array(out["transmittance"]),
        np.array(out["reflectance"]),
        harmonics,
        np.array(out["seconds"]),
    )


def converge(
    fin: Fin,
    fin_index: np.ndarray,
    substrate_index: np.ndarray,
    wavelengths_m,
    *,
    start: int = FIRST_HARMONICS,
    stop: int = 41,
    tolerance: float = 1e-3,
    device=None,
    solver: str = "modes",
    on_progress=None,
) -> tuple[int | None, list[dict], FinResponse]:
    """η at every wavelength for N = start, start + 2, … ≤ stop, until η moves less than
    ``tolerance`` at every wavelength from both N − 2 and N − 4 to N. Returns that N (None when
    none does up to ``stop``), the table (``harmonics``; ``max_change``, the largest change of η
    over the wavelengths from N − 2; ``conversion``, η at the middle wavelength; ``seconds`` for
    all wavelengths) and the last response (at the chosen N). η oscillates as N grows, and one
    pair can agree by chance: for the paper's fin at n = 2.0, N = 17 is within 1e-3 of N = 15 at
    all 24 wavelengths 430-660 nm but 2.3e-3 from N = 41; two pairs rarely agree by chance.
    ``on_progress(n, stop)`` is called after each N; ``stop`` must be at least ``start`` + 4 (three
    N to compare)."""
    if stop < start + 4:
        raise InputError(
            "max-harmonics",
            str(stop),
            f"at least {start + 4}: η at N is compared with N − 2 and N − 4 from N = {start}",
        )
    table, chosen, responses = [], None, []
    middle = np.atleast_1d(wavelengths_m).size // 2
    for n in range(start, stop + 1, 2):
        r = fin_response(fin, fin_index, substrate_index, wavelengths_m, n, device=device, solver=solver)
        changes = [float(np.abs(r.conversion - earlier.conversion).max()) for earlier in responses[-2:]]
        table.append(
            {
                "harmonics": n,
                "max_change": changes[-1] if changes else None,
                "conversion": float(r.conversion[middle]),
                "seconds": float(r.seconds.sum()),
            }
        )
        responses.append(r)
        if on_progress is not None:
            on_progress(n, stop)
        if len(changes) == 2 and max(changes) < tolerance:
            chosen = n
            break
    return chosen, table, responses[-1]
