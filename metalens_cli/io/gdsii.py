"""A streamed, vectorised GDSII (Calma stream format, release 6) writer built on numpy.

A GDSII file is a sequence of records: a 2-byte big-endian length (header included, always
even), a record type byte, a data type byte, then the data. Integers are big-endian two's
complement (2 or 4 bytes); reals are the 8-byte excess-64 base-16 format of :func:`real8`;
strings are ASCII padded with one NUL to an even length. Coordinates are 4-byte integers in
database units.

:class:`GdsStream` writes the library frame, structures, text elements and, for speed, whole
chunks of boundary or structure-reference elements at once: the records of every element of a
chunk are packed into one big-endian numpy structured array and written with one ``write``,
so the cost per element is a few vector operations, not Python calls.
"""

from __future__ import annotations

import datetime as _dt
import struct
from fractions import Fraction
from typing import BinaryIO

import numpy as np

# Record headers (record type, data type) as the 16-bit word following the length.
HEADER, BGNLIB, LIBNAME, UNITS, ENDLIB = 0x0002, 0x0102, 0x0206, 0x0305, 0x0400
BGNSTR, STRNAME, ENDSTR = 0x0502, 0x0606, 0x0700
BOUNDARY, SREF, TEXT = 0x0800, 0x0A00, 0x0C00
LAYER, DATATYPE, XY, ENDEL, SNAME = 0x0D02, 0x0E02, 0x1003, 0x1100, 0x1206
TEXTTYPE, STRING = 0x1602, 0x1906

GDS_VERSION = 600
MAX_COORDINATE = 2**31 - 1  # 4-byte signed integers
MAX_RECORD_BYTES = 65534  # the 2-byte length, kept even


def real8(value: float) -> bytes:
    """``value`` as a GDSII 8-byte real: sign bit, 7-bit excess-64 base-16 exponent, 56-bit fraction.

    value = (−1)^sign · 16^(exponent − 64) · fraction / 2^56 with 1/16 ≤ fraction / 2^56 < 1.
    Every finite double in range is represented exactly: the normalised fraction has at least
    53 significant bits. Zero encodes as eight zero bytes.
    """
    if value == 0:
        return bytes(8)
    exact = Fraction(abs(value))
    exponent = 0
    while exact >= 1:
        exact /= 16
        exponent += 1
    while exact < Fraction(1, 16):
        exact *= 16
        exponent -= 1
    fraction = exact * 2**56
    if fraction.denominator != 1 or not -64 <= exponent <= 63:
        raise ValueError(f"{value!r} is outside the GDSII real range")
    sign = 0x80 if value < 0 else 0
    return bytes([sign | (exponent + 64)]) + int(fraction).to_bytes(7, "big")


def record(header: int, data: bytes = b"") -> bytes:
    """One record: length, ``header`` (record type and data type) and ``data`` (even length)."""
    if len(data) % 2 or len(data) + 4 > MAX_RECORD_BYTES:
        raise ValueError(f"record {header:#06x}: data of {len(data)} bytes is odd or too long")
    return struct.pack(">HH", len(data) + 4, header) + data


def ascii_data(text: str) -> bytes:
    """ASCII string data padded with NUL to an even length."""
    data = text.encode("ascii")
    return data + b"\0" * (len(data) % 2)


def _timestamp(now: _dt.datetime) -> bytes:
    """Modification and access time: year, month, day, hour, minute, second, twice (2-byte ints)."""
    fields = (now.year, now.month, now.day, now.hour, now.minute, now.second)
    return struct.pack(">12h", *fields, *fields)


def boundary_words(layer: int, datatype: int) -> np.ndarray:
    """The 64 bytes of one 4-vertex BOUNDARY element as 16 big-endian int32 words, coordinates zero.

    Words 0-4: BOUNDARY, LAYER, DATATYPE and the XY header; words 5-14: the closed ring of five
    (x, y) points; word 15: ENDEL.
    """
    head = record(BOUNDARY) + record(LAYER, struct.pack(">h", layer)) + record(DATATYPE, struct.pack(">h", datatype))
    element = head + struct.pack(">HH", 44, XY) + bytes(40) + record(ENDEL)
    return np.frombuffer(element, dtype=">i4")


