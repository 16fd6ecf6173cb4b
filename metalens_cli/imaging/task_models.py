"""A user's own vision model on the captures: load it, run it, decode what it returns.

A spec (``--task-model``) is a file or a callable:

- ``.onnx``: run by onnxruntime (the optional extra ``metalens-cli[tasks]``), on CUDA when the
  device is one and onnxruntime has it;
- ``.pt2``: a ``torch.export`` program; ``.pt``, ``.ts``, ``.torchscript``: TorchScript;
- ``module:callable``: a Python callable, importable from the working directory or the path.

Input: a model file gets float32 N × 3 × H × W sRGB in 0..1 (YOLO's convention) at its input's
fixed size where it declares one (resized: the sensor is square), else at the capture's; a
callable gets uint8 N × H × W × 3 sRGB. Captures are auto-levelled as the built-in detectors see
them (``task_detection.to_rgb8``).

Output of a ``detect`` model, either
- (N, K, 6): boxes x1, y1, x2, y2, score, class (an end-to-end or NMS'd export), or
- (N, 4 + C, A): a raw YOLOv8/11 head, cx, cy, w, h and C class scores per anchor, decoded here:
  each anchor's best class, score ≥ ``MIN_SCORE``, non-maximum suppression per class at IoU
  ``NMS_IOU``, at most ``MAX_DETECTIONS`` kept;
in the model's input pixels, scaled back to the capture's. Of a ``segment`` model, either
(N, C, H, W) per-class logits or probabilities (the argmax; with C = 1 foreground where the
value passes 0.5, or 0 for logits outside 0..1), or (N, H, W) class indices; brought to the
capture's size by nearest neighbour.
"""

from __future__ import annotations

import importlib
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from metalens_cli.errors import InputError

KINDS = ("detect", "segment")
MODEL_SUFFIXES = (".onnx", ".pt2", ".pt", ".ts", ".torchscript")
MIN_SCORE = 0.001  # detections kept for mAP (COCO evaluates the whole ranking)
NMS_IOU = 0.7
MAX_DETECTIONS = 300
FORM = "a .onnx, .pt2 or TorchScript (.pt, .ts, .torchscript) file, or module:callable"


@dataclass(frozen=True)
class Detections:
    """One image's detections: ``boxes`` (K, 4) x1, y1, x2, y2 in the capture's pixels (edges, so a
    box over pixels 0..9 spans 0 to 10), ``scores`` (K,), ``classes`` (K,) integers."""

    boxes: np.ndarray
    scores: np.ndarray
    classes: np.ndarray

    def above(self, score: float) -> Detections:
        """Those scoring at least ``score``."""
        keep = self.scores >= score
        return Detections(self.boxes[keep], self.scores[keep], self.classes[keep])


@dataclass
class TaskModel:
    """A loaded model: ``kind`` ("detect" or "segment"), ``source`` (its spec), ``run`` (uint8
    N × H × W × 3 sRGB → its raw output as a numpy array), ``input_hw``, the fixed size its
    input is resized to (None: the image's own), and ``seconds``, what one image cost on the check."""

    kind: str
    source: str
    run: Callable[[np.ndarray], np.ndarray]
    input_hw: tuple[int, int] | None = None
    seconds: float = 0.0  # one image's run, timed on the check image (0: not checked)

    def __call__(self, rgb8: np.ndarray):
        """The decoded output for one uint8 H × W × 3 image: :class:`Detections` or an (H, W) map.
        A model that fails on the image is an ``InputError`` naming ``--task-model``."""
        try:
            raw = self.run(rgb8[None])
        except Exception as error:  # the user's model, not ours: say which image size it refused
            h, w = rgb8.shape[:2]
            raise InputError(
                "--task-model",
                f"{self.source} failed on a {w} × {h} image: {error}".splitlines()[0],
                "a model that takes any size (export with dynamic shapes), or one fixed size it declares",
            ) from None
        return decode(raw, self.kind, rgb8.shape[:2], self.input_hw, self.source)[0]


