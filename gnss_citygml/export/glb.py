"""Binary glTF 2.0 (GLB) files from numpy arrays: the content of a 3D Tiles tile.

:class:`Glb` collects the arrays of one asset into one binary buffer (each buffer view aligned
to 8 bytes, as the float64 columns of a property table need) and writes the file: the 12-byte
header, the JSON chunk padded with spaces and the binary chunk padded with zeros, each to 4
bytes, as the glTF 2.0 specification (section 4.4, "Binary glTF Layout") sets it.
"""

from __future__ import annotations

import json
import struct
from typing import Any

import numpy as np

__all__ = ["Glb"]

#: glTF's accessor component types, by numpy dtype.
_COMPONENT = {
    np.dtype(np.int8): 5120,
    np.dtype(np.uint8): 5121,
    np.dtype(np.int16): 5122,
    np.dtype(np.uint16): 5123,
    np.dtype(np.uint32): 5125,
    np.dtype(np.float32): 5126,
}
#: glTF's accessor types, by the number of components.
_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
#: Buffer view targets: vertex attributes and indices.
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


class Glb:
    """One glTF asset being built: its JSON (``gltf``) and its binary buffer."""

    def __init__(self) -> None:
        self.gltf: dict[str, Any] = {
            "asset": {"version": "2.0", "generator": "gnss-citygml"},
            "buffers": [{"byteLength": 0}],
            "bufferViews": [],
            "accessors": [],
        }
        self._chunks: list[bytes] = []
        self._length = 0

    def view(self, data: np.ndarray, target: int | None = None, stride: int | None = None) -> int:
        """Add ``data``'s bytes (little-endian, C order) as a buffer view; return its index."""
        raw = np.ascontiguousarray(data).tobytes()
        pad = -self._length % 8
        if pad:
            self._chunks.append(b"\0" * pad)
            self._length += pad
        view: dict[str, Any] = {"buffer": 0, "byteOffset": self._length, "byteLength": len(raw)}
        if target is not None:
            view["target"] = target
        if stride is not None:
            view["byteStride"] = stride
        self._chunks.append(raw)
        self._length += len(raw)
        self.gltf["bufferViews"].append(view)
        return len(self.gltf["bufferViews"]) - 1

    def accessor(
        self, data: np.ndarray, target: int | None = ARRAY_BUFFER, bounds: bool = False
    ) -> int:
        """Add ``data`` ((count,) or (count, k), a dtype glTF knows) as an accessor on a view of
        its own; ``bounds`` adds its ``min`` and ``max`` (POSITION must have them)."""
        width = 1 if data.ndim == 1 else data.shape[1]
        accessor: dict[str, Any] = {
            "bufferView": self.view(data, target),
            "componentType": _COMPONENT[data.dtype],
            "count": int(data.shape[0]),
            "type": _TYPE[width],
        }
        if bounds:
            shaped = data.reshape(len(data), width)
            accessor["min"] = [_number(v) for v in shaped.min(axis=0)]
            accessor["max"] = [_number(v) for v in shaped.max(axis=0)]
        self.gltf["accessors"].append(accessor)
        return len(self.gltf["accessors"]) - 1

    def extension(self, name: str, value: dict[str, Any] | None = None) -> None:
        """Declare extension ``name`` used (not required: a viewer without it still draws
        the meshes), with its top-level ``value`` if given."""
        used = self.gltf.setdefault("extensionsUsed", [])
        if name not in used:
            used.append(name)
        if value is not None:
            self.gltf.setdefault("extensions", {})[name] = value

    def to_bytes(self) -> bytes:
        """The GLB file."""
        pad = -self._length % 4
        binary = b"".join(self._chunks) + b"\0" * pad
        self.gltf["buffers"][0]["byteLength"] = self._length
        text = json.dumps(self.gltf, separators=(",", ":"), allow_nan=False).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(binary)
        return b"".join(
            [
                struct.pack("<III", 0x46546C67, 2, total),  # "glTF", version 2
                struct.pack("<II", len(text), 0x4E4F534A),  # "JSON"
                text,
                struct.pack("<II", len(binary), 0x004E4942),  # "BIN\0"
                binary,
            ]
        )


def _number(value: Any) -> float | int:
    """A JSON number of a numpy scalar (an int stays an int)."""
    return int(value) if np.issubdtype(type(value), np.integer) else float(value)
