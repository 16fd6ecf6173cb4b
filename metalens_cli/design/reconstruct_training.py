"""Training the reconstruction network of one design (Suppl. Note 5) into a run directory.

    RUN/
      reconstruct.toml          the resolved reconstruction preset (steps and seed as run)
      design.json               the design (spec, geometry, fingerprint), camera and data source
      model.pt                  network shape, weights and design identity (imaging.restore)
      loss.csv, loss.png        one row per step: lr, loss terms, seconds
      validation/step_NNNNNN.png  raw | reconstruction | clean for the first validation pairs
      checkpoints/step_NNNNNN.pt  network, optimiser, schedule and history (the newest two)
      run.json                  settings, data, cost, validation history, notes

Each step draws everything from (seed, step) and the pool from (seed, generation), so a resumed
run repeats an uninterrupted one exactly. Loss l1·L1 + ssim·(1 − SSIM) + lpips·LPIPS between
the sRGB-encoded estimate and clean image (LPIPS only when its weights are found locally; the
run records the terms used). AdamW; the learning rate rises linearly from 0.1·lr over the
warm-up, then follows cosine annealing with warm restarts (Loshchilov & Hutter 2017). Under
torchrun every rank computes its share of the batch and gradients are summed.
"""

from __future__ import annotations

import copy
import json
import math
import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch

from metalens_cli import arguments
from metalens_cli.design import distributed
from metalens_cli.design.reconstruct_data import (
    VALIDATION_GENERATION,
    Camera,
    Pool,
    batch,
    psf_bank,
    read_pairs,
    simulate_pool,
)
from metalens_cli.design.rundir import RunDirectory
from metalens_cli.design.train_loop import TrainLoop, checkpoint_to_resume, overrides, update
from metalens_cli.errors import InputError
from metalens_cli.imaging.metrics import ssim
from metalens_cli.imaging.network import NetworkShape, ReconstructionNet
from metalens_cli.imaging.restore import MODEL_FILE, Reconstructor, design_fingerprint, save_model
from metalens_cli.io.image_files import srgb_encode_tensor
from metalens_cli.io.reconstruct_presets import (
    SECTIONS,
    ReconstructPreset,
    load_reconstruct_preset,
    reconstruct_to_toml,
)

PRESET_FILE = "reconstruct.toml"
COLUMNS = ("step", "lr", "total", "l1", "ssim", "lpips", "seconds", "data_seconds")
PREVIEWS = 3  # validation pairs drawn in validation/step_*.png


def run_directory(path: str | Path) -> RunDirectory:
    """The :class:`RunDirectory` of a ``metalens reconstruct train`` run at ``path``: preset file
    ``reconstruct.toml``, loss columns ``COLUMNS``."""
    return RunDirectory(path, PRESET_FILE, COLUMNS, "metalens reconstruct train")


def learning_rate_factor(step: int, t) -> float:
    """lr(step)/lr: linear warm-up 0.1 → 1 over ``t.warmup_steps``, then cosine annealing to 0
    with warm restarts every ``t.restart_period`` steps, the period growing × ``t.restart_growth``."""
    if step < t.warmup_steps:
        return 0.1 + 0.9 * step / t.warmup_steps
    k, period = step - t.warmup_steps, t.restart_period
    while k >= period:
        k, period = k - period, period * t.restart_growth
    return 0.5 * (1 + math.cos(math.pi * k / period))


def loss_terms(estimate: torch.Tensor, clean: torch.Tensor, weights, lpips_model=None) -> dict[str, torch.Tensor]:
    """Per-term batch means on sRGB-encoded images; ``total`` is the weighted sum."""
    x, y = srgb_encode_tensor(estimate), srgb_encode_tensor(clean)
    terms = {"l1": (x - y).abs().mean(), "ssim": 1 - ssim(x, y).mean()}
    if lpips_model is not None:
        from metalens_cli.imaging.lpips import lpips_distance

        terms["lpips"] = lpips_distance(lpips_model, x.clamp(0, 1), y).mean()
    terms["total"] = sum(getattr(weights, name) * value for name, value in terms.items())
    return terms


