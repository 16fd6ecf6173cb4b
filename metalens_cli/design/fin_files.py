"""The report and files of a nanofin sweep (``metalens nanofin sweep -o FOLDER``): the map
(sweep.npz, sweep.csv, sweep.png), the report (sweep.json), the recommended fin as a preset's
``[nanofin]`` (nanofin.toml) and, given a preset, that preset with it (preset.toml). Lengths in
metres (the CSV's in nm)."""

from __future__ import annotations

import json

import numpy as np

from metalens_cli.design.fin_choice import FinMap, Sweep, SweepCell, recommended_nanofin
from metalens_cli.io.atomic import atomic_folder
from metalens_cli.io.json_files import jsonable
from metalens_cli.io.presets import section_toml, to_toml
from metalens_cli.optics.nanofin import SOLVERS
from metalens_cli.plotting.nanofin import plot_fin_map

SWEEP_FILES = ("sweep.npz", "sweep.csv", "sweep.png", "sweep.json", "nanofin.toml")


def sweep_report(cell: SweepCell, material, substrate, result: Sweep, output, preset_path=None) -> dict:
    """The JSON object of a sweep (sweep.json, ``--json``): the cell, its materials
    (:class:`~metalens_cli.optics.materials.Material`), the grid and wavelengths, the recommended
    fin, times, cache hits, warnings, the files written into ``output`` and the preset's path."""
    m = result.map
    return {
        "period_m": cell.period_m,
        "height_m": cell.height_m,
        "material": material.describe(),
        "substrate": substrate.describe(),
        "bands_m": [list(b) for b in cell.bands_m],
        "wavelengths_m": m.wavelengths_m.tolist(),
        "harmonics": m.harmonics,
        "widths_m": m.widths_m.tolist(),
        "lengths_m": m.lengths_m.tolist(),
        "recommended": result.choice,
        "seconds": m.seconds,
        "cached": result.cached,
        "converged_cached": result.converged_cached,
        "solver": SOLVERS["modes"],
        "warnings": result.warnings,
        "files": [*SWEEP_FILES, *(["preset.toml"] if preset_path is not None else [])],
        "output": str(output),
        "preset": preset_path,
    }


def sweep_csv(m: FinMap) -> str:
    """One line per grid fin (lengths outer, widths inner): width and length (nm), η per band and
    their mean."""
    rows = ["width_nm,length_nm," + ",".join(f"eta_{c * 1e9:g}nm" for c, _ in m.bands_m) + ",eta_mean"]
    for i, length in enumerate(m.lengths_m):
        for j, width in enumerate(m.widths_m):
            rows.append(
                f"{width * 1e9:g},{length * 1e9:g},"
                + ",".join(f"{v:.6f}" for v in m.eta[i, j])
                + f",{m.score[i, j]:.6f}"
            )
    return "\n".join(rows) + "\n"


def write_sweep(output, cell: SweepCell, result: Sweep, report: dict, preset=None) -> None:
    """Write the sweep's files into the folder ``output``, all or none
    (:func:`~metalens_cli.io.atomic.atomic_folder`); preset.toml only with a ``preset``."""
    m, choice = result.map, result.choice
    section = recommended_nanofin(cell.period_m, cell.height_m, cell.material, cell.substrate, choice)
    with atomic_folder(output) as folder:
        np.savez_compressed(
            folder / "sweep.npz",
            widths_m=m.widths_m,
            lengths_m=m.lengths_m,
            wavelengths_m=m.wavelengths_m,
            bands_m=np.array(m.bands_m),
            eta=m.eta,
            score=m.score,
        )
        (folder / "sweep.csv").write_text(sweep_csv(m), encoding="utf-8")
        plot_fin_map(folder / "sweep.png", m, choice)
        (folder / "sweep.json").write_text(
            json.dumps(jsonable(report), allow_nan=False, indent=1) + "\n", encoding="utf-8"
        )
        (folder / "nanofin.toml").write_text(
            "# the recommended fin of metalens nanofin sweep, for a preset\n" + section_toml("nanofin", section),
            encoding="utf-8",
        )
        if preset is not None:
            (folder / "preset.toml").write_text(to_toml(preset, nanofin=vars(section)), encoding="utf-8")
