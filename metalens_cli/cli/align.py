"""`metalens align`: register captured photographs onto their reference (homography, then a
smooth refinement) and write them on the reference's pixel grid."""

from __future__ import annotations

import os
import time
from contextlib import nullcontext
from pathlib import Path

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    MetalensCommand,
    OutputFile,
    OutputFolder,
    check_output_unused,
    hold_folder,
    json_option,
    overwrite_option,
    quiet_option,
)
from metalens_cli.constants import REFINEMENTS
from metalens_cli.errors import InputError
from metalens_cli.io.input_files import IMAGE_SUFFIXES

OUTPUT_SUFFIXES = (".png", ".tif", ".tiff", ".exr")
WARP_SUFFIX = ".warp.npz"


class FileOrFolder(OutputFile):
    """An output that is a file when its name ends in one of ``suffixes`` (checked as
    :class:`OutputFile`), else a folder (checked as :class:`OutputFolder`)."""

    name = "path"

    def convert(self, value, param, ctx):
        """The checked output path (str): as :class:`OutputFile` when its suffix (any case) is one
        of ``suffixes``, else as :class:`OutputFolder`; a bad path fails with the accepted form."""
        if Path(str(value)).suffix.lower() in self.suffixes:
            return super().convert(value, param, ctx)
        return OutputFolder().convert(value, param, ctx)


@click.command("align", cls=MetalensCommand)
@click.argument("reference", metavar="REFERENCE")
@click.argument("target", metavar="TARGET")
@click.option(
    "-o",
    "--output",
    required=True,
    type=FileOrFolder(OUTPUT_SUFFIXES),
    help="Aligned image (.png, .tif: 16-bit; .exr for an EXR target), or a folder for two folders (created).",
)
@click.option(
    "--refine",
    type=click.Choice(REFINEMENTS),
    default="flow",
    show_default=True,
    help="After the homography: flow (dense optical flow), tps (thin-plate spline through the matches) or none.",
)
@click.option(
    "--warp-out",
    type=FileOrFolder((".npz",)),
    help="Save the warp: WARP.npz for two images; for two folders, a folder (created, apart from -o) of NAME.warp.npz.",
)
@click.option(
    "--warp",
    "warp_path",
    type=click.Path(dir_okay=False),
    help="Reapply this saved warp (WARP.npz) to every target instead of registering.",
)
@overwrite_option
@quiet_option("No table, progress or 'wrote' lines (warnings and errors still go to stderr).")
@json_option
@click.pass_context
def align(ctx, reference, target, output, refine, warp_out, warp_path, overwrite, quiet, as_json):
    """Register captures of a scene (TARGET) onto its reference (REFERENCE) and write them on the
    reference's pixel grid.

    REFERENCE TARGET -o ALIGNED.png: two images. REF_DIR TARGET_DIR -o OUT_DIR: every
    TARGET_DIR/NAME.* onto REF_DIR/NAME.* (same file stem), written as OUT_DIR/NAME.png (NAME.exr
    for an EXR target); a target without a reference is an error, references without a target
    are skipped. The output has the target's encoding (8/16-bit in: 16-bit PNG or TIFF out; EXR
    in: EXR out), its R, G, B or single channel (alpha is dropped), and 0 where the target does
    not cover the reference. Nothing is written unless every pair registers, and -o and
    --warp-out are published together or not at all (a full disk, the file-size limit).

    Registration (the paper's protocol): SIFT features on contrast-stretched luminance (the
    sharper image blurred to the other's sharpness), a MAGSAC++ homography, then --refine.
    Exit 1 when a pair cannot be registered with confidence: fewer than 12 feature matches or
    consistent matches, under 15 % of them consistent, a degenerate homography (folded, mirrored,
    scale change over ×8), or under 10 % overlap. A low inlier fraction or a large residual is a
    warning on stderr.

    --warp WARP.npz replaces the registration by a saved warp (same setup, other captures):
    every REFERENCE and TARGET must have the sizes it was made for; REFERENCE pixels are unused.
    """
    folders = [os.path.isdir(path) for path in (reference, target)]
    if folders[0] != folders[1]:
        raise InputError(
            "TARGET",
            f"{target!r} is {'a folder' if folders[1] else 'a file'} but REFERENCE {reference!r} "
            f"is {'a folder' if folders[0] else 'a file'}",
            "two image files or two folders",
        )
    is_folder = folders[0]
    if warp_path is not None:
        if warp_out is not None:
            raise click.UsageError("--warp-out does not apply with --warp (the warp is saved already)")
        if ctx.get_parameter_source("refine") == click.core.ParameterSource.COMMANDLINE:
            raise click.UsageError("--refine does not apply with --warp (the saved warp was refined when it was made)")
    pairs = (
        _folder_pairs(Path(reference), Path(target))
        if is_folder
        else [(Path(target).stem, Path(reference), Path(target))]
    )
    _check_outputs(is_folder, output, warp_out, pairs, overwrite)
    from metalens_cli.imaging.registration import load_warp

    saved = None if warp_path is None else load_warp(warp_path, "--warp")
    if is_folder:
        rows, warnings = _align_folders(
            pairs, Path(output), None if warp_out is None else Path(warp_out), refine, saved, quiet
        )
    else:
        rows, warnings = _align_pair(pairs[0], Path(output), warp_out, refine, saved)
    for name, warning in warnings:
        render.say([f"{name}: {warning}"])
    if as_json:
        render.emit_json(
            {
                "reference": reference,
                "target": target,
                "output": output,
                "refine": rows[0]["registration"]["refine"],
                "warp": warp_path,
                "pairs": rows,
            }
        )
    elif not quiet:
        _render(rows, reference, is_folder, output, warp_out)