@dataclass
class ReconstructSummary:
    """What :func:`train_reconstruction` returns: the run directory and its report (the dict written
    to run.json)."""

    run_dir: Path
    report: dict


def train_reconstruction(
    design,
    camera: Camera,
    preset: ReconstructPreset | None,
    run_dir: str | Path,
    *,
    steps: int | None = None,
    seed: int | None = None,
    device="cpu",
    resume: bool = False,
    pairs: str | Path | None = None,
    lpips_weights: str | Path | None = None,
    on_step: Callable[[int, int, dict], None] | None = None,
    on_stage: Callable[[str], None] | None = None,
) -> ReconstructSummary:
    """Train the network for ``design`` (a resolved design) with ``preset`` into ``run_dir``.

    Args:
        design: the resolved design (:func:`resolve_design`); on resume, the one the run was made
            for.
        camera: the camera (``imaging.camera.Camera``: electrons at full scale before the filter,
            read electrons rms, zero-order leak).
        preset: the training settings; None: the defaults (a fresh run). On resume a ``preset``
            given must hold the same settings, steps and seed aside.
        run_dir: the run directory to write.
        steps: override the preset's step count (on resume: may extend it).
        seed: override the preset's seed.
        device: torch device.
        resume: continue from the newest checkpoint with the preset saved there.
        pairs: a folder of captured pairs instead of simulation.
        lpips_weights: a folder with the LPIPS weights (else looked up as ``evaluate`` does).
        on_step: ``on_step(done, total, row)`` reports each step.
        on_stage: ``on_stage(text)`` reports each stage.

    Returns:
        ``ReconstructSummary``: the run directory and the report.
    """
    from metalens_cli.io.designs import Design

    arguments.instance(design, "design", Design, "a Design (ml.resolve_design)")
    arguments.instance(camera, "camera", Camera, "a Camera (imaging.camera)")
    run_dir = arguments.path(run_dir, "run_dir", "a run directory")
    device = arguments.device(device)
    with distributed.session(device) as ctx:
        return _train(
            design,
            camera,
            preset,
            run_directory(run_dir),
            steps,
            seed,
            ctx,
            resume,
            pairs,
            lpips_weights,
            on_step or (lambda *a: None),
            on_stage or (lambda text: None),
        )


def _identity(design, camera: Camera, pairs) -> dict:
    return {
        "spec": design.spec,
        "fingerprint": design_fingerprint(design),
        **design.describe(),
        "camera": {
            "pixel_pitch_m": camera.pixel_pitch_m,
            "z_near_m": list(camera.z_near_m),
            "z_far_m": [z if math.isfinite(z) else None for z in camera.z_far_m],
        },
        "pairs": None if pairs is None else str(Path(pairs).resolve()),
    }


def _made_for(run: RunDirectory, identity: dict) -> dict:
    """The identity in the run's design.json. A run killed between writing its preset and its
    design.json (it has no checkpoint yet) is given this design's identity and starts over."""
    path = run.path / "design.json"
    if not path.exists() and not any(run.checkpoints.glob("step_*.pt")):
        run.write_text("design.json", json.dumps(identity, indent=2) + "\n")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise InputError(
            "--resume",
            f"{str(run.path)!r} lacks a readable design.json",
            "a run directory written by metalens reconstruct train",
        ) from None


