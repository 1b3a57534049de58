"""A small OpenEXR reader and writer in numpy and zlib, for where the OpenEXR wheel cannot
be loaded: inside Blender, whose own OpenEXR library clashes with the wheel's in one
process (reading a file crashes Blender 3.4). It covers what Blender writes: single-part
scanline files, NONE, ZIPS or ZIP compression, HALF, FLOAT and UINT channels, no
subsampling. Anything else is refused with a message naming the file and the feature.
"""

from __future__ import annotations

import struct
import zlib
from typing import Any, Dict, List, Tuple

import numpy as np

MAGIC = 20000630
_COMPRESSION_NAMES = ["NONE", "RLE", "ZIPS", "ZIP", "PIZ", "PXR24", "B44", "B44A", "DWAA", "DWAB", "HTJ2K"]
_LINES = {0: 1, 2: 1, 3: 16}
_DTYPE = {0: np.dtype("<u4"), 1: np.dtype("<f2"), 2: np.dtype("<f4")}
_PIXEL_TYPE = {np.dtype("<u4"): 0, np.dtype("<f2"): 1, np.dtype("<f4"): 2}


class Unsupported(Exception):
    pass


def _cstr(buf: bytes, at: int) -> Tuple[str, int]:
    end = buf.index(b"\0", at)
    return buf[at:end].decode("latin-1"), end + 1


def _decode_value(kind: str, raw: bytes) -> Any:
    if kind == "string":
        return raw.decode("utf-8", "replace")
    if kind == "int":
        return struct.unpack("<i", raw)[0]
    if kind == "float":
        return struct.unpack("<f", raw)[0]
    if kind == "v2f":
        return np.frombuffer(raw, "<f4").copy()
    if kind == "v2i":
        return np.frombuffer(raw, "<i4").copy()
    if kind == "box2i":
        v = np.frombuffer(raw, "<i4")
        return (v[:2].copy(), v[2:].copy())
    if kind == "compression":
        return _COMPRESSION_NAMES[raw[0]] if raw[0] < len(_COMPRESSION_NAMES) else raw[0]
    return raw


def _channels(raw: bytes) -> List[Tuple[str, int, int, int]]:
    out, at = [], 0
    while raw[at] != 0:
        name, at = _cstr(raw, at)
        ptype, _plinear, xs, ys = struct.unpack_from("<iB3xii", raw, at)
        at += 16
        out.append((name, ptype, xs, ys))
    return out


def _unpredict(data: bytes) -> bytes:
    """ZIP's predictor and byte interleaving undone."""
    d = np.frombuffer(data, np.uint8).astype(np.int64)
    t = np.empty(len(d), np.int64)
    t[0] = d[0]
    t[1:] = (d[0] + np.cumsum(d[1:] - 128)) & 0xFF  # t[i] = t[i-1] + d[i] - 128 (mod 256)
    t = t.astype(np.uint8)
    half = (len(t) + 1) // 2
    out = np.empty(len(t), np.uint8)
    out[0::2] = t[:half]
    out[1::2] = t[half:]
    return out.tobytes()


def _predict(data: bytes) -> bytes:
    """ZIP's byte interleaving and predictor (the inverse of _unpredict)."""
    b = np.frombuffer(data, np.uint8)
    t = np.concatenate([b[0::2], b[1::2]]).astype(np.int64)
    d = np.empty_like(t)
    d[0] = t[0]
    d[1:] = (t[1:] - t[:-1] + 128 + 256) & 0xFF
    return d.astype(np.uint8).tobytes()


def read(path: str) -> Tuple[Dict[str, Any], Dict[str, Tuple[str, bytes]], Dict[str, np.ndarray]]:
    """(decoded attributes, raw attributes by name as (type, bytes), channels by name)."""
    with open(path, "rb") as f:
        buf = f.read()
    if len(buf) < 8 or struct.unpack_from("<i", buf, 0)[0] != MAGIC:
        raise Unsupported("not a readable OpenEXR file (no magic number)")
    flags = struct.unpack_from("<I", buf, 4)[0]
    if flags & 0x200:
        raise Unsupported("tiled files are not read by the built-in reader")
    if flags & 0x1800:
        raise Unsupported("multi-part or deep files are not read by the built-in reader")
    at = 8
    raw: Dict[str, Tuple[str, bytes]] = {}
    while buf[at] != 0:
        name, at = _cstr(buf, at)
        kind, at = _cstr(buf, at)
        size = struct.unpack_from("<i", buf, at)[0]
        at += 4
        raw[name] = (kind, buf[at : at + size])
        at += size
    at += 1
    attrs = {k: _decode_value(t, v) for k, (t, v) in raw.items() if k != "channels"}
    chans = _channels(raw["channels"][1])
    comp = raw["compression"][1][0]
    if comp not in _LINES:
        raise Unsupported(f"{_COMPRESSION_NAMES[comp] if comp < len(_COMPRESSION_NAMES) else comp} compression is not read by the built-in reader (NONE, ZIPS, ZIP are)")
    for name, ptype, xs, ys in chans:
        if xs != 1 or ys != 1:
            raise Unsupported(f"channel {name} is subsampled")
        if ptype not in _DTYPE:
            raise Unsupported(f"channel {name} has pixel type {ptype}")
    x0, y0, x1, y1 = struct.unpack("<4i", raw["dataWindow"][1])
    w, h = x1 - x0 + 1, y1 - y0 + 1
    lines = _LINES[comp]
    nchunks = (h + lines - 1) // lines
    offsets = struct.unpack_from(f"<{nchunks}Q", buf, at)
    out = {name: np.empty((h, w), _DTYPE[p]) for name, p, _, _ in chans}
    row_bytes = sum(_DTYPE[p].itemsize for _, p, _, _ in chans) * w
    for off in offsets:
        y, size = struct.unpack_from("<ii", buf, off)
        data = buf[off + 8 : off + 8 + size]
        n = min(lines, y1 - y + 1)
        if comp != 0 and size < n * row_bytes:
            data = _unpredict(zlib.decompress(data))
        if len(data) != n * row_bytes:
            raise Unsupported(f"chunk at line {y}: {len(data)} bytes, expected {n * row_bytes}")
        pos = 0
        for r in range(n):
            for name, p, _, _ in chans:
                k = _DTYPE[p].itemsize * w
                out[name][y - y0 + r] = np.frombuffer(data, _DTYPE[p], w, pos)
                pos += k
    return attrs, raw, out