def sref_dtype(name_bytes: int) -> np.dtype:
    """One SREF element without transformation: SREF, SNAME (``name_bytes``, even), XY (1 point), ENDEL."""
    return np.dtype(
        [
            ("sref", ">u4"),
            ("sname_h", ">u4"),
            ("sname", f"S{name_bytes}"),
            ("xy_h", ">u4"),
            ("xy", ">i4", (2,)),
            ("endel", ">u4"),
        ]
    )


def _word(header: int, data_bytes: int) -> int:
    """The first 4 bytes of a record as one big-endian unsigned int."""
    return ((data_bytes + 4) << 16) | header


class GdsStream:
    """Write a GDSII library to an open binary file, element chunks at a time.

    Call order: :meth:`begin_library`, then per structure :meth:`begin_structure`, elements
    (:meth:`text`, :meth:`boundaries`, :meth:`srefs`), :meth:`end_structure`; finally
    :meth:`end_library`. Coordinates are integers in database units.
    """

    def __init__(self, file: BinaryIO):
        self.file = file
        self.bytes_written = 0

    def _write(self, data) -> None:
        self.bytes_written += memoryview(data).nbytes
        self.file.write(data)

    def begin_library(
        self, name: str, dbu_m: float, user_unit_m: float = 1e-6, now: _dt.datetime | None = None
    ) -> None:
        """HEADER, BGNLIB, LIBNAME and UNITS: ``dbu_m`` metres per database unit, user unit in metres."""
        stamp = _timestamp(now or _dt.datetime.now())
        self._write(
            record(HEADER, struct.pack(">h", GDS_VERSION))
            + record(BGNLIB, stamp)
            + record(LIBNAME, ascii_data(name))
            + record(UNITS, real8(dbu_m / user_unit_m) + real8(dbu_m))
        )

    def begin_structure(self, name: str, now: _dt.datetime | None = None) -> None:
        """BGNSTR and STRNAME."""
        self._write(record(BGNSTR, _timestamp(now or _dt.datetime.now())) + record(STRNAME, ascii_data(name)))

    def text(self, layer: int, texttype: int, x: int, y: int, string: str) -> None:
        """A TEXT element anchored at (x, y) (database units)."""
        self._write(
            record(TEXT)
            + record(LAYER, struct.pack(">h", layer))
            + record(TEXTTYPE, struct.pack(">h", texttype))
            + record(XY, struct.pack(">ii", x, y))
            + record(STRING, ascii_data(string))
            + record(ENDEL)
        )

    def boundaries(self, vertices: np.ndarray, layer: int, datatype: int) -> None:
        """One BOUNDARY per quadrilateral: ``vertices`` is (n, 4, 2) integers in database units.

        The ring is closed (first vertex repeated) as GDSII requires. One ``write`` per call.
        """
        n = vertices.shape[0]
        words = np.empty((n, 16), dtype=">i4")
        words[:] = boundary_words(layer, datatype)
        words[:, 5:13] = vertices.reshape(n, 8)
        words[:, 13:15] = vertices[:, 0]
        self._write(words)

    def srefs(self, names: np.ndarray, positions: np.ndarray) -> None:
        """One SREF per row of ``positions`` ((n, 2) integer database units) to the structure named in
        ``names`` (n fixed-width byte strings of one even width, NUL-padded)."""
        out = np.empty(positions.shape[0], dtype=sref_dtype(names.dtype.itemsize))
        out["sref"] = _word(SREF, 0)
        out["sname_h"], out["sname"] = _word(SNAME, names.dtype.itemsize), names
        out["xy_h"], out["xy"] = _word(XY, 8), positions
        out["endel"] = _word(ENDEL, 0)
        self._write(out)

    def end_structure(self) -> None:
        """ENDSTR."""
        self._write(record(ENDSTR))

    def end_library(self) -> None:
        """ENDLIB."""
        self._write(record(ENDLIB))
