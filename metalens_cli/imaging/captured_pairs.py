"""The paper's metric table from real captures (``metalens evaluate --pairs DIR``).

Layout (names: file stems; PNG, JPEG, TIFF 8/16-bit taken as sRGB-encoded, EXR as linear)::

    DIR/gt/NAME.png                          the reference (compound lens) of scene NAME
    DIR/DESIGN/unobstructed/NAME.png         the capture through lens DESIGN without obstruction
    DIR/DESIGN/obstructed/NAME.png           ... with the obstruction (or obstructed-KIND/, one per kind)
    DIR/DESIGN/recon-unobstructed/NAME.png   optional: the reconstructions of those captures
    DIR/DESIGN/recon-obstructed[-KIND]/NAME.png

Every design must hold every scene of ``gt`` in every folder it has. Alignment (``align``):
``unobstructed`` (default) registers each scene's unobstructed capture onto its reference
(:func:`metalens_cli.imaging.registration.register`) and applies that warp to the scene's
other captures of the same design (same camera and set-up, so the same size; an obstruction
would mislead the matching); ``each`` registers every capture on its own; ``none`` takes the
captures as aligned (same size as the reference). The metrics are computed over the largest rectangle that every
aligned capture of the scene covers, after the photometric match (``pipeline.score``).
A greyscale reference (one channel, or R = G = B) says nothing of colour: its captures are
scored by their Rec. 709 luminance, in all three channels, and the report warns.

Units are scenes; the statistics are those of simulated evaluation
(:mod:`metalens_cli.imaging.evaluation`): means with 95 % bootstrap intervals, Δ per scene,
paired differences between designs on the same scenes.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError
from metalens_cli.imaging.evaluation import Evaluation, metric_names, summarise, warn_few_units
from metalens_cli.imaging.images import luminance, read_linear
from metalens_cli.imaging.metrics import DEFAULT_MATCH
from metalens_cli.imaging.model_scores import summarise_model, unit_output
from metalens_cli.imaging.targets import from_records
from metalens_cli.imaging.task_detection import score_tasks, to_rgb8
from metalens_cli.imaging.task_scores import summarise_tasks
from metalens_cli.imaging.task_truth import cropped, truth_of
from metalens_cli.io.input_files import IMAGE_SUFFIXES

BYTES_PER_PIXEL = 500  # peak memory per pixel of the largest image: float64 SSIM/PSNR copies, the warp
SECONDS_PER_PIXEL = 2.5e-6  # per pixel of each capture: registration and scoring, 2 cores
BASE_MEMORY = 300 << 20  # torch, OpenCV and the interpreter
ALIGN_MODES = ("unobstructed", "each", "none")
_FOLDER = re.compile(r"(recon-)?(unobstructed|obstructed(?:-([A-Za-z0-9_]+))?)")
LAYOUT = (
    "DIR/gt/NAME.png and "
    "DIR/DESIGN/{unobstructed,obstructed[-KIND],recon-unobstructed,recon-obstructed[-KIND]}/NAME.png"
)


@dataclass(frozen=True)
class PairLayout:
    """What a pairs folder holds: scene ``names`` (sorted), ``gt`` paths by name, the
    ``designs`` (sorted folder names), obstruction ``kinds``, and ``captures[design][(capture,
    condition)]`` = paths by name, capture "raw" or "recon", condition "unobstructed" or a kind."""

    names: list[str]
    gt: dict[str, Path]
    designs: list[str]
    kinds: list[str]
    captures: dict[str, dict[tuple[str, str], dict[str, Path]]]

    def has_recon(self, design: str) -> bool:
        """Whether ``design`` has any reconstructed (``recon-…``) capture folder."""
        return any(capture == "recon" for capture, _ in self.captures[design])


def read_layout(folder: str | Path) -> PairLayout:
    """The layout of ``folder``, checked: every design has its unobstructed captures and at least
    one obstructed folder, each folder holds exactly the scenes of ``gt``, the obstruction kinds
    are the same for every design."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("--pairs", f"{str(folder)!r} is not a folder", LAYOUT)
    gt = images_by_stem(folder / "gt", "--pairs")
    if not gt:
        raise InputError("--pairs", f"no images in {str(folder / 'gt')!r}", LAYOUT)
    designs, kinds, captures = [], None, {}
    for design_folder in sorted(
        p for p in folder.iterdir() if p.is_dir() and p.name != "gt" and not p.name.startswith(".")
    ):
        found = {}
        for sub in sorted(p for p in design_folder.iterdir() if p.is_dir()):
            m = _FOLDER.fullmatch(sub.name)
            if m is None:
                raise InputError("--pairs", f"unexpected folder {sub.relative_to(folder)}", LAYOUT)
            capture = "recon" if m.group(1) else "raw"
            condition = "unobstructed" if m.group(2) == "unobstructed" else (m.group(3) or "obstructed")
            images = images_by_stem(sub, "--pairs")
            check_scenes(sub.relative_to(folder), images, gt)
            found[capture, condition] = images
        design_kinds = sorted({c for _, c in found if c != "unobstructed"})
        if ("raw", "unobstructed") not in found or not design_kinds:
            raise InputError("--pairs", f"{design_folder.name}/ lacks unobstructed/ or obstructed/", LAYOUT)
        missing_recon = [c for c in ("unobstructed", *design_kinds) if ("recon", c) not in found]
        if any(capture == "recon" for capture, _ in found) and missing_recon:
            raise InputError(
                "--pairs",
                f"{design_folder.name}/ has recon captures but not for {', '.join(missing_recon)}",
                "recon-unobstructed/ and recon-obstructed[-KIND]/ together",
            )
        if kinds is not None and design_kinds != kinds:
            raise InputError(
                "--pairs",
                f"{design_folder.name}/ has obstructions {design_kinds}, another design {kinds}",
                "the same obstructed folders for every design",
            )
        kinds = design_kinds
        designs.append(design_folder.name)
        captures[design_folder.name] = found
    if not designs:
        raise InputError("--pairs", f"no design folders in {str(folder)!r}", LAYOUT)
    return PairLayout(sorted(gt), gt, designs, kinds, captures)


