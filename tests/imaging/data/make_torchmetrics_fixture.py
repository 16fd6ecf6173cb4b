"""Write torchmetrics_ssim_psnr.json: torchmetrics' SSIM and PSNR of the pairs
``metric_references.ssim_pairs()`` (the astronaut photograph with noise, blur, a constant shift
and a colour change; two textures), the reference that tests/imaging/test_metrics.py checks
metalens_cli.imaging.metrics against without needing torchmetrics (not a project dependency).

SSIM is stored twice: torchmetrics' own value (``ssim_full``: its reflect-padded map averaged
over every pixel, borders included) and its map (``return_full_image=True``) averaged over the
positions whose 11 × 11 window lies inside the image (``ssim_valid``: this package's and
scikit-image's convention). PSNR per image (``dim=(1, 2, 3)``) and torchmetrics' default for
the whole batch (``psnr_pooled``: one MSE over all images' pixels).

Rerun (torchmetrics goes into a temporary folder, not the project's environment)::

    pip download torchmetrics==1.9.0 lightning-utilities --no-deps -d /tmp/tm-wheels
    pip install --no-deps --target /tmp/tm-ref /tmp/tm-wheels/*.whl
    PYTHONPATH=/tmp/tm-ref:. python tests/imaging/data/make_torchmetrics_fixture.py
"""

import datetime
import importlib.metadata
import json
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # tests/, for metric_references

from metric_references import ssim_pairs  # noqa: E402

JSON_OUT = HERE / "torchmetrics_ssim_psnr.json"
PAD = 5  # (11 - 1) / 2


def main():
    from torchmetrics.functional.image import peak_signal_noise_ratio, structural_similarity_index_measure

    pairs = ssim_pairs()
    x = torch.as_tensor(np.stack([p[0] for p in pairs.values()]))  # float64, (6, 3, 96, 128)
    y = torch.as_tensor(np.stack([p[1] for p in pairs.values()]))
    args = dict(gaussian_kernel=True, sigma=1.5, kernel_size=11, data_range=1.0, k1=0.01, k2=0.03, reduction="none")
    full, ssim_map = structural_similarity_index_measure(y, x, return_full_image=True, **args)
    assert torch.equal(full, structural_similarity_index_measure(y, x, **args))
    valid = ssim_map[..., PAD:-PAD, PAD:-PAD].mean(dim=(-3, -2, -1))
    psnr = peak_signal_noise_ratio(y, x, data_range=1.0, reduction="none", dim=(1, 2, 3))
    pooled = float(peak_signal_noise_ratio(y, x, data_range=1.0))
    rows = [
        {"name": name, "ssim_full": float(f), "ssim_valid": float(v), "psnr_db": float(p)}
        for name, f, v, p in zip(pairs, full, valid, psnr)
    ]
    for row in rows:
        print(row)
    reference = {
        "about": (
            "torchmetrics.functional.image on float64 (6, 3, 96, 128) batches of "
            "metric_references.ssim_pairs() (distorted as preds, reference as target): "
            "structural_similarity_index_measure(gaussian_kernel=True, sigma=1.5, kernel_size=11, "
            "data_range=1.0, k1=0.01, k2=0.03, reduction='none') as ssim_full; its return_full_image map "
            "cropped by 5 pixels on every side and averaged as ssim_valid; "
            "peak_signal_noise_ratio(data_range=1.0, reduction='none', dim=(1, 2, 3)) as psnr_db, and with "
            "its defaults (dim=None: one MSE over the whole batch) as psnr_pooled. "
            "Written by make_torchmetrics_fixture.py."
        ),
        "date": datetime.date.today().isoformat(),
        "versions": {name: importlib.metadata.version(name) for name in ("torchmetrics", "torch", "numpy")},
        "psnr_pooled": pooled,
        "pairs": rows,
    }
    head = json.dumps({k: v for k, v in reference.items() if k != "pairs"}, indent=1)[:-2]
    body = ",\n  ".join(json.dumps(row) for row in rows)
    JSON_OUT.write_text(f'{head},\n "pairs": [\n  {body}\n ]\n}}\n')
    print(f"wrote {JSON_OUT}")


if __name__ == "__main__":
    main()
