"""Layout export of the paper's lens: `metalens export-gds` against the straightforward gdstk route.

Lens: hyperbolic, λd = 532 nm, f = 4 mm, D = 2.516 mm, pitch 395 nm, fins 305 × 125 nm, database
unit 1 nm: 31,865,073 nanofins. Each case runs in a fresh process; its peak memory is the larger of
that process's and its children's peak resident set size (ru_maxrss; the OASIS route runs KLayout
in a child). Outputs go to a scratch directory (default /tmp), never into the repository.

Cases: exact rotations as GDSII and as OASIS, 128 quantised levels as GDSII, `--verify` of the
exact GDSII (KLayout reading it back), and the straightforward route: one gdstk.Polygon per fin
(vertices from the same numpy code), added to one cell and written with gdstk.Library.write_gds.

Usage: python benchmarks/bench_gds.py [--aperture 2.516mm] [--scratch /tmp] (writes its section of docs/benchmarks.md)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

from report import write_section

DESIGN = ["--design", "hyperbolic:532nm", "--f", "4mm", "--pitch", "395nm", "--width", "305nm", "--length", "125nm"]
CASES = {
    "gds": ("exact rotations, GDSII", ["--angles", "exact"], "lens.gds"),
    "oas": ("exact rotations, OASIS", ["--angles", "exact"], "lens.oas"),
    "gds128": ("128 quantised levels, GDSII", ["--angles", "128"], "lens128.gds"),
}


def _peak_gib() -> float:
    """Peak RSS (GiB) of this process and of its waited-for children."""
    return max(resource.getrusage(who).ru_maxrss for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)) / 2**20


def case_export(name: str, aperture: str, scratch: Path) -> dict:
    """One `metalens export-gds` run, in process: its JSON report plus wall time and peak memory."""
    import contextlib
    import io

    from metalens_cli.cli.main import run

    label, extra, file = CASES[name]
    start = time.perf_counter()
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = run(
            ["export-gds", *DESIGN, "--aperture", aperture, *extra, "-o", str(scratch / file), "--json", "--quiet"]
        )
    assert code == 0, code
    report = json.loads(stdout.getvalue())
    return {
        "case": label,
        "command": f"metalens export-gds {' '.join(DESIGN)} --aperture {aperture} {' '.join(extra)} -o {file}",
        "seconds": report["seconds"],
        "wall_s": time.perf_counter() - start,
        "peak_gib": _peak_gib(),
        "bytes": report["bytes"],
        "atoms": report["atoms"],
        "max_phase_error_rad": report["max_phase_error_rad"],
    }


def _design_and_geometry(aperture: str):
    from metalens_cli.io.designs import resolve_design
    from metalens_cli.io.layout import FinGeometry
    from metalens_cli.io.units import parse_length

    design = resolve_design(
        "hyperbolic:532nm", None, f_m=4e-3, aperture_m=parse_length(aperture, "aperture"), pitch_m=395e-9
    )
    return design, FinGeometry(395e-9, 305e-9, 125e-9)


def case_verify(aperture: str, scratch: Path) -> dict:
    """KLayout reads the exact GDSII back and checks count and 1000 sampled fins (--verify)."""
    from metalens_cli.io.layout_verify import verify_layout

    design, geometry = _design_and_geometry(aperture)
    start = time.perf_counter()
    result = verify_layout(str(scratch / CASES["gds"][2]), design, geometry, None)
    assert result.ok, result.failures
    return {
        "case": "--verify of the exact GDSII (KLayout)",
        "command": "verify_layout(lens.gds, ...)",
        "seconds": time.perf_counter() - start,
        "wall_s": time.perf_counter() - start,
        "peak_gib": _peak_gib(),
        "bytes": None,
        "atoms": result.found_atoms,
        "max_phase_error_rad": result.worst["phase_vs_design_rad"],
    }


def case_gdstk(aperture: str, scratch: Path) -> dict:
    """The straightforward route: one gdstk.Polygon per fin in one cell, then Library.write_gds."""
    import gdstk

    from metalens_cli.io.layout import fin_vertices, site_chunks, site_rows, site_theta

    design, geometry = _design_and_geometry(aperture)
    start = time.perf_counter()
    library = gdstk.Library(unit=1e-6, precision=1e-9)
    cell = library.new_cell("hyperbolic_532nm")
    atoms = 0
    for i, j in site_chunks(site_rows(design.lens.radius_m, design.lens.pitch_m)):
        vertices = fin_vertices(i, j, site_theta(design.lens, i, j), geometry) * 1e-3  # µm
        cell.add(*[gdstk.Polygon(points, layer=1, datatype=0) for points in vertices])
        atoms += i.size
    path = scratch / "gdstk.gds"
    library.write_gds(str(path))
    seconds = time.perf_counter() - start
    return {
        "case": "straightforward gdstk (one Polygon per fin)",
        "command": "gdstk.Polygon per fin + write_gds",
        "seconds": seconds,
        "wall_s": seconds,
        "peak_gib": _peak_gib(),
        "bytes": path.stat().st_size,
        "atoms": atoms,
        "max_phase_error_rad": 0.0,
    }


def run_case(name: str, aperture: str, scratch: Path) -> dict:
    """Run one case in a fresh interpreter and return its result."""
    out = subprocess.run(
        [sys.executable, __file__, "--case", name, "--aperture", aperture, "--scratch", str(scratch)],
        check=True,
        capture_output=True,
        text=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def table(results: dict, aperture: str, load: tuple) -> str:
    """The Markdown report."""
    base = results["gdstk"]
    lines = [
        "## Layout export of the paper's lens (`metalens export-gds`)",
        "",
        f"Command: `python benchmarks/bench_gds.py --aperture {aperture}`; {os.cpu_count()} CPUs, Python "
        f"{platform.python_version()}; load average before the run {load[0]:.2f} (other work shares this machine).",
        f"Lens: hyperbolic:532nm, f 4 mm, D {aperture}, pitch 395 nm, fins 305 × 125 nm, dbu 1 nm: "
        f"{results['gds']['atoms']:,} nanofins. Targets: exact GDSII ≤ 20 s at ≤ 4 GiB; OASIS ≤ 60 s and ≤ 150 MB.",
        "",
        "| case | export (s) | process wall (s) | peak RSS (GiB) | file (MB) | max phase error (rad) | time vs gdstk |",
        "|---|---|---|---|---|---|---|",
    ]
    for key in ("gds", "oas", "gds128", "verify", "gdstk"):
        r = results[key]
        size = "—" if r["bytes"] is None else f"{r['bytes'] / 1e6:.1f}"
        ratio = "—" if key == "verify" else f"{base['seconds'] / r['seconds']:.1f}× faster" if key != "gdstk" else "1×"
        lines.append(
            f"| {r['case']} | {r['seconds']:.1f} | {r['wall_s']:.1f} | {r['peak_gib']:.2f} | {size} | "
            f"{r['max_phase_error_rad']:.3g} | {ratio} |"
        )
    lines += [
        "",
        "Export time is the `seconds` of the `--json` report (sites, θ, vertices, records, rename); process wall "
        "adds interpreter start, imports (torch) and design resolution. The verify row's phase error is measured on "
        "the file (vertex rounding to 1 nm). Commands:",
        "",
    ]
    lines += [f"- {results[key]['case']}: `{results[key]['command']}`" for key in ("gds", "oas", "gds128")]
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aperture", default="2.516mm")
    parser.add_argument("--scratch", default="/tmp/metalens-bench-gds")
    parser.add_argument("--case", help=argparse.SUPPRESS)
    args = parser.parse_args()
    scratch = Path(args.scratch)
    scratch.mkdir(parents=True, exist_ok=True)
    if args.case:
        result = {
            "verify": lambda: case_verify(args.aperture, scratch),
            "gdstk": lambda: case_gdstk(args.aperture, scratch),
        }.get(args.case, lambda: case_export(args.case, args.aperture, scratch))()
        print(json.dumps(result))
        return
    load = os.getloadavg()
    results = {}
    for name in ("gds", "oas", "gds128", "verify", "gdstk"):
        results[name] = run_case(name, args.aperture, scratch)
        print(
            f"{name}: {results[name]['seconds']:.1f} s, {results[name]['peak_gib']:.2f} GiB",
            file=sys.stderr,
            flush=True,
        )
    for path in scratch.iterdir():
        path.unlink()
    print(f"wrote {write_section('gds', table(results, args.aperture, load))}", file=sys.stderr)


if __name__ == "__main__":
    main()
