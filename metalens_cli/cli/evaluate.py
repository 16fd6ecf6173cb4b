"""`metalens evaluate`: PSNR/SSIM (and LPIPS when its weights are present) of unobstructed and
obstructed captures, design against design, with bootstrap confidence intervals."""

from __future__ import annotations

import click

from metalens_cli.cli import render
from metalens_cli.cli.options import (
    CommaChoice,
    LightLevels,
    MetalensCommand,
    Number,
    OutputFile,
    SeedList,
    announce,
    json_option,
    lpips_weights_option,
    max_memory_option,
    plot_option,
    quiet_option,
    refuse_overwriting,
)
from metalens_cli.cli.progress import efficiency_used, progress_bar
from metalens_cli.cli.simulate import capture_options, setup_from
from metalens_cli.constants import REFINEMENTS

MATCH_METHODS = (
    "lstsq",
    "luminance",
)  # imaging.metrics.MATCH_METHODS, the first the default (not imported: it pulls in torch)
ALIGN_MODES = ("unobstructed", "each", "none")  # imaging.captured_pairs.ALIGN_MODES
TASKS = ("markers", "qr", "text")  # imaging.targets.TASKS (not imported: it pulls in numpy)
LABELS = {"unobstructed": "Unobs.", "obstructed": "Obs.", "delta": "Δ"}


# the options that apply to --pairs (its run is estimated and announced: --max-memory and --max-time hold)
PAIRS_OPTIONS = {
    "pairs",
    "align",
    "refine",
    "match",
    "csv_path",
    "lpips_weights",
    "quiet",
    "as_json",
    "plot_path",
    "max_memory",
    "max_time",
    "specs",
    "tasks",
    "task_model",
    "task_kind",
    "task_labels",
}


