"""DA feature loss: DeepLabv3+ encoder (ResNet OS16 + ASPP) from a VainF-format checkpoint.

The checkpoint is a random-weight ResNet-50 written once per module in the public
VainF/DeepLabV3Plus-Pytorch layout ({"model_state": ..., "best_score": numpy float, ...}).
Error-path checkpoints use stride-0 expanded tensors so that they stay a few kB on disk.
"""

import datetime

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from metalens_cli.design import features
from metalens_cli.design.features import (
    ENV_VAR,
    SKIP_NOTE,
    DeepLabFeatures,
    feature_l1,
    find_deeplab_weights,
    load_feature_extractor,
)
from metalens_cli.errors import InputError


@pytest.fixture(scope="module", autouse=True)
def _one_thread():
    """One intra-op thread: on a small shared CI box, OpenMP spin-waiting beside other jobs costs ~20×."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _randomised_state(depth=50, seed=0):
    """A state_dict with He-initialised convs and non-trivial BatchNorm statistics."""
    torch.manual_seed(seed)
    model = DeepLabFeatures(depth)
    for m in model.modules():
        if isinstance(m, torch.nn.Conv2d):
            torch.nn.init.kaiming_normal_(m.weight, nonlinearity="relu")
        elif isinstance(m, torch.nn.BatchNorm2d):
            m.weight.uniform_(0.5, 1.5)
            m.bias.uniform_(-0.1, 0.1)
            m.running_mean.normal_(0.0, 0.1)
            m.running_var.uniform_(0.5, 2.0)
    return model.state_dict()


def _tiny_state(depth=50, separable=False):
    """Every key the loader uses, at the right shape, but backed by one element per tensor."""
    with torch.device("meta"):
        state = DeepLabFeatures(depth, separable).state_dict()
    return {k: torch.zeros((), dtype=v.dtype).expand(v.shape) for k, v in state.items()}


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    state = dict(_randomised_state())
    state["classifier.project.0.weight"] = torch.randn(48, 256, 1, 1)  # decoder: must be ignored
    state["classifier.classifier.3.weight"] = torch.randn(21, 256, 1, 1)
    path = tmp_path_factory.mktemp("deeplab") / "best_deeplabv3plus_resnet50_voc_os16.pth"
    torch.save({"cur_itrs": 30000, "model_state": state, "best_score": np.float64(0.77)}, path)
    return path


@pytest.fixture(scope="module")
def extractor(checkpoint):
    return load_feature_extractor(checkpoint)


@pytest.fixture
def own_cache(monkeypatch):
    """Loads of throw-away checkpoints go to a private cache, leaving the module's extractor cached."""
    monkeypatch.setattr(features, "_CACHE", {})


@pytest.fixture
def images():
    g = torch.Generator().manual_seed(1)
    return torch.rand(2, 3, 65, 65, generator=g), torch.rand(2, 3, 65, 65, generator=g)


# ---------------------------------------------------------------- discovery


def test_discovery_by_argument_wins_over_env(tmp_path, monkeypatch):
    arg, env = tmp_path / "a.pth", tmp_path / "b.pth"
    arg.write_bytes(b"x")
    env.write_bytes(b"x")
    monkeypatch.setenv(ENV_VAR, str(env))
    assert find_deeplab_weights(arg) == (arg, None)
    assert find_deeplab_weights(str(arg)) == (arg, None)


def test_discovery_by_env_var(tmp_path, monkeypatch):
    env = tmp_path / "b.pth"
    env.write_bytes(b"x")
    monkeypatch.setenv(ENV_VAR, str(env))
    assert find_deeplab_weights() == (env, None)


def test_discovery_absent_gives_one_line_note(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    path, note = find_deeplab_weights()
    assert path is None and note == SKIP_NOTE
    assert "\n" not in note and ENV_VAR in note and "loss.domain_adaptation_weights" in note
    assert "no download" in note
    monkeypatch.setenv(ENV_VAR, "  ")  # blank counts as unset
    assert find_deeplab_weights() == (None, SKIP_NOTE)


def test_discovery_named_but_missing_file_is_an_error(tmp_path, monkeypatch):
    with pytest.raises(InputError) as err:
        find_deeplab_weights(tmp_path / "nope.pth")
    assert err.value.field == "loss.domain_adaptation_weights"
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "gone.pth"))
    with pytest.raises(InputError) as err:
        find_deeplab_weights()
    assert err.value.field == ENV_VAR


