"""Reading back the PLY files the package writes, shared by the point-cloud tests."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_ply(path: Path) -> tuple[list[str], np.ndarray]:
    """A minimal reader of the binary little-endian PLY files write_ply makes: the header's
    lines and the vertices as a structured array (x, y, z float32; red, green, blue uint8)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    header = data[:end].decode("ascii").splitlines()
    assert header[:2] == ["ply", "format binary_little_endian 1.0"]
    n = int(next(h for h in header if h.startswith("element vertex")).split()[-1])
    types = {"float": "<f4", "uchar": "u1"}
    fields = [(h.split()[2], types[h.split()[1]]) for h in header if h.startswith("property")]
    vertex = np.frombuffer(data[end:], dtype=np.dtype(fields))
    assert vertex.size == n
    return header, vertex