def check_scenes(where: str | Path, scenes, gt) -> None:
    """Refuse a folder ``where`` (named relative to the pairs folder) whose scene names are not
    exactly those of gt/: a scene without a capture or a capture without a gt image."""
    extra, missing = sorted(set(scenes) - set(gt)), sorted(set(gt) - set(scenes))
    if missing or extra:
        what = f"lacks {', '.join(missing[:3])}" if missing else f"has {', '.join(extra[:3])} without a gt image"
        raise InputError("--pairs", f"{where} {what}", "every folder holding the scenes of gt/, by name")


def estimate_pairs(layout: PairLayout) -> tuple[int, float]:
    """(peak memory in bytes, seconds) of :func:`evaluate_pairs`, from the image headers; both
    measured on 2048² pairs (2.2 GB, 21 s for one scene's two captures on 2 cores)."""
    from metalens_cli.io.input_files import check_image_size

    def pixels(path: Path) -> int:
        height, width = check_image_size(path, f"--pairs: {path}")
        return height * width

    largest = max(pixels(path) for path in layout.gt.values())
    captures = [path for design in layout.captures.values() for paths in design.values() for path in paths.values()]
    sizes = [pixels(path) for path in captures]
    return BASE_MEMORY + BYTES_PER_PIXEL * max(largest, *sizes), SECONDS_PER_PIXEL * sum(sizes)


