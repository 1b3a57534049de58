"""Rewrites a single-part scanline OpenEXR file (ZIP, ZIPS or uncompressed) with every
32-bit float channel as a half float, ZIP-compressed; header attributes are kept.

Blender writes its data passes (Depth, Vector, Normal, IndexOB) as 32-bit floats even
when asked for half floats; the committed test subset stores everything as halves to stay
small. Depth (metres, under 100 in the corpus), motion (pixels), normals and object
indices (small integers) all survive the conversion: halves hold integers up to 2048
exactly and have 11 significant bits. Pure Python, no numpy.

    python3 exr_half.py FILE [FILE...]
"""

import struct
import sys
import zlib

ZIP_LINES = {0: 1, 2: 1, 3: 16}
UINT, HALF, FLOAT = 0, 1, 2


def _cstr(buf, pos):
    end = buf.index(b"\0", pos)
    return buf[pos:end], end + 1


def _unpredict(data):
    """ZIP's inverse: undo the delta predictor, then re-interleave the two halves."""
    d = bytearray(data)
    for i in range(1, len(d)):
        d[i] = (d[i - 1] + d[i] - 128) & 0xFF
    half = (len(d) + 1) // 2
    out = bytearray(len(d))
    out[0::2] = d[:half]
    out[1::2] = d[half:]
    return bytes(out)


def _predict(raw):
    d = bytearray(raw[0::2] + raw[1::2])
    for i in range(len(d) - 1, 0, -1):
        d[i] = (d[i] - d[i - 1] + 128) & 0xFF
    return bytes(d)


def to_half(path):
    with open(path, "rb") as f:
        buf = f.read()
    (version,) = struct.unpack_from("<I", buf, 4)
    if buf[:4] != b"\x76\x2f\x31\x01" or version & (0x200 | 0x800 | 0x1000):
        raise ValueError(f"{path}: not a single-part scanline OpenEXR file")
    pos = 8
    attrs = []
    channels = []
    compression = window = None
    while buf[pos] != 0:
        name, pos = _cstr(buf, pos)
        atype, pos = _cstr(buf, pos)
        (size,) = struct.unpack_from("<i", buf, pos)
        pos += 4
        value = buf[pos : pos + size]
        pos += size
        attrs.append([name, atype, value])
        if name == b"channels":
            p = 0
            while value[p] != 0:
                cname, p = _cstr(value, p)
                (ptype,) = struct.unpack_from("<i", value, p)
                xs, ys = struct.unpack_from("<2i", value, p + 8)
                if (xs, ys) != (1, 1):
                    raise ValueError(f"{path}: subsampled channel {cname!r}")
                channels.append([cname, ptype, value[p + 4 : p + 8]])
                p += 16
        elif name == b"compression":
            compression = value[0]
        elif name == b"dataWindow":
            window = struct.unpack("<4i", value)
    if compression not in ZIP_LINES:
        raise ValueError(f"{path}: compression {compression} (only none, zips, zip)")
    width = window[2] - window[0] + 1
    height = window[3] - window[1] + 1
    lines = ZIP_LINES[compression]
    chunks = -(-height // lines)
    table = struct.unpack_from(f"<{chunks}Q", buf, pos + 1)

    def decode(k):
        off = table[k]
        y, size = struct.unpack_from("<ii", buf, off)
        data = buf[off + 8 : off + 8 + size]
        n = min(lines, window[3] + 1 - y)
        expect = n * width * sum(2 if c[1] == HALF else 4 for c in channels)
        if compression != 0 and size < expect:
            data = _unpredict(zlib.decompress(data))
        return y, n, data

    out_chunks = []
    for k in range(chunks):
        y, n, data = decode(k)
        raw = bytearray()
        p = 0
        for _ in range(n):
            for c in channels:
                if c[1] == FLOAT:
                    vals = struct.unpack_from(f"<{width}f", data, p)
                    p += 4 * width
                    raw += struct.pack(f"<{width}e", *(max(-65504.0, min(65504.0, v)) for v in vals))
                else:
                    step = (2 if c[1] == HALF else 4) * width
                    raw += data[p : p + step]
                    p += step
        packed = zlib.compress(_predict(bytes(raw)), 9)
        if len(packed) >= len(raw):
            packed = bytes(raw)
        out_chunks.append(struct.pack("<ii", y, len(packed)) + packed)

    for c in channels:
        if c[1] == FLOAT:
            c[1] = HALF
    chlist = b"".join(c[0] + b"\0" + struct.pack("<i", c[1]) + c[2] + struct.pack("<2i", 1, 1) for c in channels) + b"\0"
    head = bytearray(buf[:8])
    for name, atype, value in attrs:
        if name == b"channels":
            value = chlist
        elif name == b"compression":
            value = bytes([3])
        head += name + b"\0" + atype + b"\0" + struct.pack("<i", len(value)) + value
    head += b"\0"
    out_lines = 16
    if lines != out_lines:
        raise ValueError(f"{path}: re-chunking is not supported (write ZIP from Blender)")
    offset = len(head) + 8 * chunks
    offsets = []
    for c in out_chunks:
        offsets.append(offset)
        offset += len(c)
    with open(path, "wb") as f:
        f.write(bytes(head) + struct.pack(f"<{chunks}Q", *offsets) + b"".join(out_chunks))


if __name__ == "__main__":
    for p in sys.argv[1:]:
        to_half(p)