@click.command("evaluate", cls=MetalensCommand)
@click.argument("specs", metavar="DESIGN...", nargs=-1)
@capture_options
@click.option(
    "--seed",
    "seeds",
    type=SeedList(),
    default="0:2",
    show_default=True,
    help="Seeds of depths, obstructions and noise: 0, 0,1,2 or 0:2; units are images × seeds "
    "(default: 9 photographs × 3 seeds = 27 units, where paired differences between the quick designs "
    "have 95 % CIs 0.1-0.6 dB wide; under 20 units a cell is warned about).",
)
@click.option(
    "--obstruction",
    default="dirt,fence",
    show_default=True,
    help="Comma-separated: dirt, fence, drops, rain, file:PATH.png.",
)
@click.option(
    "--match",
    type=click.Choice(MATCH_METHODS),
    default=MATCH_METHODS[0],
    show_default=True,
    help="Photometric match before the metrics: least-squares gain and bias, or the paper's luminance mean/std "
    "(which can let an obstruction raise a blurred capture's score).",
)
@click.option("--csv", "csv_path", type=OutputFile(), help="Write the rows (means and CIs) as CSV.")
@lpips_weights_option(
    "Directory with alexnet-owt-7be5be79.pth and lpips's v0.1 alex.pth "
    "(without it or its environment variable: torch hub's checkpoints with an installed lpips; "
    "none found: LPIPS is skipped with a note; nothing is downloaded)."
)
@click.option(
    "--recon",
    "recon_runs",
    multiple=True,
    help="Reconstruction runs (metalens reconstruct train), one per DESIGN in order, comma-separated or repeated; "
    "'-' for a design without one. Adds Recon rows.",
)
@click.option(
    "--pairs",
    type=click.Path(exists=True, file_okay=False),
    help="Score real captures instead of simulating: DIR/gt/NAME.png, DIR/DESIGN/unobstructed/NAME.png, "
    "DIR/DESIGN/obstructed[-KIND]/NAME.png, optional DIR/DESIGN/recon-unobstructed/ and recon-obstructed[-KIND]/.",
)
@click.option(
    "--align",
    type=click.Choice(ALIGN_MODES),
    default="unobstructed",
    show_default=True,
    help="--pairs: register each scene's unobstructed capture onto gt and reuse its warp, register every capture, "
    "or none (already aligned).",
)
@click.option(
    "--refine",
    type=click.Choice(REFINEMENTS),
    default="flow",
    show_default=True,
    help="--pairs: the non-linear refinement after the homography (see metalens align).",
)
@click.option(
    "--photons-before-filter",
    is_flag=True,
    help="--photons counts the light before each design's filter: its channels get their filter's throughput of it "
    "(designs with different filters compared at the same light).",
)
@click.option(
    "--light",
    "light_levels",
    type=LightLevels(),
    help="One table per light level, every design under the same camera: electrons a full-scale pixel collects "
    "before the filter through an ideal lens (η = 1), e.g. 250,2000,20000, names dim, indoor, daylight, or none "
    "(noise-free); each design's filter and nanofin efficiency take their share, shot and read noise follow, and "
    "its zero-order light is imaged. With 2+ levels, verdicts say below which level the first design stops winning.",
)
@click.option(
    "--read-electrons",
    type=Number(0, 1000),
    default=2.5,  # imaging.camera.DEFAULT_READ_ELECTRONS (not imported: it pulls in numpy)
    show_default=True,
    help="--light: read noise, electrons rms.",
)
@click.option(
    "--zero-order-leak",
    type=Number(0, 1),
    default=0.01,  # imaging.camera.DEFAULT_ZERO_ORDER_LEAK
    show_default=True,
    help="--light: the fraction of the unconverted (co-polarised) light the analyzer passes; 1 without one.",
)
@click.option(
    "--wiener",
    is_flag=True,
    help="Add Wiener rows: the oracle linear restoration from each design's far PSFs, its regularisation chosen per "
    "design and light level on held-out charts.",
)
@click.option(
    "--task",
    "tasks",
    type=CommaChoice(TASKS),
    multiple=True,
    help="Vision tasks, comma-separated or repeated: ArUco markers (side 24-160 px), QR codes (modules 1.5-6 px) "
    "and text lines (10-40 px) are printed into every clean scene before imaging; OpenCV's ArUco detector, "
    "zxing-cpp and RapidOCR (text: pip install --no-deps rapidocr) score each capture and the clean scene (the "
    "ceiling): found rate, wrong detections, corner error, size50 (text: also line recall and character error rate).",
)
@click.option(
    "--task-model",
    help="Your own model on every capture: a .onnx (pip install 'metalens-cli[tasks]'), .pt2 (torch.export) or "
    "TorchScript file taking float N×3×H×W sRGB in 0..1, or module:callable taking uint8 N×H×W×3 sRGB.",
)
@click.option(
    "--task-kind",
    type=click.Choice(("detect", "segment")),  # imaging.task_models.KINDS
    default="detect",
    show_default=True,
    help="--task-model's output: (N, K, 6) boxes or a raw (N, 4 + classes, anchors) YOLO head; or segmentation "
    "(N, C, H, W) scores or (N, H, W) classes. Scored by mAP50, mAP50-95 and recall, or mIoU, IoU and Dice.",
)
@click.option(
    "--task-labels",
    default="clean",
    show_default=True,
    help="--task-model's truth: 'clean' (its own output on each clean scene, scores ≥ 0.25) or a folder of labels "
    "for --images DIR: NAME.txt (YOLO), one COCO .json, or NAME.png class masks.",
)
@quiet_option()
@max_memory_option
@json_option
@plot_option
@click.pass_context
def evaluate(
    ctx,
    specs,
    preset_path,
    f_m,
    aperture_m,
    pitch_m,
    images,
    limit,
    z_near_m,
    z_far_m,
    pixels,
    psf_pixels,
    pixel_pitch_m,
    wavelengths,
    formation,
    alpha_gain,
    field_model,
    field_tolerance,
    halo_scale,
    photons,
    read_noise,
    device,
    seeds,
    obstruction,
    match,
    csv_path,
    lpips_weights,
    recon_runs,
    pairs,
    align,
    refine,
    photons_before_filter,
    light_levels,
    read_electrons,
    zero_order_leak,
    wiener,
    tasks,
    task_model,
    task_kind,
    task_labels,
    quiet,
    max_memory,
    as_json,
    plot_path,
):
    """Unobstructed and obstructed captures of each DESIGN against the clean images, or of real
    captures with --pairs DIR.

    Every design sees the same units (image, seed). Per cell: the mean over units with a 95 %
    bootstrap confidence interval; Δ = Obs. − Unobs. per unit (LPIPS: Unobs. − Obs.; negative is
    a degradation); paired differences between designs on the same units. PSNR and SSIM after
    the photometric match (Suppl. Note 11), on sRGB-encoded images. LPIPS (v0.1, AlexNet) when
    its weights are found locally (nothing is downloaded), else skipped with a note. With
    --recon, each design's captures are also scored after its reconstruction network (Recon rows).

    --pairs DIR: the same table from captured photographs (the paper's Suppl. table), one unit
    per scene: each capture registered onto its gt image (homography, then a smooth
    refinement), the metrics over the region every capture of the scene covers.
    """
    tasks = tuple(dict.fromkeys(t for group in tasks for t in group))
    if pairs is not None:
        model = (task_model, task_kind, task_labels)
        return _evaluate_pairs(
            ctx,
            pairs,
            align,
            refine,
            match,
            csv_path,
            lpips_weights,
            quiet,
            max_memory,
            as_json,
            plot_path,
            tasks,
            model,
        )
    if not specs:
        raise click.UsageError("give at least one DESIGN, or --pairs DIR for captured photographs")
    from metalens_cli.imaging.evaluation import EvaluationSettings, metric_names
    from metalens_cli.imaging.evaluation import evaluate as run_evaluation
    from metalens_cli.imaging.images import image_count
    from metalens_cli.imaging.obstructions import parse_obstructions
    from metalens_cli.imaging.pipeline import estimate_capture_runs

    kinds = parse_obstructions(obstruction)
    lpips_model, notes = _lpips(lpips_weights)
    metrics = metric_names(lpips_model)
    s = setup_from(list(specs), ctx.params)
    formation_options = dict(formation=formation, alpha_gain=alpha_gain, photons=photons, read_noise=read_noise)
    model, model_truth = _task_model(task_model, task_kind, task_labels, images, limit, s)
    settings = EvaluationSettings.from_setup(
        s,
        images=images,
        limit=limit,
        match=match,
        photons_before_filter=photons_before_filter,
        psf_window=psf_pixels,
        field_model=field_model,
        field_tolerance=field_tolerance,
        halo_scale=halo_scale,
        light_levels=light_levels,
        read_electrons=read_electrons,
        zero_order_leak=zero_order_leak if light_levels else None,
        wiener=wiener,
        tasks=tasks,
        model=model,
        model_truth=model_truth,
        **formation_options,
    )
    if light_levels and (photons or read_noise or photons_before_filter):
        from metalens_cli.errors import InputError

        raise InputError("--light", "with --photons, --read-noise or --photons-before-filter", "one of the two cameras")
    reconstructors = _reconstructors(recon_runs, s.designs, s.device)
    count = image_count(images, limit)
    what = (
        f"evaluate of {len(s.designs)} design(s) × {count} image(s) × {len(seeds)} seed(s) × {len(kinds)} "
        "obstruction(s)"
    )
    # PSFs once per design and seed (the depths are the seed's), captures per obstruction kind too
    depths = (s.z_near_interval_m[0], s.z_far_interval_m[0])
    estimate = estimate_capture_runs(
        s,
        what,
        depths,
        count,
        window=psf_pixels,
        seeds=len(seeds),
        kinds=len(kinds),
        field_model=field_model,
        zero_order=bool(light_levels) and zero_order_leak > 0,
    )
    if tasks or model:
        import dataclasses

        from metalens_cli.imaging.task_detection import scoring_seconds

        per_capture = (1 + len(kinds)) * max(1, len(light_levels or ()))  # unobstructed and each kind, each camera
        made = sum(1 + wiener + (r is not None) for r in reconstructors)  # raw, wiener, recon per design
        scored = len(seeds) * count * (1 + made * per_capture)  # 1: the clean scene
        seconds = scoring_seconds(tasks, s.pixels, scored) + (model.seconds * scored if model else 0.0)
        estimate = dataclasses.replace(estimate, seconds=(estimate.seconds or 0.0) + seconds)
    announce(estimate, max_memory, device=s.device)
    efficiency = {d.spec: efficiency_used(d.preset, quiet) for d in s.designs}
    with progress_bar("evaluate", quiet) as update:
        result = run_evaluation(
            s.designs,
            kinds,
            seeds,
            settings,
            lpips_model=lpips_model,
            on_progress=update,
            reconstructors=reconstructors,
        )
    extra = {
        "photometric_match": match,
        "psfs": result.psfs,
        "seeds": seeds,
        "formation": formation,
        "recon": [None if r is None else r.source for r in reconstructors],
        "efficiency": efficiency,
        "cameras": result.cameras,
        "verdicts": result.verdicts,
        **({"camera": {"read_electrons": read_electrons, "zero_order_leak": zero_order_leak}} if light_levels else {}),
    }
    title = _title(result, seeds, [*reconstructors, wiener or None])
    _report(result, [d.spec for d in s.designs], kinds, metrics, notes, csv_path, plot_path, as_json, extra, title)


