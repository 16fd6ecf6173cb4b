"""Bounded readers of user files: text, ``.npy`` arrays and image headers checked before any
large allocation, and C-library chatter kept off standard output.

Every limit is far above what a real input of this tool needs (a preset is a few kB, a θ map
of the paper's lens 0.3 GB, a photograph tens of megapixels) and far below what would bring a
machine down; a file beyond it is an :class:`InputError` naming the field and the limit.
"""

from __future__ import annotations

import os
import stat
import sys
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from metalens_cli.errors import InputError

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr")  # image files the tool reads
MAX_TEXT_BYTES = 4 << 20  # presets, CSV tables, JSON run files
MAX_ARRAY_BYTES = 4 << 30  # a .npy θ map (the paper's lens in float64: 0.3 GB)
MAX_IMAGE_PIXELS = 150_000_000  # one image, all channels aside (a 12 000² frame; below 2 × Pillow's bomb limit)


def image_files(folder: Path) -> list[Path]:
    """The image files of ``folder`` (:data:`IMAGE_SUFFIXES`, hidden files aside), sorted by name."""
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith("."))


def regular_file(path: str | os.PathLike[str], field: str, expected: str) -> Path:
    """``path`` if it names an existing regular file (following links); a missing file, folder,
    device or FIFO is an :class:`InputError` (a device could be read without end)."""
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise InputError(field, f"no such file {str(path)!r}", expected) from None
    except OSError as exc:
        raise InputError(field, f"cannot read {str(path)!r}: {exc.strerror}", expected) from None
    if not stat.S_ISREG(mode):
        kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file"
        raise InputError(field, f"{str(path)!r} is {kind}", expected)
    return path


def read_text(path: str | os.PathLike[str], field: str, expected: str, limit: int = MAX_TEXT_BYTES) -> str:
    """The UTF-8 text of a regular file of at most ``limit`` bytes."""
    path = regular_file(path, field, expected)
    try:
        with open(path, "rb") as handle:
            data = handle.read(limit + 1)
    except OSError as exc:
        raise InputError(field, f"cannot read {str(path)!r}: {exc.strerror}", expected) from None
    if len(data) > limit:
        raise InputError(field, f"{path.name} is larger than {limit >> 20} MiB", expected)
    try:
        return data.decode("utf-8-sig")  # a byte-order mark (Excel's "CSV UTF-8") is dropped
    except UnicodeDecodeError:
        raise InputError(field, f"{path.name} is not UTF-8 text", f"{expected} in UTF-8") from None


def read_npy(path: str | os.PathLike[str], field: str, expected: str, limit: int = MAX_ARRAY_BYTES):
    """A ``.npy`` array whose header is checked before its data is read: a plain numeric dtype,
    and a size that the file holds and that is at most ``limit`` bytes."""
    import numpy as np
    from numpy.lib import format as npy_format

    path = regular_file(path, field, expected)
    try:
        with open(path, "rb") as handle:
            version = npy_format.read_magic(handle)
            read_header = npy_format.read_array_header_1_0 if version == (1, 0) else npy_format.read_array_header_2_0
            shape, _, dtype = read_header(handle, max_header_size=10_000)
            offset = handle.tell()
    except (OSError, ValueError, SyntaxError, TypeError, UnicodeDecodeError) as exc:
        raise InputError(
            field, f"{path.name} is not a readable .npy file: {str(exc).splitlines()[0] if str(exc) else exc}", expected
        ) from None
    if dtype.kind not in "fiu" or dtype.hasobject:
        raise InputError(field, f"{path.name} holds {dtype}, not real numbers", expected)
    size = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if size > limit:
        raise InputError(
            field, f"{path.name} claims {size / 2**30:.3g} GiB of data; the limit is {limit / 2**30:g} GiB", expected
        )
    if size > path.stat().st_size - offset:
        raise InputError(field, f"{path.name} is truncated: its header claims {size} bytes of data", expected)
    return np.load(path, allow_pickle=False)


def check_image_size(path: Path, field: str, limit: int = MAX_IMAGE_PIXELS) -> tuple[int, int]:
    """(height, width) from an image file's header, refusing more than ``limit`` pixels before
    any pixel is decoded (a small compressed file can decode to gigabytes)."""
    if path.suffix.lower() == ".exr":
        header = open_exr(path, field, "an EXR image", header_only=True).header()
        (x0, y0), (x1, y1) = header["dataWindow"]
        height, width = int(y1) - int(y0) + 1, int(x1) - int(x0) + 1
    else:
        from PIL import Image

        pillow_limit = Image.MAX_IMAGE_PIXELS
        try:
            # Pillow's bomb check refuses at open, before the size can be read; opening reads the
            # header only, and our own limit below refuses before any pixel is decoded
            Image.MAX_IMAGE_PIXELS = None
            with Image.open(path) as image:
                width, height = image.size
        except Exception:  # Pillow cannot parse it: leave the verdict to the decoder
            return 0, 0
        finally:
            Image.MAX_IMAGE_PIXELS = pillow_limit
    if height * width > limit:
        raise InputError(
            field,
            f"{path.name} is {width} × {height} pixels; the limit is {limit / 1e6:g} megapixels",
            "a smaller image",
        )
    return height, width


def open_exr(path: Path, field: str, expected: str, header_only: bool = False):
    """An ``OpenEXR.File`` (channels as separate arrays); a corrupt or truncated file is an
    :class:`InputError` carrying the library's own reason, which is kept off stdout/stderr.
    Pixels are read only after the header shows they fit in ``MAX_ARRAY_BYTES``."""
    import OpenEXR

    path = regular_file(path, field, expected)
    if not header_only:
        header = open_exr(path, field, expected, header_only=True).header()
        (x0, y0), (x1, y1) = header["dataWindow"]
        size = (int(x1) - int(x0) + 1) * (int(y1) - int(y0) + 1) * len(header.get("channels", ())) * 4
        if size > MAX_ARRAY_BYTES:
            raise InputError(
                field,
                f"{path.name} claims {size / 2**30:.3g} GiB of pixels; the limit is {MAX_ARRAY_BYTES / 2**30:g} GiB",
                expected,
            )
    with library_output() as said:
        try:
            exr = OpenEXR.File(str(path), separate_channels=True, header_only=header_only)
            parts = len(exr.parts)
        except RuntimeError:
            exr, parts = None, 0
    if parts != 1:
        reason = next((line.strip() for line in said.text.splitlines() if line.strip()), "")
        detail = (
            "corrupt or truncated" + (f": {reason[:160]}" if reason else "")
            if parts == 0
            else f"{parts} parts, not one"
        )
        who = "" if field == str(path) else f"{path.name}: "
        raise InputError(field, f"{who}not a readable OpenEXR file ({detail})", expected)
    return exr


class _Said:
    text = ""


_CAPTURE = threading.RLock()  # file descriptors 1 and 2 are the process's: one capture at a time


@contextmanager
def library_output() -> Iterator[_Said]:
    """Capture what C libraries write to file descriptors 1 and 2 (OpenEXR warns on stdout,
    which would break ``--json``); the text is on the yielded object afterwards. Captures are
    serialised: two threads swapping the descriptors at once could leave stdout on a
    temporary file."""
    with _CAPTURE, _captured() as said:
        yield said


@contextmanager
def _captured() -> Iterator[_Said]:
    said = _Said()
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(1), os.dup(2)
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 1)
        os.dup2(sink.fileno(), 2)
        try:
            yield said
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            sink.seek(0)
            said.text = sink.read(1 << 16).decode("utf-8", "replace")