def _folder_pairs(reference: Path, target: Path) -> list[tuple[str, Path, Path]]:
    """(stem, reference file, target file) for every image of ``target``, by stem."""
    references, targets = _images(reference, "REFERENCE"), _images(target, "TARGET")
    if not targets:
        raise InputError("TARGET", f"folder {str(target)!r} holds no images", "PNG, JPEG, TIFF or EXR files")
    alone = sorted(set(targets) - set(references))
    if alone:
        listed = ", ".join(targets[stem].name for stem in alone[:5]) + (", …" if len(alone) > 5 else "")
        raise InputError(
            "TARGET",
            f"{len(alone)} image(s) without a reference of the same name in {str(reference)!r}: {listed}",
            "REF_DIR/NAME.* for every TARGET_DIR/NAME.*",
        )
    return [(stem, references[stem], targets[stem]) for stem in sorted(targets)]


def _images(folder: Path, field: str) -> dict[str, Path]:
    """The image files of ``folder`` by stem (hidden files skipped; two with one stem refused)."""
    try:
        entries = sorted(folder.iterdir())
    except OSError as exc:
        raise InputError(field, f"cannot read folder {str(folder)!r}: {exc.strerror}", "a readable folder") from None
    found: dict[str, Path] = {}
    for path in entries:
        if path.suffix.lower() not in IMAGE_SUFFIXES or path.name.startswith(".") or not path.is_file():
            continue
        if path.stem in found:
            raise InputError(
                field, f"{found[path.stem].name} and {path.name} in {str(folder)!r} share a name", "one image per name"
            )
        found[path.stem] = path
    return found


def _check_outputs(is_folder: bool, output: str, warp_out: str | None, pairs, overwrite: bool) -> None:
    """Outputs of the right kind for the mode (output folders unused, unless ``overwrite``), and
    an output encoding that is the target's."""
    if is_folder:
        for option, value, kind in (
            ("--output", output, "an output folder"),
            ("--warp-out", warp_out, "a folder of warps"),
        ):
            if (
                value is not None
                and not os.path.isdir(value)
                and Path(value).suffix.lower() in (*OUTPUT_SUFFIXES, ".npz")
            ):
                raise InputError(option, f"{value!r} names a file, but REFERENCE and TARGET are folders", kind)
            if value is not None:
                hold_folder(value, option)
                check_output_unused(value, overwrite, option)
        return
    if Path(output).suffix.lower() not in OUTPUT_SUFFIXES:
        raise InputError(
            "--output", f"{output!r} does not end in .png, .tif, .tiff or .exr", "an image file for two images"
        )
    if warp_out is not None and not warp_out.lower().endswith(".npz"):
        raise InputError("--warp-out", f"{warp_out!r} does not end in .npz", "WARP.npz for two images")
    target_exr = pairs[0][2].suffix.lower() == ".exr"
    if target_exr != (Path(output).suffix.lower() == ".exr"):
        raise InputError(
            "--output",
            f"{Path(output).name!r}: the output keeps the target's encoding",
            "a .exr output for an EXR target" if target_exr else ".png or .tif (16-bit) for an 8/16-bit target",
        )


def _align_pair(pair, output: Path, warp_out: str | None, refine: str, saved):
    from metalens_cli.imaging.registration import save_warp
    from metalens_cli.io.atomic import atomic_files

    row, registration, aligned, is_linear, warnings = _align_one(pair, refine, saved, "TARGET")
    with atomic_files(output, warp_out) as (image_file, warp_file):  # both or neither
        _write_image(image_file, aligned, is_linear)
        if warp_file is not None:
            save_warp(warp_file, registration)
    return [{**row, "output": str(output), "warp_out": warp_out}], warnings