def _task_model(spec, kind, labels, images, limit, setup):
    """(the loaded --task-model, checked on a grey image of the sensor's size, and its truth) or
    (None, "clean")."""
    if spec is None:
        return None, "clean"
    from metalens_cli.imaging.task_models import load_task_model
    from metalens_cli.imaging.task_truth import label_truths

    model = load_task_model(spec, kind, setup.device, check_pixels=setup.pixels)
    folder = _label_folder(labels)
    if folder is None:
        return model, "clean"
    return model, label_truths(folder, images, limit, kind, (setup.pixels, setup.pixels))


def _pairs_model(spec, kind, labels, layout):
    """--task-model with --pairs: (the model, checked on a grey image, and its truth: "clean" or
    the labels of each reference in its own pixels) or (None, "clean")."""
    if spec is None:
        return None, "clean"
    from metalens_cli.imaging.task_models import load_task_model
    from metalens_cli.imaging.task_truth import framed_labels
    from metalens_cli.io.input_files import check_image_size

    model = load_task_model(spec, kind, "cpu", check_pixels=256)
    folder = _label_folder(labels)
    if folder is None:
        return model, "clean"
    sources = {name: check_image_size(path, "--pairs") for name, path in layout.gt.items()}
    return model, framed_labels(folder, sources, kind)