def load_task_model(spec: str, kind: str, device="cpu", check_pixels: int | None = None) -> TaskModel:
    """The model of ``spec`` (module doc) for ``kind``; with ``check_pixels`` it is run once on a
    grey image of that side and its output checked, so a wrong model fails before any work.
    Raises ``InputError`` naming ``--task-model`` (or ``--task-kind``)."""
    if kind not in KINDS:
        raise InputError("--task-kind", f"{kind!r}", " or ".join(KINDS))
    text = str(spec).strip()
    path = Path(text)
    if path.suffix.lower() in MODEL_SUFFIXES:
        if not path.is_file():
            raise InputError("--task-model", f"no such file {text!r}", FORM)
        run, input_hw = _file_runner(path, str(device))
    elif ":" in text and not path.exists():
        run, input_hw = _callable_runner(text), None
    else:
        raise InputError("--task-model", f"{text!r}", FORM)
    model = TaskModel(kind, text, run, input_hw)
    if check_pixels:
        start = time.perf_counter()
        model(np.full((check_pixels, check_pixels, 3), 128, np.uint8))
        model.seconds = time.perf_counter() - start
    return model


def _file_runner(path: Path, device: str) -> tuple[Callable[[np.ndarray], np.ndarray], tuple[int, int] | None]:
    """(uint8 N × H × W × 3 → the model file's first output, its fixed input size or None)."""
    suffix = path.suffix.lower()
    if suffix == ".onnx":
        try:
            import onnxruntime
        except ImportError:
            raise InputError(
                "--task-model", f"{path.name} needs onnxruntime", "pip install 'metalens-cli[tasks]'"
            ) from None
        providers = ["CPUExecutionProvider"]
        if device.startswith("cuda") and "CUDAExecutionProvider" in onnxruntime.get_available_providers():
            providers.insert(0, "CUDAExecutionProvider")
        try:
            session = onnxruntime.InferenceSession(str(path), providers=providers)
        except Exception as error:
            raise InputError(
                "--task-model", f"{path.name} is not an ONNX model ({error})".splitlines()[0], FORM
            ) from None
        entry = session.get_inputs()[0]
        fixed = len(entry.shape) == 4 and all(isinstance(d, int) for d in entry.shape[2:4])
        size = (int(entry.shape[2]), int(entry.shape[3])) if fixed else None

        def run(batch):
            return session.run(None, {entry.name: _model_input(batch, size)})[0]

        return run, size
    import torch

    try:
        if suffix == ".pt2":
            module = torch.export.load(str(path)).module()
        else:
            module = torch.jit.load(str(path), map_location=device)
    except Exception as error:
        raise InputError("--task-model", f"{path.name} could not be loaded ({error})".splitlines()[0], FORM) from None
    if suffix == ".pt2":
        module = module.to(device)

    def run(batch):
        with torch.no_grad():
            out = module(torch.as_tensor(_model_input(batch, None), device=device))
        out = out[0] if isinstance(out, (tuple, list)) else out
        return out.detach().cpu().numpy()

    return run, None


def _model_input(batch: np.ndarray, size) -> np.ndarray:
    """uint8 N × H × W × 3 → float32 N × 3 × H × W in 0..1, resized to ``size`` (h, w) when given."""
    if size is not None and tuple(size) != batch.shape[1:3]:
        import cv2

        batch = np.stack([cv2.resize(b, (size[1], size[0]), interpolation=cv2.INTER_LINEAR) for b in batch])
    return np.ascontiguousarray(batch.transpose(0, 3, 1, 2), dtype=np.float32) / 255.0


def _callable_runner(spec: str) -> Callable[[np.ndarray], np.ndarray]:
    """``module:callable`` imported (the working directory first on the path)."""
    module_name, _, name = spec.partition(":")
    sys.path.insert(0, str(Path.cwd()))
    try:
        target = getattr(importlib.import_module(module_name), name)
    except (ImportError, AttributeError) as error:
        raise InputError("--task-model", f"{spec!r}: {error}", FORM) from None
    finally:
        sys.path.pop(0)
    if not callable(target):
        raise InputError("--task-model", f"{spec!r} is not callable", FORM)
    return lambda batch: np.asarray(target(batch))


