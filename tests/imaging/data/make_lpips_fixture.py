"""Write lpips_alex_reference.json: LPIPS distances from the lpips package itself, the reference
that tests/imaging/test_lpips.py checks metalens_cli.imaging.lpips against.

The published AlexNet weights cannot be downloaded here, so the package's network is built
without them (``lpips.LPIPS(net="alex", pretrained=True, pnet_rand=True)``: the v0.1 linear
calibration ``weights/v0.1/alex.pth`` that the wheel ships, a random AlexNet trunk) and given
deterministic trunk weights instead: ``metric_references.alexnet_features(seed)`` (numpy
normal, He-scaled), which the test regenerates identically. The image pairs are
``metric_references.LPIPS_PAIRS`` (seeded numpy textures, 64 × 64: noise, blur, a shift, a
colour change, ...). The JSON keeps the recipes, the distances, the package versions and the
sha256 of the weights; the package's alex.pth (6 kB) is copied beside it as
lpips_v0.1_alex.pth.

Rerun (the packages go into a temporary folder, not the project's environment; torchvision's
version must match torch's, 0.28.0 for torch 2.13.0)::

    pip download lpips==0.1.4 torchvision==0.28.0 tqdm --no-deps -d /tmp/lpips-wheels
    pip install --no-deps --target /tmp/lpips-ref /tmp/lpips-wheels/*.whl
    PYTHONPATH=/tmp/lpips-ref:. python tests/imaging/data/make_lpips_fixture.py

torchvision's PyPI wheel is built for CUDA torch: against the CPU build its compiled operators
(nms, roi_align, ...) do not load and its fake-tensor registrations for them fail at import, so
those registrations are skipped while importing it (AlexNet needs none of them).
"""

import datetime
import hashlib
import importlib.metadata
import json
import shutil
import sys
import warnings
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # tests/, for metric_references

from metric_references import LPIPS_PAIRS, alexnet_features, lpips_pair, state_sha256  # noqa: E402

SEED = 0
JSON_OUT = HERE / "lpips_alex_reference.json"
LIN_OUT = HERE / "lpips_v0.1_alex.pth"


def import_lpips():
    register_fake = torch.library.register_fake
    torch.library.register_fake = lambda *args, **kwargs: lambda f: f  # see the docstring
    try:
        import torchvision
    finally:
        torch.library.register_fake = register_fake
    import lpips

    return lpips, torchvision


def dumps(reference: dict) -> str:
    """Indented JSON with one line per pair."""
    head = json.dumps({k: v for k, v in reference.items() if k != "pairs"}, indent=1)[:-2]
    pairs = ",\n  ".join(json.dumps(row) for row in reference["pairs"])
    return f'{head},\n "pairs": [\n  {pairs}\n ]\n}}\n'


def main():
    lpips, torchvision = import_lpips()
    features = {k: torch.from_numpy(v) for k, v in alexnet_features(SEED).items()}
    # the generated state dict has torchvision's layout: it loads into torchvision's AlexNet as is
    missing, unexpected = torchvision.models.alexnet(weights=None).load_state_dict(features, strict=False)
    assert not unexpected and all(k.startswith("classifier.") for k in missing), (missing, unexpected)

    with warnings.catch_warnings():  # torchvision's deprecation of the `pretrained` argument lpips passes
        warnings.simplefilter("ignore", UserWarning)
        model = lpips.LPIPS(net="alex", version="0.1", pretrained=True, pnet_rand=True, verbose=False).eval()
    state = model.state_dict()
    trunk = [k for k in state if k.startswith("net.")]  # net.slice<s>.<features index>.<weight|bias>
    assert sorted(f"features.{k.split('.', 2)[2]}" for k in trunk) == sorted(features)
    state.update({k: features[f"features.{k.split('.', 2)[2]}"] for k in trunk})
    model.load_state_dict(state)

    lin_path = Path(lpips.__file__).parent / "weights" / "v0.1" / "alex.pth"
    for n in range(5):  # the calibration in use is the shipped file's
        shipped = torch.load(lin_path, map_location="cpu")[f"lin{n}.model.1.weight"]
        assert torch.equal(model.state_dict()[f"lin{n}.model.1.weight"], shipped)

    rows = []
    with torch.no_grad():
        for recipe in LPIPS_PAIRS:
            x, y = (torch.from_numpy(a).float()[None] for a in lpips_pair(recipe))
            d = float(model(x, y, normalize=True).reshape(()))  # normalize: 0..1 → -1..1
            rows.append({**recipe, "x_mean": float(x.double().mean()), "y_mean": float(y.double().mean()), "lpips": d})
            print(f"{recipe['name']:>14}  {d:.6f}")

    shutil.copyfile(lin_path, LIN_OUT)
    sha = hashlib.sha256(lin_path.read_bytes()).hexdigest()
    reference = {
        "about": (
            "LPIPS v0.1 'alex' distances from the lpips package (lpips.LPIPS(net='alex', version='0.1', "
            "pretrained=True, pnet_rand=True), forward(x, y, normalize=True) on float32 1 x 3 x 64 x 64 "
            "images in 0..1) with the package's shipped linear calibration weights/v0.1/alex.pth (copied "
            "as lpips_v0.1_alex.pth) and AlexNet trunk weights from metric_references.alexnet_features(seed) "
            "instead of the published ImageNet ones (not downloadable here). Pairs: "
            "metric_references.lpips_pair(recipe); x_mean, y_mean check their regeneration. "
            "Written by make_lpips_fixture.py."
        ),
        "date": datetime.date.today().isoformat(),
        "versions": {name: importlib.metadata.version(name) for name in ("lpips", "torchvision", "torch", "numpy")},
        "lin_file_sha256": sha,
        "alexnet_seed": SEED,
        "alexnet_sha256": state_sha256(alexnet_features(SEED)),
        "pairs": rows,
    }
    JSON_OUT.write_text(dumps(reference))
    print(f"wrote {JSON_OUT} and {LIN_OUT} (sha256 {sha})")


if __name__ == "__main__":
    main()
