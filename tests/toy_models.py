"""Small vision models written for the tests: a detector with a raw YOLO-style head and a
segmenter, both torch modules that export to ONNX, torch.export and TorchScript."""

import torch
import torch.nn.functional as F

CELL = 16  # the detector's anchor grid (px)


class CellDetector(torch.nn.Module):
    """Scores each cell × cell square (CELL by default) by how much brighter (class 0) or darker
    (class 1) it is than its 3 × 3 neighbourhood of cells: a raw head (N, 4 + 2, cells), boxes cx,
    cy, w, h in pixels."""

    def __init__(self, cell: int = CELL):
        super().__init__()
        self.cell = cell

    def forward(self, x):
        g = F.avg_pool2d(x.mean(1, keepdim=True), self.cell)
        local = F.avg_pool2d(F.pad(g, (1, 1, 1, 1), mode="replicate"), 3, stride=1)
        scores = torch.cat([torch.sigmoid(30 * (g - local - 0.03)), torch.sigmoid(30 * (local - g - 0.03))], 1)
        n, _, h, w = g.shape
        ys = (torch.arange(h, dtype=x.dtype) + 0.5) * self.cell
        xs = (torch.arange(w, dtype=x.dtype) + 0.5) * self.cell
        cy = ys[:, None].expand(h, w)
        cx = xs[None, :].expand(h, w)
        size = torch.full((h, w), float(self.cell), dtype=x.dtype)
        boxes = torch.stack([cx, cy, size, size]).reshape(1, 4, h * w).expand(n, 4, h * w)
        return torch.cat([boxes, scores.reshape(n, 2, h * w)], 1)


class BrightSegmenter(torch.nn.Module):
    """One logit per pixel: foreground where the image is brighter than 0.45 (N, 1, H, W)."""

    def forward(self, x):
        return 20 * (x.mean(1, keepdim=True) - 0.45)


def boxes_callable(batch):
    """A callable detector on uint8 N × H × W × 3: one fixed box per image, (N, 1, 6)."""
    import numpy as np

    return np.tile(np.array([[[10.0, 10.0, 30.0, 40.0, 0.9, 2.0]]]), (len(batch), 1, 1))


def cell_detector(batch):
    """:class:`CellDetector` of 48-pixel cells as a callable on uint8 N × H × W × 3 (any size; under
    COCO's 100 detections per image and class on a 384² board)."""
    x = torch.as_tensor(batch, dtype=torch.float32).permute(0, 3, 1, 2) / 255
    with torch.no_grad():
        return CellDetector(48)(x).numpy()