def _label_folder(labels: str):
    """--task-labels as a folder, or None for "clean"; anything else is refused naming the option."""
    from pathlib import Path

    from metalens_cli.errors import InputError

    if labels.strip() == "clean":
        return None
    if not Path(labels).is_dir():
        raise InputError("--task-labels", f"no such folder {labels!r}", "clean or a folder of labels")
    return Path(labels)


def _title(result, seeds, reconstructors) -> str:
    """The title of the table of simulated captures."""
    n = result.rows[0]["n"] if result.rows else 0
    what = "Raw and reconstructed captures" if any(reconstructors) else "Raw captures"
    return f"{what} vs clean: mean [95 % CI] over {len(result.images)} images × {len(seeds)} seeds = {n} units"


def _lpips(weights) -> tuple[object, list[str]]:
    """The LPIPS model of --lpips-weights (None when no weights are found) and the note saying so."""
    from metalens_cli.imaging.lpips import Lpips, find_lpips_weights

    paths, skip = find_lpips_weights(weights)
    return (Lpips.from_files(paths.alexnet, paths.lin) if paths else None), [n for n in (skip,) if n]


def _report(result, specs, kinds, metrics, notes, csv_path, plot_path, as_json, extra: dict, title: str) -> None:
    """Notes and warnings on stderr, the CSV and figure, then the JSON or the tables (one per
    light level, then the verdicts)."""
    from metalens_cli.imaging.evaluation import evaluation_report, write_rows_csv

    notes = [*notes, *result.notes]
    render.say(notes, "note")
    render.say(result.warnings)
    if csv_path:
        write_rows_csv(csv_path, result.rows, metrics)
    if plot_path:
        from metalens_cli.plotting.imaging import comparison_figure

        comparison_figure(plot_path, specs, result.panels)
    if as_json:
        render.emit_json(evaluation_report(result, extra, notes, csv_path, plot_path))
        return
    con = render.console()
    for light in dict.fromkeys(r.get("light") for r in result.rows):
        where = "" if light is None else f", light {light}"
        con.print(
            render.table(
                title + where,
                ["design", "condition"] + [f"{k} {_short(m)}" for k in kinds for m in metrics],
                _table_rows(result, kinds, metrics, light),
            )
        )
        pairs = [
            c
            for c in result.comparisons
            if c["metric"] == "psnr_db" and c["condition"] in ("obstructed", "delta") and c.get("light") == light
        ]
        if pairs:
            con.print(
                render.table(
                    f"Paired PSNR differences (design − versus, same units){where}, dB [95 % CI]",
                    ["design", "versus", "obstruction", "condition", "difference", "CI width"],
                    [
                        [
                            f"{c['design']} ({c['capture']})",
                            f"{c['versus']} ({c['versus_capture']})",
                            c["obstruction"],
                            LABELS[c["condition"]],
                            _ci(c["difference"], c["ci"], 2, lines=False),
                            f"{c['ci'][1] - c['ci'][0]:.2f}",
                        ]
                        for c in pairs
                    ],
                )
            )
    verdicts = [v for v in result.verdicts if "verdict" in v]
    if verdicts:
        con.print(
            render.table(
                "Verdicts: obstructed PSNR, first design − versus, over the light levels",
                ["design", "versus", "capture", "obstruction", "verdict"],
                [[v["design"], v["versus"], v["capture"], v["obstruction"], v["verdict"]] for v in verdicts],
            )
        )
    _task_tables(con, result)
    _model_tables(con, result)