def _train(
    design, camera, preset, run: RunDirectory, steps, seed, ctx, resume, pairs, lpips_weights, on_step, on_stage
) -> ReconstructSummary:
    identity = _identity(design, camera, pairs)
    if resume:
        run.check_resumable()
        preset = _resumed_preset(run, preset)
        made_for = _made_for(run, identity)
        if made_for.get("fingerprint") != identity["fingerprint"]:
            raise InputError(
                "DESIGN",
                f"{design.spec!r} is not the design the run was made for ({made_for.get('spec')!r})",
                "the run's own design",
            )
        pairs = made_for.get("pairs")
        identity["pairs"] = pairs
    given = overrides(steps, seed)
    preset = preset or ReconstructPreset("reconstruct")
    preset = replace(preset, train=replace(preset.train, **given))
    t = preset.train
    checkpoint = checkpoint_to_resume(run, resume, t.steps, lists=("validations",))
    lpips_model, notes = _lpips(t, lpips_weights)  # its files are checked before the data is built
    data = _Data(design, camera, preset, pairs, ctx.device, on_stage)
    torch.manual_seed(t.seed)
    n = preset.network
    net = ReconstructionNet(
        NetworkShape(n.width, n.depth, n.frequencies, n.reduction, data.position_scale, n.spectral_bins)
    ).to(ctx.device, memory_format=torch.channels_last)  # oneDNN's fast layout
    optimizer = torch.optim.AdamW(net.parameters(), lr=t.learning_rate, weight_decay=t.weight_decay)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda s: learning_rate_factor(s, t))
    if ctx.is_main and not resume:  # only now: every check above has passed
        run.create(reconstruct_to_toml(preset), folders=("validation",))
        run.write_text("design.json", json.dumps(identity, indent=2) + "\n")
    validations: list[dict] = []  # one row per validation pass, kept in the checkpoints
    loop = TrainLoop(
        run,
        ctx,
        t.steps,
        t.checkpoint_every,
        {"model": net, "optimizer": optimizer, "scheduler": scheduler},
        lambda: {"validations": validations},
        lambda state: validations.extend(state["validations"]),
    )
    loop.resume(checkpoint, reconstruct_to_toml(preset) if resume and given else None)
    shard = ctx.shard(t.batch_size)
    share = len(shard) / t.batch_size
    if ctx.is_main and not validations:
        validations.append(_validate(net, data, 0, run, ctx))

    def one_step(step: int) -> dict:
        t0 = time.perf_counter()
        pool = data.pool_for(step)
        b = batch(pool, preset.data, t.crop, t.seed, step, shard, ctx.device)
        t1 = time.perf_counter()
        optimizer.zero_grad(set_to_none=True)
        net.train()
        terms = loss_terms(
            net(b.inputs.contiguous(memory_format=torch.channels_last), b.positions, b.means),
            b.targets,
            t,
            lpips_model,
        )
        (terms["total"] * share).backward()
        reported = torch.stack([terms[k].detach() * share for k in sorted(terms)]).double()
        update(optimizer, scheduler, reported, ctx)
        return {
            "step": step + 1,
            "lr": optimizer.param_groups[0]["lr"],
            **dict(zip(sorted(terms), reported.tolist())),
            "data_seconds": t1 - t0,
        }

    def after_step(done: int) -> None:
        if done % t.validate_every == 0 or done == t.steps:
            validations.append(_validate(net, data, done, run, ctx))

    on_stage("training")
    loop.train(one_step, on_step, after_step)
    report: dict = {}
    if ctx.is_main:
        history, start, notes = loop.history, loop.start, notes + data.warnings
        report = _finish(run, preset, net, identity, data, history, validations, start, notes, lpips_model, ctx)
    return ReconstructSummary(run.path, report)


def _resumed_preset(run: RunDirectory, given: ReconstructPreset | None) -> ReconstructPreset:
    """The preset saved in ``run``; ``given`` (--preset with --resume) must hold the same settings
    but for train.steps and train.seed (which --steps and --seed set)."""
    saved = load_reconstruct_preset(run.preset_path)
    if given is None:
        return saved
    for section in SECTIONS:
        mine, theirs = getattr(saved, section), getattr(given, section)
        for f in fields(mine):
            was, now = getattr(mine, f.name), getattr(theirs, f.name)
            if was != now and (section, f.name) not in (("train", "steps"), ("train", "seed")):
                raise InputError(
                    "--preset",
                    f"{given.source or given.name} sets {section}.{f.metadata['key']} = {now!r}, but the run "
                    f"in {str(run.path)!r} was made with {was!r}",
                    f"no --preset with --resume (the run goes on with its own {PRESET_FILE}), or that same preset",
                )
    return saved


