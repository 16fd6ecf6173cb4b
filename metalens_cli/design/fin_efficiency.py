"""η(λ) of one nanofin at given or converged harmonics, and its report (``metalens nanofin
efficiency``). Lengths in metres, times in seconds."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass

from metalens_cli.optics.fin import Fin, FinResponse
from metalens_cli.optics.nanofin import FIRST_HARMONICS, SOLVERS, converge, fin_response


@dataclass(frozen=True)
class FinEfficiency:
    """The ``response`` at N = ``harmonics``; the convergence table of
    :func:`~metalens_cli.optics.nanofin.converge` and its ``tolerance`` (empty and None for a
    given N); warnings for the user."""

    response: FinResponse
    harmonics: int
    convergence: list[dict]
    tolerance: float | None
    warnings: list[str]

    @property
    def seconds(self) -> float:
        """RCWA seconds: the response's and those of every N before it in the convergence."""
        return float(self.response.seconds.sum() + sum(t["seconds"] for t in self.convergence[:-1]))


def fin_efficiency(
    fin: Fin,
    fin_index,
    substrate_index,
    wavelengths_m,
    harmonics: int | None,
    *,
    max_harmonics: int = 35,
    tolerance: float = 1e-3,
    device=None,
    solver: str = "modes",
    on_progress: Callable[[int, int], None] | None = None,
) -> FinEfficiency:
    """η at N = ``harmonics`` (:func:`~metalens_cli.optics.nanofin.fin_response`) or, for None,
    at the first N that converges within ``tolerance`` up to ``max_harmonics`` (else at
    ``max_harmonics``, with a warning); indices complex, one per wavelength."""
    if harmonics is not None:
        response = fin_response(
            fin,
            fin_index,
            substrate_index,
            wavelengths_m,
            harmonics,
            on_progress=on_progress,
            device=device,
            solver=solver,
        )
        return FinEfficiency(response, harmonics, [], None, [])
    chosen, table, response = converge(
        fin,
        fin_index,
        substrate_index,
        wavelengths_m,
        start=FIRST_HARMONICS,
        stop=max_harmonics,
        tolerance=tolerance,
        device=device,
        solver=solver,
        on_progress=on_progress,
    )
    warnings = []
    if chosen is None:
        chosen = table[-1]["harmonics"]
        warnings.append(
            f"η moved up to {table[-1]['max_change']:.2g} from N = {table[-2]['harmonics']} to {chosen}, more "
            f"than --tolerance {tolerance:g}; using N = {chosen} (raise --max-harmonics)"
        )
    return FinEfficiency(response, chosen, table, tolerance, warnings)


def efficiency_report(fin: Fin, material, substrate, result: FinEfficiency, solver: str, plot_path=None) -> dict:
    """The JSON object of ``metalens nanofin efficiency``: the fin, its materials
    (:class:`~metalens_cli.optics.materials.Material`), η, T, R and the Jones coefficients
    (``[re, im]``) per wavelength, the harmonics and their convergence, the solver's name."""
    r = result.response
    return {
        "fin": dataclasses.asdict(fin),
        "material": material.describe(),
        "substrate": substrate.describe(),
        "wavelengths_m": r.wavelengths_m.tolist(),
        "conversion_efficiency": r.conversion.tolist(),
        "co_polarized": r.co_polarized.tolist(),
        "transmittance": r.transmittance.tolist(),
        "reflectance": r.reflectance.tolist(),
        "t_xx": [[z.real, z.imag] for z in r.t_xx.tolist()],
        "t_yy": [[z.real, z.imag] for z in r.t_yy.tolist()],
        "harmonics": result.harmonics,
        "convergence": result.convergence,
        "tolerance": result.tolerance,
        "solver": SOLVERS[solver],
        "seconds": result.seconds,
        "warnings": result.warnings,
        **({"plot": str(plot_path)} if plot_path else {}),
    }