def _task_tables(con, result) -> None:
    """Per task and light level: found rate, size50, wrong detections and corner error per cell,
    then the paired found-rate differences of the obstructed captures."""
    from metalens_cli.analysis.size50 import describe

    for task, light in dict.fromkeys((r["task"], r.get("light")) for r in result.tasks):
        where = "" if light is None else f", light {light}"
        rows = [r for r in result.tasks if r["task"] == task and r.get("light") == light]
        text = task == "text"
        con.print(
            render.table(
                f"Task {task}{where}: {'read exactly' if text else 'found'} [95 % CI] over {rows[0]['n']} units, "
                f"size50 ({rows[0]['size_unit']})",
                ["design", "capture", "obstruction", "condition", "read" if text else "found", "size50"]
                + (["line recall", "CER"] if text else [])
                + ["wrong/unit", "corner err px"],
                [
                    [
                        r["design"],
                        r["capture"],
                        r["obstruction"] or "",
                        r["condition"],
                        _ci(r["found_rate"], r["found_rate_ci"], 2, lines=False),
                        describe(r),
                        *([f"{r['line_recall']:.2f}", f"{r['cer']:.2f}"] if text else []),
                        f"{r['wrong_per_unit']:.2f}",
                        "" if r["corner_error_px"] is None else f"{r['corner_error_px']:.2f}",
                    ]
                    for r in rows
                ],
            )
        )
        pairs = [
            c
            for c in result.task_comparisons
            if c["task"] == task and c.get("light") == light and c["condition"] == "obstructed"
        ]
        if not pairs:
            continue
        con.print(
            render.table(
                f"Task {task}{where}: paired found-rate differences, obstructed (design − versus) [95 % CI]",
                ["design", "versus", "obstruction", "difference"],
                [
                    [
                        f"{c['design']} ({c['capture']})",
                        f"{c['versus']} ({c['versus_capture']})",
                        c["obstruction"],
                        _ci(c["difference"], c["ci"], 2, lines=False),
                    ]
                    for c in pairs
                ],
            )
        )


