"""The package's own checks of a glTF 2.0 file's structure, which run without node.

Khronos' glTF validator (:mod:`.gltf`) needs Node.js; these checks need nothing but Python, so
that every GLB of a tileset is checked on any machine. They are fewer than Khronos' and cover
what a reader trips on:

- a GLB's header (magic ``glTF``, version 2, its length the file's) and chunks (a JSON chunk
  first, then at most a ``BIN`` chunk, each a multiple of 4 bytes, within the file); the JSON
  chunk (or a ``.gltf`` file) parses as a JSON object, ``asset.version`` ``2.0``;
- buffers, buffer views and accessors within bounds: buffer 0 of a GLB no longer than its BIN
  chunk, each view within its buffer, each accessor's values within its view, aligned to their
  component size;
- mesh primitives: their attributes' and indices' accessors exist, the attributes have one
  count, every index is below it, a POSITION accessor has ``min`` and ``max``;
- an accessor's ``min`` and ``max``, where given and its values are in the GLB: as many as its
  components, equal to the values' (as Khronos' validator wants).

A buffer in another file (``uri``) is not read: its accessors are checked against the
``byteLength`` the file gives.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Iterator
from pathlib import Path
from typing import TypeGuard

import numpy as np

__all__ = ["structure_issues"]

#: numpy types of glTF's component types.
COMPONENT_TYPES: dict[object, np.dtype] = {
    5120: np.dtype("<i1"),
    5121: np.dtype("<u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
#: Components per element, by accessor type.
TYPES: dict[object, int] = {
    "SCALAR": 1,
    "VEC2": 2,
    "VEC3": 3,
    "VEC4": 4,
    "MAT2": 4,
    "MAT3": 9,
    "MAT4": 16,
}
#: The component types an index accessor may have.
INDEX_TYPES = (5121, 5123, 5125)

Issues = Iterator[tuple[str, str]]


class _Broken(ValueError):
    """A file whose structure cannot be read further: where and why."""

    def __init__(self, pointer: str, problem: str):
        super().__init__(problem)
        self.pointer, self.problem = pointer, problem


def structure_issues(path: Path) -> list[tuple[str, str]]:
    """(JSON pointer or ``GLB``, what is wrong) of every structural error of a ``.glb`` or
    ``.gltf`` file; none for a sound file."""
    try:
        doc, binary = _read(path.read_bytes(), path.suffix.lower() == ".glb")
    except OSError as exc:
        return [("/", f"cannot read the file ({exc.strerror})")]
    except _Broken as exc:
        return [(exc.pointer, exc.problem)]
    return list(_Gltf(doc, binary).issues())


def _read(data: bytes, is_glb: bool) -> tuple[dict, bytes | None]:
    """The glTF JSON and the BIN chunk of a GLB (or the JSON of a ``.gltf``)."""
    binary = None
    if is_glb or data[:4] == b"glTF":
        if len(data) < 20 or data[:4] != b"glTF":
            raise _Broken("GLB", "no GLB header (the magic glTF and 20 bytes at least)")
        _, version, length = struct.unpack_from("<4sII", data)
        if version != 2:
            raise _Broken("GLB", f"GLB version {version}, not 2")
        if length != len(data):
            raise _Broken("GLB", f"the header's length, {length}, is not the file's {len(data)}")
        chunks = list(_chunks(data))
        if chunks[0][0] != b"JSON":
            raise _Broken("GLB", "the first chunk is not JSON")
        if len(chunks) > 2 or (len(chunks) == 2 and chunks[1][0] != b"BIN\0"):
            raise _Broken("GLB", "chunks after the JSON chunk other than one BIN chunk")
        text, binary = chunks[0][1], chunks[1][1] if len(chunks) == 2 else None
    else:
        text = data
    try:
        doc = json.loads(text)
    except (ValueError, RecursionError):
        raise _Broken("GLB" if binary is not None or is_glb else "/", _not_json(is_glb)) from None
    if not isinstance(doc, dict):
        raise _Broken("/", "the glTF JSON is not an object")
    asset = doc.get("asset")
    if not isinstance(asset, dict) or asset.get("version") != "2.0":
        raise _Broken("/asset/version", "not 2.0 (or no asset)")
    return doc, binary


def _not_json(is_glb: bool) -> str:
    return "the JSON chunk is not JSON (UTF-8)" if is_glb else "not JSON (UTF-8)"


def _chunks(data: bytes) -> Iterator[tuple[bytes, bytes]]:
    """(type, bytes) of each chunk of a GLB whose header was read."""
    at = 12
    while at < len(data):
        if at + 8 > len(data):
            raise _Broken("GLB", f"a chunk header cut short at byte {at}")
        size, kind = struct.unpack_from("<I4s", data, at)
        if size % 4 or at + 8 + size > len(data):
            raise _Broken(
                "GLB",
                f"the chunk at byte {at} ({size} bytes) is not a multiple of 4 or past the end",
            )
        yield kind, data[at + 8 : at + 8 + size]
        at += 8 + size


def _list(doc: dict, key: str) -> list:
    value = doc.get(key, [])
    return value if isinstance(value, list) else []


def _lookup(table: dict, item: dict, key: str):
    """``table``'s entry for ``item[key]``; None if there is none (or it is not a key at all:
    a list, say)."""
    value = item.get(key)
    return table.get(value) if isinstance(value, int | str) else None


def _int(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


class _Gltf:
    """The arrays of a glTF document and the bytes of its GLB buffer."""

    def __init__(self, doc: dict, binary: bytes | None):
        self.doc, self.binary = doc, binary
        self.buffers = [b if isinstance(b, dict) else {} for b in _list(doc, "buffers")]
        self.views = [v if isinstance(v, dict) else {} for v in _list(doc, "bufferViews")]
        self.accessors = [a if isinstance(a, dict) else {} for a in _list(doc, "accessors")]
        self.sound: set[int] = set()  # accessors within bounds

    def issues(self) -> Issues:
        yield from self._buffers()
        yield from self._views()
        for i, accessor in enumerate(self.accessors):
            problems = list(self._accessor(i, accessor))
            if not problems:
                self.sound.add(i)
            yield from problems
        yield from self._meshes()
        for i in sorted(self.sound):
            yield from self._bounds(i, self.accessors[i])

    def _buffers(self) -> Issues:
        for i, buffer in enumerate(self.buffers):
            length = buffer.get("byteLength")
            if not _int(length) or length < 1:
                yield f"/buffers/{i}/byteLength", f"{length!r}, not an integer of at least 1"
            elif i == 0 and "uri" not in buffer:
                held = len(self.binary) if self.binary is not None else 0
                if length > held:
                    yield (
                        f"/buffers/{i}",
                        f"byteLength {length} is more than the BIN chunk's {held} bytes",
                    )

    def _views(self) -> Issues:
        for i, view in enumerate(self.views):
            at = f"/bufferViews/{i}"
            buffer = view.get("buffer")
            if not (_int(buffer) and buffer < len(self.buffers)):
                yield f"{at}/buffer", f"buffer {buffer!r} does not exist"
                continue
            start, length = view.get("byteOffset", 0), view.get("byteLength")
            size = self.buffers[buffer].get("byteLength")
            if not (_int(start) and _int(length) and length >= 1):
                yield at, "byteOffset or byteLength is not a non-negative integer"
            elif _int(size) and start + length > size:
                yield (
                    at,
                    f"bytes {start} to {start + length} are past the {size} of buffer {buffer}",
                )
            stride = view.get("byteStride")
            if stride is not None and not (_int(stride) and 4 <= stride <= 252 and stride % 4 == 0):
                yield f"{at}/byteStride", f"{stride!r}, not a multiple of 4 from 4 to 252"

    def _accessor(self, i: int, accessor: dict) -> Issues:
        at = f"/accessors/{i}"
        dtype = _lookup(COMPONENT_TYPES, accessor, "componentType")
        width = _lookup(TYPES, accessor, "type")
        count = accessor.get("count")
        if dtype is None or width is None or not (_int(count) and count >= 1):
            yield at, "componentType, type or count (at least 1) is not one of glTF's"
            return
        view_index = accessor.get("bufferView")
        if view_index is None:
            return  # all zeros (or sparse): nothing to read
        if not (_int(view_index) and view_index < len(self.views)):
            yield f"{at}/bufferView", f"buffer view {view_index!r} does not exist"
            return
        view = self.views[view_index]
        start = accessor.get("byteOffset", 0)
        element = dtype.itemsize * width
        stride = view.get("byteStride") or element
        length = view.get("byteLength")
        if not _int(start) or start % dtype.itemsize:
            yield f"{at}/byteOffset", f"{start!r}, not a multiple of its component size"
        elif _int(length) and start + stride * (count - 1) + element > length:
            yield (
                at,
                f"{count} values of {element} byte(s) from byte {start} do not fit buffer "
                f"view {view_index} ({length} bytes)",
            )

    def _meshes(self) -> Issues:
        for m, mesh in enumerate(_list(self.doc, "meshes")):
            primitives = _list(mesh, "primitives") if isinstance(mesh, dict) else []
            for p, primitive in enumerate(primitives):
                if isinstance(primitive, dict):
                    yield from self._primitive(f"/meshes/{m}/primitives/{p}", primitive)

    def _primitive(self, at: str, primitive: dict) -> Issues:
        attributes = primitive.get("attributes")
        attributes = attributes if isinstance(attributes, dict) else {}
        counts = set()
        for name, index in attributes.items():
            if not (_int(index) and index < len(self.accessors)):
                yield f"{at}/attributes/{name}", f"accessor {index!r} does not exist"
                continue
            count = self.accessors[index].get("count")
            counts.add(count if _int(count) else None)
            if name == "POSITION" and not {"min", "max"} <= set(self.accessors[index]):
                yield f"/accessors/{index}", "a POSITION accessor without min and max"
        if len(counts) > 1:
            yield f"{at}/attributes", f"the attributes' accessors have different counts {counts}"
        index = primitive.get("indices")
        if index is None:
            return
        if not (_int(index) and index < len(self.accessors)):
            yield f"{at}/indices", f"accessor {index!r} does not exist"
            return
        accessor = self.accessors[index]
        if accessor.get("type") != "SCALAR" or accessor.get("componentType") not in INDEX_TYPES:
            yield f"/accessors/{index}", "indices that are not unsigned SCALAR integers"
            return
        values = self._values(index)
        if values is not None and len(counts) == 1:
            (n_vertices,) = counts
            if _int(n_vertices) and values.size and int(values.max()) >= n_vertices:
                yield (
                    f"{at}/indices",
                    f"index {int(values.max())}, not below the {n_vertices} vertices",
                )

    def _values(self, i: int) -> np.ndarray | None:
        """The values of sound accessor ``i`` (count x components) if they are in the GLB's
        BIN chunk, else None."""
        accessor = self.accessors[i]
        view_index = accessor.get("bufferView")
        if i not in self.sound or view_index is None or self.binary is None:
            return None
        view = self.views[view_index]
        if view.get("buffer") != 0 or not self.buffers or "uri" in self.buffers[0]:
            return None
        dtype, width = COMPONENT_TYPES[accessor["componentType"]], TYPES[accessor["type"]]
        if width != 1 and accessor["type"].startswith("MAT") and dtype.itemsize < 4:
            return None  # columns padded to 4 bytes: not read
        offsets = view.get("byteOffset", 0), accessor.get("byteOffset", 0)
        stride = view.get("byteStride") or dtype.itemsize * width
        if not (_int(offsets[0]) and _int(offsets[1]) and _int(stride)):
            return None  # an error of the view or the accessor
        start = offsets[0] + offsets[1]
        count = accessor["count"]
        if start + stride * (count - 1) + dtype.itemsize * width > len(self.binary):
            return None  # past the chunk: an error of the buffer
        return np.ndarray((count, width), dtype, self.binary, start, (stride, dtype.itemsize))

    def _bounds(self, i: int, accessor: dict) -> Issues:
        """``min`` and ``max`` of accessor ``i``: as many as its components, the values'."""
        width = TYPES[accessor["type"]]
        values = None
        for key in ("min", "max"):
            given = accessor.get(key)
            if given is None:
                continue
            at = f"/accessors/{i}/{key}"
            if not isinstance(given, list) or len(given) != width:
                yield at, f"not a list of {width} number(s)"
                continue
            values = self._values(i) if values is None else values
            if values is None or accessor.get("sparse") is not None:
                continue
            actual = values.min(axis=0) if key == "min" else values.max(axis=0)
            try:
                declared = np.asarray(given, dtype=float).astype(values.dtype)
            except (TypeError, ValueError, OverflowError):
                yield at, "not a list of numbers"
                continue
            if not np.array_equal(declared, actual):
                yield at, f"{given}, not the values' {actual.astype(float).tolist()}"
