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

from exr import FLOAT, HALF, Header, predict, unpredict

# The compressions read here: none, ZIPS and ZIP.
READ = (0, 2, 3)


def to_half(path):
    with open(path, "rb") as f:
        buf = f.read()
    h = Header(buf, path)
    if h.compression not in READ:
        raise ValueError(f"{path}: compression {h.compression} (only none, zips, zip)")
    width, lines, channels = h.width, h.lines, h.channels

    def decode(k):
        off = h.offsets[k]
        y, size = struct.unpack_from("<ii", buf, off)
        data = buf[off + 8 : off + 8 + size]
        n = min(lines, h.window[3] + 1 - y)
        expect = n * width * sum(2 if c[1] == HALF else 4 for c in channels)
        if h.compression != 0 and size < expect:
            data = unpredict(zlib.decompress(data))
        return y, n, data

    out_chunks = []
    for k in range(h.chunks):
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
        packed = zlib.compress(predict(bytes(raw)), 9)
        if len(packed) >= len(raw):
            packed = bytes(raw)
        out_chunks.append(struct.pack("<ii", y, len(packed)) + packed)

    for c in channels:
        if c[1] == FLOAT:
            c[1] = HALF
    chlist = b"".join(c[0] + b"\0" + struct.pack("<i", c[1]) + c[2] + struct.pack("<2i", 1, 1) for c in channels) + b"\0"
    head = bytearray(buf[:8])
    for name, atype, value, _start, _end in h.attrs:
        if name == b"channels":
            value = chlist
        elif name == b"compression":
            value = bytes([3])
        head += name + b"\0" + atype + b"\0" + struct.pack("<i", len(value)) + value
    head += b"\0"
    out_lines = 16
    if lines != out_lines:
        raise ValueError(f"{path}: re-chunking is not supported (write ZIP from Blender)")
    offset = len(head) + 8 * h.chunks
    offsets = []
    for c in out_chunks:
        offsets.append(offset)
        offset += len(c)
    with open(path, "wb") as f:
        f.write(bytes(head) + struct.pack(f"<{h.chunks}Q", *offsets) + b"".join(out_chunks))


if __name__ == "__main__":
    for p in sys.argv[1:]:
        to_half(p)