def _model_tables(con, result) -> None:
    """Per light level: the user's model's scores per cell, then its paired differences (obstructed)."""
    names = {"map50": "mAP50", "map50_95": "mAP50-95", "recall50": "recall50"}
    names |= {
        "miou": "mIoU",
        "miou_paper": "mIoU, paper's rule",
        "iou_foreground": "IoU fg",
        "dice_foreground": "Dice fg",
    }
    for light in dict.fromkeys(r.get("light") for r in result.model):
        where = "" if light is None else f", light {light}"
        rows = [r for r in result.model if r.get("light") == light]
        metrics = [m for m in names if m in rows[0]]
        con.print(
            render.table(
                f"Your model{where}: {', '.join(names[m] for m in metrics)} [95 % CI] over {rows[0]['n']} units",
                ["design", "capture", "obstruction", "condition", *(names[m] for m in metrics)],
                [
                    [
                        r["design"],
                        r["capture"],
                        r["obstruction"] or "",
                        r["condition"],
                        *("—" if r[m] is None else _ci(r[m], r[f"{m}_ci"], 3, lines=False) for m in metrics),
                    ]
                    for r in rows
                ],
            )
        )
        pairs = [c for c in result.model_comparisons if c.get("light") == light and c["condition"] == "obstructed"]
        if pairs:
            con.print(
                render.table(
                    f"Your model{where}: paired {names[pairs[0]['metric']]} differences, obstructed [95 % CI]",
                    ["design", "versus", "obstruction", "difference"],
                    [
                        [
                            f"{c['design']} ({c['capture']})",
                            f"{c['versus']} ({c['versus_capture']})",
                            c["obstruction"],
                            "—" if c["difference"] is None else _ci(c["difference"], c["ci"], 3, lines=False),
                        ]
                        for c in pairs
                    ],
                )
            )


def _evaluate_pairs(
    ctx, folder, align, refine, match, csv_path, lpips_weights, quiet, max_memory, as_json, plot_path, tasks, model
) -> None:
    """evaluate --pairs: the table of captured photographs (imaging.captured_pairs)."""
    from pathlib import Path

    from metalens_cli.errors import InputError
    from metalens_cli.imaging.captured_pairs import estimate_pairs, evaluate_pairs, read_layout
    from metalens_cli.imaging.evaluation import metric_names
    from metalens_cli.io.resources import Estimate

    given = [
        p
        for p in ctx.command.params
        if p.name not in PAIRS_OPTIONS and ctx.get_parameter_source(p.name) == click.core.ParameterSource.COMMANDLINE
    ]
    if ctx.params["specs"] or given:
        applying = [
            max(p.opts, key=len) for p in ctx.command.params if p.name in PAIRS_OPTIONS - {"pairs", "specs"} and p.opts
        ]
        raise InputError(
            "DESIGN" if not given else max(given[0].opts, key=len),
            "does not apply to --pairs (the designs are the folders of DIR)",
            f"--pairs DIR with only {', '.join(applying)}",
        )
    layout = read_layout(folder)
    for option, path in (("--csv", csv_path), ("--plot", plot_path)):
        if path is not None and Path(folder).resolve() in Path(path).resolve().parents:
            raise InputError(
                option,
                f"{path!r} is inside --pairs {folder!r}; a later run would read it as a capture",
                "an output path outside the pairs folder",
            )
    refuse_overwriting(
        [("--csv", csv_path), ("--plot", plot_path)],
        [*layout.gt.values(), *(p for d in layout.captures.values() for paths in d.values() for p in paths.values())],
    )
    task_model, model_truth = _pairs_model(*model, layout)
    memory, seconds = estimate_pairs(layout)
    if task_model is not None:  # the reference and every capture, once each
        seconds += task_model.seconds * (
            len(layout.gt) + sum(len(p) for d in layout.captures.values() for p in d.values())
        )
    announce(
        Estimate(
            f"evaluate --pairs of {len(layout.designs)} design(s) × {len(layout.names)} scene(s)",
            memory,
            "--pairs",
            seconds,
        ),
        max_memory,
    )
    lpips_model, notes = _lpips(lpips_weights)
    metrics = metric_names(lpips_model)
    with progress_bar("evaluate --pairs", quiet) as update:
        result = evaluate_pairs(layout, lpips_model, match, align, refine, update, tasks, task_model, model_truth)
    _report(
        result,
        layout.designs,
        layout.kinds,
        metrics,
        notes,
        csv_path,
        plot_path,
        as_json,
        {
            "photometric_match": match,
            "pairs": str(folder),
            "alignment": align,
            "refine": refine,
            "alignments": result.alignments,
        },
        f"Captures vs gt: mean [95 % CI] over {len(result.images)} scenes",
    )


