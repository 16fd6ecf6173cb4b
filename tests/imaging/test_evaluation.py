"""The evaluation protocol end to end on the paper's lens: obstruction costs a hyperbolic lens."""

import numpy as np

from metalens_cli.imaging.evaluation import EvaluationSettings, delta, evaluate
from metalens_cli.io.designs import resolve_design


def test_dirt_degrades_a_hyperbolic_lens():
    """Δ PSNR = obstructed − unobstructed < 0 with its whole 95 % interval, on built-in images × seeds
    (128² sensor: on 64² a near blur of ~300 px is a uniform veil that the photometric match removes)."""
    design = resolve_design("hyperbolic:532nm", None, 4e-3, 2.516e-3, None)
    settings = EvaluationSettings(128, 1.85e-6, (0.04, 0.05), (1.0, 20.0), list(np.arange(420e-9, 681e-9, 40e-9)), limit=6)
    result = evaluate([design], ["dirt"], [0, 1], settings)
    (row,) = result.deltas
    assert row["n"] == 12 and len(result.units) == 12
    assert row["delta_psnr_db"] < 0 and row["delta_psnr_db_ci"][1] < 0, row
    assert row["delta_ssim"] < 0
    assert result.warnings == []


def test_delta_sign_convention():
    assert delta("psnr_db", 20.0, 19.0) == -1.0 and delta("ssim", 0.5, 0.4) < 0
    assert delta("lpips", 0.3, 0.4) < 0  # LPIPS: lower is better, so a rise is a degradation