def _align_folders(pairs, output: Path, warp_out: Path | None, refine: str, saved, quiet: bool):
    from metalens_cli.cli.progress import progress_bar
    from metalens_cli.imaging.registration import save_warp
    from metalens_cli.io.atomic import atomic_folder

    rows, warnings = [], []
    warp_folder = atomic_folder(warp_out, field="--warp-out") if warp_out is not None else nullcontext()
    with (
        progress_bar("align", quiet) as update,
        atomic_folder(output) as staging,
        warp_folder as warp_staging,
    ):  # all or none
        for k, (stem, reference, target) in enumerate(pairs):
            row, registration, aligned, is_linear, said = _align_one(
                (stem, reference, target), refine, saved, str(target), str(reference)
            )
            name = f"{stem}.exr" if is_linear else f"{stem}.png"
            _write_image(staging / name, aligned, is_linear)
            if warp_staging is not None:
                save_warp(warp_staging / f"{stem}{WARP_SUFFIX}", registration)
            rows.append(
                {
                    **row,
                    "output": str(output / name),
                    "warp_out": None if warp_out is None else str(warp_out / f"{stem}{WARP_SUFFIX}"),
                }
            )
            warnings += said
            update(k + 1, len(pairs))
    return rows, warnings


def _align_one(pair, refine: str, saved, field: str, reference_field: str = "REFERENCE"):
    """Read, register (or take the saved warp), resample one pair: (row, registration, aligned
    (H, W, C) float32, whether the target is linear, [(target, warning)]); a registration failure
    names the target as ``field``, the reference as ``reference_field`` (their files in folder
    mode)."""
    from metalens_cli.imaging.registration import register
    from metalens_cli.io.image_files import read_image_file

    stem, reference_path, target_path = pair
    start = time.perf_counter()
    reference, _, _ = read_image_file(reference_path, "REFERENCE")
    target, names, is_linear = read_image_file(target_path, "TARGET")
    if names[-1] == "A":
        target = target[:, :, :-1]
    if saved is None:
        registration = register(reference, target, refine=refine, field=field, reference_field=reference_field)
    else:
        registration = saved
        for role, image, shape in (
            ("REFERENCE", reference, saved.reference_shape),
            ("TARGET", target, saved.target_shape),
        ):
            if image.shape[:2] != tuple(shape):
                raise InputError(
                    role,
                    f"{(reference_path if role == 'REFERENCE' else target_path).name} is "
                    f"{image.shape[1]} × {image.shape[0]} pixels",
                    f"{shape[1]} × {shape[0]} pixels, as the --warp was made for",
                )
    aligned = registration.apply(target)
    report = registration.to_report()
    row = {
        "name": stem,
        "reference": str(reference_path),
        "target": str(target_path),
        "reapplied": saved is not None,
        "seconds": time.perf_counter() - start,
        "registration": report,
    }
    return row, registration, aligned, is_linear, [(str(target_path), warning) for warning in report["warnings"]]


def _write_image(path: Path, image, is_linear: bool) -> None:
    """EXR (linear float32) or 16-bit PNG/TIFF of an (H, W, 3 or 1) image, atomically."""
    import numpy as np

    from metalens_cli.io.image_files import write_encoded, write_exr_rgb

    if is_linear:
        write_exr_rgb(path, np.transpose(image, (2, 0, 1)))
    else:
        write_encoded(path, np.round(np.clip(image, 0.0, 1.0) * 65535).astype(np.uint16))


def _render(rows, reference: str, is_folder: bool, output: str, warp_out: str | None) -> None:
    table_rows = []
    for row in rows:
        r = row["registration"]
        flow = "—" if r["flow_rms_px"] is None else f"{r['flow_rms_px']:.2f} / {r['flow_max_px']:.2f}"
        table_rows.append(
            [
                Path(row["target"]).name,
                str(r["matches"]),
                f"{r['inliers']} ({100 * r['inlier_fraction']:.0f} %)",
                f"{r['residual_px']:.2f}",
                r["refine"],
                flow,
                f"{100 * r['valid_fraction']:.1f}",
                f"{row['seconds']:.2f}",
            ]
        )
    title = f"Aligned onto {reference}" + (" (saved warp)" if rows[0]["reapplied"] else "")
    columns = ["target", "matches", "inliers", "residual (px)", "refine", "flow rms / max (px)", "valid %", "s"]
    con = render.console()
    con.print(render.table(title, columns, table_rows))
    con.print(f"wrote {len(rows)} image(s) to {output}/" if is_folder else f"wrote {output}")
    if warp_out is not None:
        con.print(f"wrote {len(rows)} warp(s) to {warp_out}/" if is_folder else f"wrote {warp_out}")