def _reconstructors(runs, designs, device) -> list:
    """One reconstructor (or None) per design from --recon, each checked to be made for its design."""
    from metalens_cli.errors import InputError

    names = [name.strip() for text in runs for name in text.split(",")]
    if not names:
        return [None] * len(designs)
    if len(names) != len(designs):
        raise InputError(
            "--recon", f"{len(names)} runs for {len(designs)} designs", "one run (or '-') per DESIGN, in order"
        )
    from metalens_cli.imaging.restore import design_fingerprint, load_reconstructor

    out = []
    for name, design in zip(names, designs):
        if name == "-":
            out.append(None)
            continue
        recon = load_reconstructor(name, device, field_name="--recon")
        made_for = recon.design.get("fingerprint")
        if made_for != design_fingerprint(design):
            raise InputError(
                "--recon",
                f"{name!r} was trained for {recon.design.get('spec')!r}, not for {design.spec!r}",
                "the reconstruction run of each DESIGN, in order",
            )
        out.append(recon)
    return out


def _short(metric: str) -> str:
    return {"psnr_db": "PSNR", "ssim": "SSIM", "lpips": "LPIPS"}[metric]


def _ci(mean: float, ci, digits: int, lines: bool = True) -> str:
    """The mean and, below it (or beside it), its interval; signed when either can be negative."""
    f = f"{{:{'+' if mean < 0 or ci[0] < 0 else ''}.{digits}f}}"
    return f"{f.format(mean)}{chr(10) if lines else ' '}[{f.format(ci[0])}, {f.format(ci[1])}]"


def _table_rows(result, kinds, metrics, light=None) -> list[list[str]]:
    """The paper's Suppl. table layout: per design, rows Raw (Wiener, Recon) Unobs., Obs., Δ;
    columns per obstruction and metric; the rows of one ``light`` level (None: without levels)."""
    digits = {"psnr_db": 2, "ssim": 3, "lpips": 3}
    table = []
    rows = [r for r in result.rows if r.get("light") == light]
    deltas = [x for x in result.deltas if x.get("light") == light]
    for design, capture in dict.fromkeys((r["design"], r["capture"]) for r in rows):
        for condition in ("unobstructed", "obstructed", "delta"):
            cells = []
            for kind in kinds:
                if condition == "delta":
                    d = next(
                        x for x in deltas if (x["design"], x["capture"], x["obstruction"]) == (design, capture, kind)
                    )
                    cells += [_ci(d[f"delta_{m}"], d[f"delta_{m}_ci"], digits[m]) for m in metrics]
                else:
                    r = next(
                        x
                        for x in rows
                        if (x["design"], x["capture"], x["obstruction"], x["condition"])
                        == (design, capture, kind, condition)
                    )
                    cells += [_ci(r[m], r[f"{m}_ci"], digits[m]) for m in metrics]
            first = condition == "unobstructed" and capture == "raw"
            table.append([design if first else "", f"{capture.capitalize()} {LABELS[condition]}", *cells])
    return table