def decode(raw, kind: str, image_hw: tuple[int, int], input_hw=None, source: str = "--task-model") -> list:
    """A model's raw output (module doc) → per image :class:`Detections` or (H, W) int class maps
    at ``image_hw``, from a model that saw ``input_hw`` (None: ``image_hw``); a shape that is
    neither form raises ``InputError`` naming ``--task-model``."""
    out = np.asarray(raw)
    if kind == "detect":
        if out.ndim == 3 and out.shape[2] == 6:
            found = [_boxes(o) for o in out]
        elif out.ndim == 3 and out.shape[1] >= 5:
            found = [_raw_head(o) for o in out]
        else:
            found = None
        if found is not None:
            sy, sx = (1.0, 1.0) if input_hw is None else (image_hw[0] / input_hw[0], image_hw[1] / input_hw[1])
            return [Detections(d.boxes * [sx, sy, sx, sy], d.scores, d.classes) for d in found]
        form = "(N, K, 6) boxes x1, y1, x2, y2, score, class or a raw (N, 4 + classes, anchors) head"
        raise InputError("--task-model", f"{source} returned shape {out.shape}", form)
    form = "(N, C, H, W) scores or (N, H, W) integer classes, H/W as the image's"
    if out.ndim == 4:
        maps = (out[:, 0] > (0.5 if 0 <= out.min() and out.max() <= 1 else 0)) if out.shape[1] == 1 else out.argmax(1)
    elif out.ndim == 3 and np.array_equal(out, np.round(out)):
        maps = out
    else:
        raise InputError("--task-model", f"{source} returned shape {out.shape}", form)
    if abs(maps.shape[1] * image_hw[1] - maps.shape[2] * image_hw[0]) > 0.02 * maps.shape[2] * image_hw[0]:
        raise InputError("--task-model", f"{source} returned maps of {maps.shape[1:]} for an image of {image_hw}", form)
    import cv2

    return [
        cv2.resize(m.astype(np.int32), image_hw[::-1], interpolation=cv2.INTER_NEAREST) if m.shape != image_hw else m
        for m in np.asarray(maps).astype(np.int32)
    ]


def _boxes(rows: np.ndarray) -> Detections:
    """(K, 6) x1, y1, x2, y2, score, class → :class:`Detections`, rows of score 0 (padding) dropped."""
    keep = rows[:, 4] > 0
    rows = rows[keep].astype(np.float64)
    return Detections(rows[:, :4], rows[:, 4], rows[:, 5].astype(np.int64))


def _raw_head(head: np.ndarray) -> Detections:
    """(4 + C, A) cx, cy, w, h, class scores → NMS'd :class:`Detections` (module doc)."""
    import cv2

    head = head.astype(np.float64)
    scores_all = head[4:]
    classes = scores_all.argmax(0)
    scores = scores_all[classes, np.arange(head.shape[1])]
    keep = scores >= MIN_SCORE
    cx, cy, w, h = head[:4, keep]
    boxes = np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)
    scores, classes = scores[keep], classes[keep]
    if not len(scores):
        return Detections(np.zeros((0, 4)), np.zeros(0), np.zeros(0, np.int64))
    xywh = np.stack([boxes[:, 0], boxes[:, 1], w, h], axis=1)
    chosen = np.asarray(
        cv2.dnn.NMSBoxesBatched(xywh.tolist(), scores.tolist(), classes.tolist(), MIN_SCORE, NMS_IOU), dtype=int
    ).ravel()
    chosen = chosen[np.argsort(-scores[chosen], kind="stable")][:MAX_DETECTIONS]
    return Detections(boxes[chosen], scores[chosen], classes[chosen].astype(np.int64))