class _Data:
    """The run's training and validation pools (simulated or captured) and what they cost."""

    def __init__(self, design, camera: Camera, preset: ReconstructPreset, pairs, device, on_stage):
        self.design, self.camera, self.preset, self.device = design, camera, preset, device
        self.warnings: list[str] = []
        self.pool_bytes = 0
        self.photos = None
        self.bank = None
        self.seconds = {"psf_bank": 0.0, "pools": 0.0}
        d = preset.data
        if pairs is not None:
            on_stage("reading pairs")
            self.pool, self.validation = read_pairs(pairs)
            if self.pool.clean.shape[-1] < preset.train.crop:
                raise InputError(
                    "--pairs",
                    f"images of {self.pool.clean.shape[-1]} px are smaller than train.crop {preset.train.crop}",
                    "captures at least as large as the crop",
                )
            self.generation = None
        else:
            self.pool_bytes = pool_bytes(d.pool_size + d.validation_pairs, d.pool_pixels)
            physical = _physical_memory()
            if physical and self.pool_bytes > physical / 2:
                raise InputError(
                    "data.pool_size",
                    f"{d.pool_size} pairs of {d.pool_pixels}² px need {self.pool_bytes / 2**30:.1f} GiB, "
                    f"over half of this machine's {physical / 2**30:.1f} GiB",
                    "a smaller pool_size or pool_pixels",
                )
            on_stage("PSF bank")
            self.bank = psf_bank(design, camera, d, device)
            self.seconds["psf_bank"] = self.bank.report()["seconds"]
            self.warnings = self.bank.warnings()
            if d.images is not None:
                from metalens_cli.imaging.images import load_images

                n = 2 * (d.pool_pixels + 2 * self.bank.margin)
                self.photos = [image.linear for image in load_images(d.images, (n, n))]
            on_stage("validation pairs")
            self.validation = self._simulate(VALIDATION_GENERATION, d.validation_pairs)
            self.generation, self.pool = None, None
        self.position_scale = self.validation.sensor / 2  # positions in units of half the sensor's side

    def _simulate(self, generation: int, count: int) -> Pool:
        pool = simulate_pool(
            self.design,
            self.camera,
            self.preset.data,
            self.bank,
            self.preset.train.seed,
            generation,
            count,
            self.photos,
            self.device,
            torch.get_num_threads(),
        )
        self.seconds["pools"] += pool.seconds
        return pool

    def pool_for(self, step: int) -> Pool:
        """The pool step ``step`` crops from (regenerated every ``data.pool_refresh`` steps)."""
        if self.bank is None:
            return self.pool
        refresh = self.preset.data.pool_refresh
        generation = step // refresh if refresh else 0
        if generation != self.generation:
            self.pool, self.generation = self._simulate(generation, self.preset.data.pool_size), generation
        return self.pool

    def report(self) -> dict:
        source = (
            {"kind": "captured pairs"} if self.bank is None else {"kind": "simulated", "psf_bank": self.bank.report()}
        )
        return {
            **source,
            "pool_entries": len(self.pool) if self.pool is not None else 0,
            "validation_entries": len(self.validation),
            "pool_pixels": int(self.validation.clean.shape[-1]),
            "pool_bytes": self.pool_bytes,
            "seconds": self.seconds,
        }


def pool_bytes(entries: int, pixels: int) -> int:
    """Memory (bytes) of ``entries`` simulated pairs: clean, obstructed and unobstructed float32 RGB."""
    return 3 * entries * 3 * pixels * pixels * 4


