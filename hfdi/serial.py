"""Bytes that are data only, for states that cross process or trust boundaries.

The layout is numpy's ``.npz`` with stored (uncompressed) entries: one
``header`` entry holding UTF-8 JSON, and named arrays. Reading never runs
code: numpy reads with ``allow_pickle=False`` (an object array is refused)
and the header is JSON. Entries must be stored, and add up to no more than
the bytes given, so that no entry expands beyond them (a zip bomb).
"""
from __future__ import annotations

import io
import json
import zipfile

import numpy as np

__all__ = ["pack", "unpack"]


def pack(header: dict, arrays: dict) -> bytes:
    """``header`` (JSON-serializable) and ``arrays`` (name -> ndarray) as bytes."""
    if "header" in arrays:
        raise ValueError("arrays may not be named 'header'")
    text = json.dumps(header, allow_nan=True).encode("utf-8")
    buffer = io.BytesIO()
    np.savez(buffer, header=np.frombuffer(text, dtype=np.uint8), **arrays)
    return buffer.getvalue()


def unpack(data) -> tuple:
    """The ``(header, arrays)`` of :func:`pack`'s bytes.

    Raises
    ------
    ValueError
        For bytes that are not such data (corrupt, truncated, compressed,
        holding objects, or without a JSON object as header).
    """
    try:
        data = bytes(data)
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            entries = archive.infolist()
            if any(e.compress_type != zipfile.ZIP_STORED for e in entries) or \
                    sum(e.file_size for e in entries) > len(data):
                raise ValueError("compressed entries")
        with np.load(io.BytesIO(data), allow_pickle=False) as z:
            arrays = {key: z[key] for key in z.files}
        header = json.loads(arrays.pop("header").tobytes().decode("utf-8"))
    except Exception as exc:
        raise ValueError(f"not data of hfdi.serial ({type(exc).__name__})") from None
    if not isinstance(header, dict):
        raise ValueError("not data of hfdi.serial (the header is not an object)")
    return header, arrays