def _encode_value(value: Any) -> Tuple[str, bytes]:
    if isinstance(value, str):
        return "string", value.encode("utf-8")
    if isinstance(value, bool) or isinstance(value, (int, np.integer)):
        return "int", struct.pack("<i", int(value))
    if isinstance(value, (float, np.floating)):
        return "float", struct.pack("<f", float(value))
    a = np.asarray(value)
    if a.shape == (2,) and a.dtype.kind == "f":
        return "v2f", a.astype("<f4").tobytes()
    if a.shape == (2,) and a.dtype.kind in "iu":
        return "v2i", a.astype("<i4").tobytes()
    raise Unsupported(f"cannot write an attribute of value {value!r}")


def write(path: str, raw: Dict[str, Tuple[str, bytes]], extra: Dict[str, Any], channels: Dict[str, np.ndarray], zip_compress: bool = True) -> None:
    """Writes a scanline file: the attributes of ``raw`` (as read), then ``extra`` (python
    values), with ``channels`` (HxW arrays, u4/f2/f4) ZIP-compressed (or uncompressed)."""
    names = sorted(channels)
    h, w = channels[names[0]].shape
    arrays = {}
    for n in names:
        a = np.asarray(channels[n])
        dt = np.dtype(a.dtype).newbyteorder("<")
        if dt not in _PIXEL_TYPE:
            raise Unsupported(f"channel {n}: cannot write samples of type {a.dtype}")
        if a.shape != (h, w):
            raise Unsupported(f"channel {n}: shape {a.shape}, the others are {(h, w)}")
        arrays[n] = np.ascontiguousarray(a, dt)
    attrs: Dict[str, Tuple[str, bytes]] = {}
    for k, (t, v) in raw.items():
        if k not in ("channels", "compression", "chunkCount", "type"):
            attrs[k] = (t, v)
    for k, v in extra.items():
        attrs[k] = _encode_value(v)
    chl = b"".join(n.encode("latin-1") + b"\0" + struct.pack("<iB3xii", _PIXEL_TYPE[arrays[n].dtype], 0, 1, 1) for n in names) + b"\0"
    attrs["channels"] = ("chlist", chl)
    comp = 3 if zip_compress else 0
    attrs["compression"] = ("compression", bytes([comp]))
    attrs.setdefault("dataWindow", ("box2i", struct.pack("<4i", 0, 0, w - 1, h - 1)))
    attrs.setdefault("displayWindow", attrs["dataWindow"])
    attrs.setdefault("lineOrder", ("lineOrder", b"\0"))
    attrs.setdefault("pixelAspectRatio", ("float", struct.pack("<f", 1.0)))
    attrs.setdefault("screenWindowCenter", ("v2f", struct.pack("<2f", 0.0, 0.0)))
    attrs.setdefault("screenWindowWidth", ("float", struct.pack("<f", 1.0)))
    x0, y0, x1, y1 = struct.unpack("<4i", attrs["dataWindow"][1])
    if (x1 - x0 + 1, y1 - y0 + 1) != (w, h):
        raise Unsupported(f"the data window is {x1 - x0 + 1}x{y1 - y0 + 1}, the channels {w}x{h}")
    long_names = any(len(k) > 31 or len(t) > 31 for k, (t, _) in attrs.items()) or any(len(n) > 31 for n in names)
    head = [struct.pack("<iI", MAGIC, 2 | (0x400 if long_names else 0))]
    for k in sorted(attrs):
        t, v = attrs[k]
        head.append(k.encode("latin-1") + b"\0" + t.encode("latin-1") + b"\0" + struct.pack("<i", len(v)) + v)
    head.append(b"\0")
    header = b"".join(head)
    lines = _LINES[comp]
    nchunks = (h + lines - 1) // lines
    chunks = []
    for c in range(nchunks):
        r0, r1 = c * lines, min(h, (c + 1) * lines)
        data = b"".join(arrays[n][r].tobytes() for r in range(r0, r1) for n in names)
        if comp:
            packed = zlib.compress(_predict(data), 6)
            if len(packed) < len(data):
                data = packed
        chunks.append(struct.pack("<ii", y0 + r0, len(data)) + data)
    offsets, pos = [], len(header) + 8 * nchunks
    for ch in chunks:
        offsets.append(pos)
        pos += len(ch)
    with open(path, "wb") as f:
        f.write(header)
        f.write(struct.pack(f"<{nchunks}Q", *offsets))
        for ch in chunks:
            f.write(ch)