# ---------------------------------------------------------------- the loss


def test_loss_zero_for_same_image_positive_otherwise(extractor, images):
    x, y = images
    assert float(feature_l1(extractor, x, x)) == 0.0
    loss = feature_l1(extractor, x, y)
    assert loss.ndim == 0 and torch.isfinite(loss) and float(loss) > 0.0
    low_x, aspp_x = extractor(x)
    low_y, aspp_y = extractor(y)
    expected = (low_x - low_y).abs().mean() + (aspp_x - aspp_y).abs().mean()
    torch.testing.assert_close(loss, expected)
    assert float(feature_l1(extractor, x[0], y[0])) > 0.0  # unbatched (3, H, W) works too


def test_gradient_reaches_input_not_weights(extractor, images):
    x, y = images
    x = x.double().requires_grad_(True)
    loss = feature_l1(extractor, x, y.double())
    assert loss.dtype == torch.float64
    loss.backward()
    assert x.grad is not None and x.grad.dtype == torch.float64
    assert torch.isfinite(x.grad).all() and x.grad.abs().sum() > 0
    assert all(not p.requires_grad and p.grad is None for p in extractor.parameters())


def test_module_frozen_and_stays_in_eval(extractor, images):
    extractor.train()
    assert not any(m.training for m in extractor.modules())
    assert not any(t.is_meta for t in [*extractor.parameters(), *extractor.buffers()])
    assert all(p.dtype == torch.float32 and p.is_contiguous() for p in extractor.parameters())
    x, _ = images
    # Eval BatchNorm: a sample's features do not depend on the rest of the batch.
    alone, batched = extractor(x[:1])[1], extractor(x)[1][:1]
    torch.testing.assert_close(alone, batched, rtol=1e-4, atol=1e-5 * float(batched.abs().max()))


def test_imagenet_normalisation_inside(extractor, images):
    x, _ = images
    mean = torch.tensor([0.485, 0.456, 0.406]).view(1, 3, 1, 1)
    std = torch.tensor([0.229, 0.224, 0.225]).view(1, 3, 1, 1)
    low, _ = extractor.backbone((x - mean) / std)
    torch.testing.assert_close(extractor(x)[0], low)


def test_loader_caches_per_path(checkpoint, extractor):
    assert load_feature_extractor(checkpoint) is extractor
    assert load_feature_extractor(str(checkpoint)) is extractor
    assert extractor.depth == 50 and not extractor.separable


# ---------------------------------------------------------------- architecture


def test_output_stride_16_and_aspp_channels(extractor):
    x = torch.rand(1, 3, 64, 64)
    low, high = extractor.backbone(extractor.normalise(x))
    assert tuple(low.shape) == (1, 256, 16, 16)
    assert tuple(high.shape) == (1, 2048, 4, 4)  # OS16: layer4 keeps layer3's resolution
    _, aspp = extractor(x)
    assert tuple(aspp.shape) == (1, 256, 4, 4)
    assert [extractor.classifier.aspp.convs[i][0].dilation for i in (1, 2, 3)] == [(6, 6), (12, 12), (18, 18)]


def _bn(x, bn):
    """Eval BatchNorm written out: (x − μ) / √(σ² + ε) · γ + β."""
    shape = (1, -1, 1, 1)
    scale = bn.weight.view(shape) / torch.sqrt(bn.running_var.view(shape) + bn.eps)
    return (x - bn.running_mean.view(shape)) * scale + bn.bias.view(shape)


def _reference_bottleneck(x, blk, stride, dilation, downsample):
    out = F.relu(_bn(F.conv2d(x, blk.conv1.weight), blk.bn1))
    out = F.relu(_bn(F.conv2d(out, blk.conv2.weight, stride=stride, padding=dilation, dilation=dilation), blk.bn2))
    out = _bn(F.conv2d(out, blk.conv3.weight), blk.bn3)
    shortcut = _bn(F.conv2d(x, blk.downsample[0].weight, stride=stride), blk.downsample[1]) if downsample else x
    return F.relu(out + shortcut)