def _physical_memory() -> int | None:
    import os

    try:
        return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def _lpips(t, directory) -> tuple[object, list[str]]:
    if t.lpips <= 0:
        return None, []
    from metalens_cli.imaging.lpips import Lpips, find_lpips_weights

    paths, note = find_lpips_weights(directory)
    if paths is None:
        return None, [f"LPIPS term left out: {note}"]
    return Lpips.from_files(paths.alexnet, paths.lin), []


def _validate(net, data: _Data, step: int, run: RunDirectory, ctx) -> dict:
    """Mean PSNR/SSIM (photometric match, sRGB) of raw and reconstructed validation captures,
    obstructed and clear; a preview image of the first pairs."""
    from metalens_cli.imaging.pipeline import score
    from metalens_cli.io.image_files import linear_to_srgb, write_png

    recon = Reconstructor(
        copy.deepcopy(net).eval(), device=ctx.device
    )  # a copy: apply's layout must not reach training
    pool = data.validation
    row: dict = {"step": step}
    previews = []
    for condition, captures in (("obstructed", pool.obstructed), ("unobstructed", pool.unobstructed)):
        if condition == "unobstructed" and pool.obstructed is pool.unobstructed:
            continue
        raw, rec = [], []
        for k in range(len(pool)):
            estimate = recon(captures[k])
            raw.append(score(captures[k], pool.clean[k]))
            rec.append(score(estimate, pool.clean[k]))
            if condition == "obstructed" and k < PREVIEWS:
                previews.append(np.concatenate([captures[k], estimate, pool.clean[k]], axis=-1))
        for name, scores in (("raw", raw), ("recon", rec)):
            for metric in ("psnr_db", "ssim"):
                row[f"{name}_{condition}_{metric}"] = statistics.fmean(s[metric] for s in scores)
    (run.path / "validation").mkdir(exist_ok=True)  # a resumed run killed while its folder was being made
    write_png(
        run.path / "validation" / f"step_{step:06d}.png",
        linear_to_srgb(np.clip(np.concatenate(previews, axis=-2), 0, 1)),
    )
    return row


def _finish(
    run: RunDirectory, preset, net, identity, data: _Data, history, validations, start, notes, lpips_model, ctx
) -> dict:
    from metalens_cli.io.presets import to_dict
    from metalens_cli.plotting.optimize import loss_figure

    terms = ["l1", "ssim"] + (["lpips"] if lpips_model is not None else [])
    save_model(
        run.path / MODEL_FILE,
        net,
        {"spec": identity["spec"], "fingerprint": identity["fingerprint"]},
        {"loss_terms": terms, "steps": preset.train.steps},
    )
    run.write_loss_csv(history)
    loss_figure(run.path / "loss.png", history, parts=("total", *terms))
    rows = history[start:]
    final = validations[-1]
    report = {
        "design": identity,
        "settings": {name: to_dict(getattr(preset, name)) for name in SECTIONS},
        "loss_terms": terms,
        "data": data.report(),
        "network": {**net.shape.to_dict(), "parameters": sum(p.numel() for p in net.parameters())},
        "cost": {
            "steps_run": len(rows),
            "seconds_per_step_median": statistics.median(r["seconds"] for r in rows) if rows else None,
            "data_seconds_per_step_median": statistics.median(r["data_seconds"] for r in rows) if rows else None,
            "training_seconds": sum(r["seconds"] for r in rows),
            "setup_seconds": data.seconds,
            "device": str(ctx.device),
            "threads": torch.get_num_threads(),
            "world": ctx.world,
        },
        "validation": {
            "history": validations,
            "final": final,
            "gain_obstructed_psnr_db": final["recon_obstructed_psnr_db"] - final["raw_obstructed_psnr_db"],
        },
        "notes": notes,
    }
    run.write_text("run.json", json.dumps(report, indent=2, allow_nan=False) + "\n")
    return report