def images_by_stem(folder: Path, field: str) -> dict[str, Path]:
    """Image files of a folder by stem; two files of one stem are refused."""
    if not folder.is_dir():
        return {}
    out: dict[str, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() in IMAGE_SUFFIXES and path.is_file():
            if path.stem in out:
                raise InputError(
                    field, f"{out[path.stem].name} and {path.name} in {folder} name one scene", "one image per scene"
                )
            out[path.stem] = path
    return out


def evaluate_pairs(
    layout: PairLayout,
    lpips_model=None,
    match: str = DEFAULT_MATCH,
    align: str = "unobstructed",
    refine: str = "flow",
    on_progress: Callable[[int, int], None] | None = None,
    tasks=(),
    model=None,
    model_truth="clean",
) -> Evaluation:
    """Score every capture of ``layout`` against its reference (see the module docstring); the
    result is that of simulated evaluation with ``alignments`` (one report per registration)
    and no ``psfs``. With ``tasks`` (``imaging.targets.TASKS``), each reference's layout file
    (``DIR/gt/NAME.targets.json``, ``io.target_files``) gives its targets in its pixels, and the
    detectors score every aligned capture and the reference itself (the ceiling) on the targets
    that lie inside the region every capture of the scene, of every design, covers. With a user's
    ``model`` (``imaging.task_models``), it is run on that region of every aligned capture and of
    the reference; its truth is its output on the reference (``model_truth`` "clean") or the
    reference's labels (per name, in the reference's pixels: ``task_truth.framed_labels``), cut
    to the region."""
    from metalens_cli.imaging.pipeline import score

    if align not in ALIGN_MODES:
        raise InputError("--align", repr(align), " or ".join(ALIGN_MODES))
    layouts = {name: _scene_targets(layout.gt[name]) for name in layout.names} if tasks else {}
    out = Evaluation(images=list(layout.names))
    out.panels = {design: [] for design in layout.designs}
    metrics = metric_names(lpips_model)
    scores: dict[tuple, dict] = {}
    outcomes: dict[tuple, dict] = {}
    ceiling: dict[tuple, dict] = {}
    in_view: dict[tuple, list] = {}
    model_outputs: dict[tuple, object] = {}
    model_clean: dict[tuple, object] = {}
    model_truths: dict[tuple, object] = {}
    units: dict[tuple[int, int], list] = {}
    total = len(layout.designs) * len(layout.names)
    grey_names: list[str] = []
    for index, name in enumerate(layout.names):
        clean = read_linear(layout.gt[name], f"--pairs: {layout.gt[name]}")
        grey = bool((clean[0] == clean[1]).all() and (clean[1] == clean[2]).all())
        if grey:
            grey_names.append(name)
        scene = {
            d: _aligned_captures(layout, design, name, clean, align, refine, out)
            for d, design in enumerate(layout.designs)
        }
        boxes = {d: _common_box([valid for _, valid in aligned.values()]) for d, aligned in scene.items()}
        shared = _common_box([valid for aligned in scene.values() for _, valid in aligned.values()])
        if tasks:
            in_view[0, index] = targets = [t for t in layouts[name] if _inside(t, shared)]
            ceiling[0, index] = score_tasks(clean, targets, tasks)
        if model is not None:
            region = clean[:, shared[0] : shared[1], shared[2] : shared[3]]
            on_clean = model(to_rgb8(region))
            if isinstance(model_truth, str):
                model_truths[0, index] = truth_of(model, on_clean, model_truth, name)
            else:
                model_truths[0, index] = cropped(model_truth[name], shared)
            model_clean[0, index] = unit_output(model.kind, on_clean, model_truths[0, index])
        for d, design in enumerate(layout.designs):
            box = boxes[d]
            reference = clean[:, box[0] : box[1], box[2] : box[3]]
            for (capture, condition), (image, _) in scene[d].items():
                crop = image[:, box[0] : box[1], box[2] : box[3]]
                if grey:  # a monochrome reference says nothing of colour: compare luminance only
                    crop = np.repeat(luminance(crop)[None], 3, axis=0)
                scores[capture, d, condition, 0, index] = score(crop, reference, lpips_model, match)
                if tasks:
                    outcomes[capture, d, condition, 0, index] = score_tasks(image, in_view[0, index], tasks)
                if model is not None:
                    seen = model(to_rgb8(image[:, shared[0] : shared[1], shared[2] : shared[3]]))
                    model_outputs[capture, d, condition, 0, index] = unit_output(
                        model.kind, seen, model_truths[0, index]
                    )
                if index == 0:
                    if not out.panels[design]:
                        out.panels[design].append(("gt", reference))
                    prefix = "recon, " if capture == "recon" else ""
                    out.panels[design].append((f"{prefix}{condition}", crop))
            units[d, index] = [
                {
                    "design": design,
                    "capture": capture,
                    "obstruction": kind,
                    "seed": None,
                    "image": name,
                    "unobstructed": scores[capture, d, "unobstructed", 0, index],
                    "obstructed": scores[capture, d, kind, 0, index],
                }
                for capture in (("raw", "recon") if layout.has_recon(design) else ("raw",))
                for kind in layout.kinds
            ]
            if on_progress is not None:
                on_progress(index * len(layout.designs) + d + 1, total)
    out.units = [unit for d in range(len(layout.designs)) for i in range(len(layout.names)) for unit in units[d, i]]
    if grey_names:
        out.warnings.append(
            f"{len(grey_names)} greyscale reference(s) "
            f"({', '.join(grey_names[:3])}{', …' if len(grey_names) > 3 else ''}): their captures are compared in "
            "luminance (Rec. 709 Y of linear RGB)"
        )
    captures_of = [["raw", "recon"] if layout.has_recon(design) else ["raw"] for design in layout.designs]
    summarise(out, layout.designs, captures_of, layout.kinds, [0], len(layout.names), metrics, scores)
    if tasks:
        out.tasks, out.task_comparisons = summarise_tasks(
            tasks, layout.designs, captures_of, layout.kinds, [(0, i) for i in range(len(layout.names))],
            outcomes, ceiling, in_view,
        )  # fmt: skip
    if model is not None:
        out.model, out.model_comparisons = summarise_model(
            model.kind, layout.designs, captures_of, layout.kinds, [(0, i) for i in range(len(layout.names))],
            model_outputs, model_clean, model_truths,
        )  # fmt: skip
    warn_few_units(out, len(layout.names), f"{len(layout.names)} scene(s)", "capture more scenes")
    return out


def _scene_targets(reference: Path) -> list:
    """The targets of a reference image from its layout file, checked to be of its size."""
    from metalens_cli.io.input_files import check_image_size
    from metalens_cli.io.target_files import read_targets, targets_path

    path = targets_path(reference)
    field = "--task"
    if not path.is_file():
        raise InputError(
            field, f"no layout {path.name} beside {reference}", "DIR/gt/NAME.targets.json (metalens board)"
        )
    hw, records = read_targets(path, field)
    if tuple(hw) != check_image_size(reference, "--pairs"):
        raise InputError(field, f"{path.name} is for {hw[1]} × {hw[0]} pixels", f"the size of {reference.name}")
    return from_records(records, field)


def _inside(target, box: tuple[int, int, int, int]) -> bool:
    """Whether ``target``'s footprint lies inside ``box`` (top, bottom, left, right)."""
    x0, y0, fw, fh = target.footprint
    return box[2] <= x0 and x0 + fw <= box[3] and box[0] <= y0 and y0 + fh <= box[1]


def _aligned_captures(
    layout: PairLayout, design: str, name: str, clean: np.ndarray, align: str, refine: str, out: Evaluation
) -> dict[tuple[str, str], tuple[np.ndarray, np.ndarray]]:
    """(capture, condition) → (aligned (3, H, W) linear capture on the reference grid, valid mask)."""
    from metalens_cli.imaging.registration import register

    reference = np.transpose(clean, (1, 2, 0))
    shared, registered = None, None
    aligned = {}
    for key, paths in sorted(
        layout.captures[design].items(), key=lambda item: (item[0][0] != "raw", item[0][1] != "unobstructed")
    ):
        path = paths[name]
        image = read_linear(path, f"--pairs: {path}")
        if align == "none":
            if image.shape != clean.shape:
                raise InputError(
                    f"--pairs: {path}",
                    f"is {image.shape[2]} × {image.shape[1]} pixels, its gt {clean.shape[2]} × {clean.shape[1]}",
                    "captures of the reference's size with --align none",
                )
            aligned[key] = (image, np.ones(clean.shape[1:], bool))
            continue
        if align == "each" or shared is None:
            registration = register(reference, np.transpose(image, (1, 2, 0)), refine=refine, field=f"--pairs: {path}")
            out.alignments.append(
                {"design": design, "image": name, "capture": key[0], "condition": key[1], **registration.to_report()}
            )
            out.warnings += [f"{design}/{name}: {w}" for w in registration.warnings()]
            shared, registered = registration, path
        elif image.shape[1:] != tuple(shared.target_shape):
            raise InputError(
                f"--pairs: {path}",
                f"is {image.shape[2]} × {image.shape[1]} pixels, the capture whose warp it shares "
                f"({registered}) {shared.target_shape[1]} × {shared.target_shape[0]}",
                "the captures of one scene and design at one size (one camera), or --align each",
            )
        warped = shared.apply(np.transpose(image, (1, 2, 0)))
        aligned[key] = (np.transpose(warped, (2, 0, 1)), shared.valid_mask())
    return aligned


def _common_box(masks: list[np.ndarray]) -> tuple[int, int, int, int]:
    """(top, bottom, left, right) of a large rectangle inside which every mask is True: the
    edge with the most invalid pixels is moved in, one row or column at a time."""
    valid = np.logical_and.reduce(masks)
    top, bottom, left, right = 0, valid.shape[0], 0, valid.shape[1]
    while bottom - top > 16 and right - left > 16:
        box = valid[top:bottom, left:right]
        counts = [
            np.count_nonzero(~box[0]),
            np.count_nonzero(~box[-1]),
            np.count_nonzero(~box[:, 0]),
            np.count_nonzero(~box[:, -1]),
        ]
        if max(counts) == 0:
            if box.all():
                return top, bottom, left, right
            top, bottom, left, right = (
                top + 1,
                bottom - 1,
                left + 1,
                right - 1,
            )  # a hole inside: close in from all sides
            continue
        side = int(np.argmax(counts))
        top, bottom = top + (side == 0), bottom - (side == 1)
        left, right = left + (side == 2), right - (side == 3)
    raise InputError(
        "--pairs",
        "the aligned captures share under 16 × 16 pixels with their reference",
        "captures that cover their reference",
    )