@pytest.mark.parametrize(
    "stage, index, cin, stride, dilation, downsample",
    [
        (2, 0, 256, 2, 1, True),  # strided first block of layer2, projection shortcut
        (4, 0, 1024, 1, 1, True),  # OS16: layer4 entry block loses its stride, keeps dilation 1
        (4, 1, 2048, 1, 2, False),  # dilated layer4 block, identity shortcut
    ],
)
def test_bottleneck_matches_explicit_functional(extractor, stage, index, cin, stride, dilation, downsample):
    blk = getattr(extractor.backbone, f"layer{stage}")[index]
    x = torch.randn(1, cin, 9, 9, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(
        blk(x), _reference_bottleneck(x, blk, stride, dilation, downsample), rtol=1e-5, atol=1e-5
    )


# ---------------------------------------------------------------- checkpoint variants and errors


def test_resnet101_and_separable_aspp_detected_from_keys(tmp_path, own_cache):
    state = {"module." + k: v for k, v in _tiny_state(101, separable=True).items()}  # DataParallel prefix
    path = tmp_path / "best_deeplabv3plus_resnet101_cityscapes_os16.pth"
    torch.save({"model_state": state}, path)
    model = load_feature_extractor(path)
    assert model.depth == 101 and model.separable and len(model.backbone.layer3) == 23
    assert tuple(model(torch.rand(1, 3, 33, 33))[1].shape) == (1, 256, 3, 3)


def test_old_checkpoint_without_num_batches_tracked_loads(tmp_path, own_cache):
    state = {k: v for k, v in _tiny_state().items() if not k.endswith("num_batches_tracked")}
    path = tmp_path / "old.pth"
    torch.save({"model_state": state}, path)
    assert load_feature_extractor(path).depth == 50


def _expect_error(path, *fragments):
    with pytest.raises(InputError) as err:
        load_feature_extractor(path)
    assert err.value.field == str(path)
    assert "\n" not in str(err.value)
    for fragment in fragments:
        assert fragment in str(err.value)


def test_missing_key_is_an_error_naming_the_file(tmp_path, own_cache):
    state = _tiny_state()
    del state["classifier.aspp.project.0.weight"]
    path = tmp_path / "missing.pth"
    torch.save({"model_state": state}, path)
    _expect_error(path, "missing 1 key(s)", "classifier.aspp.project.0.weight")


def test_wrong_shape_is_an_error_naming_the_file(tmp_path, own_cache):
    state = _tiny_state()
    state["backbone.layer1.0.conv2.weight"] = torch.zeros(()).expand(64, 64, 1, 1)
    path = tmp_path / "shape.pth"
    torch.save({"model_state": state}, path)
    _expect_error(path, "backbone.layer1.0.conv2.weight", "(64, 64, 1, 1)", "(64, 64, 3, 3)")


def test_unknown_backbone_and_bad_files_are_errors(tmp_path, own_cache):
    state = {k: v for k, v in _tiny_state().items() if not k.startswith("backbone.layer3.5.")}
    torch.save({"model_state": state}, tmp_path / "resnet-odd.pth")
    _expect_error(tmp_path / "resnet-odd.pth", "(3, 4, 5, 3)")
    mobilenet = {"backbone.low_level_features.0.0.weight": torch.zeros(32, 3, 3, 3)}
    torch.save({"model_state": mobilenet}, tmp_path / "best_deeplabv3plus_mobilenet_voc_os16.pth")
    _expect_error(tmp_path / "best_deeplabv3plus_mobilenet_voc_os16.pth", "no ResNet backbone keys")
    torch.save({"state_dict": {}}, tmp_path / "other.pth")
    _expect_error(tmp_path / "other.pth", "model_state")
    (tmp_path / "junk.pth").write_bytes(b"not a checkpoint")
    _expect_error(tmp_path / "junk.pth", "not a readable torch checkpoint")
    torch.save({"model_state": _tiny_state(), "when": datetime.date(2020, 1, 1)}, tmp_path / "pickled.pth")
    _expect_error(tmp_path / "pickled.pth", "datetime.date", "weights-only")
    with pytest.raises(InputError):
        load_feature_extractor(tmp_path / "absent.pth")


def test_cache_is_bounded(tmp_path, own_cache):
    paths = []
    for i in range(features._CACHE_SIZE + 1):
        paths.append(tmp_path / f"c{i}.pth")
        torch.save({"model_state": _tiny_state()}, paths[-1])
        load_feature_extractor(paths[-1])
    assert len(features._CACHE) <= features._CACHE_SIZE
    assert all(key[0] != str(paths[0].resolve()) for key in features._CACHE)
