"""The small part of the OpenEXR file layout the corpus scripts need: the header of a
single-part scanline file, its line-offset table, and ZIP's byte predictor. Pure Python
(runs under Blender's interpreter or any python3); `exr_attr.py`, `exr_half.py` and
`taa_proto.py` share it.
"""

import struct

MAGIC = b"\x76\x2f\x31\x01"
# Version flags of tiled, multi-part and deep files, which these scripts do not handle.
NOT_SCANLINE = 0x200 | 0x800 | 0x1000
# Scan lines per chunk, by compression code (OpenEXR file layout, "Line Offset Table").
LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}
# Pixel types of a channel list.
UINT, HALF, FLOAT = 0, 1, 2


def cstr(buf, pos):
    """The null-terminated bytes at `pos`, and the position after the null."""
    end = buf.index(b"\0", pos)
    return buf[pos:end], end + 1


class Header:
    """A parsed header: `attrs` as [name, type, value, start, end] (bytes, with the byte
    range of each attribute in the file), `channels` as [name, pixel type, the 4 bytes of
    pLinear and reserved], `compression`, `window` (xmin, ymin, xmax, ymax), `end` (the
    position of the header's terminating null) and the line-offset table `offsets`."""

    def __init__(self, buf, path):
        (version,) = struct.unpack_from("<I", buf, 4)
        if buf[:4] != MAGIC or version & NOT_SCANLINE:
            raise ValueError(f"{path}: not a single-part scanline OpenEXR file")
        pos = 8
        self.attrs, self.channels = [], []
        self.compression = self.window = None
        while buf[pos] != 0:
            start = pos
            name, pos = cstr(buf, pos)
            atype, pos = cstr(buf, pos)
            (size,) = struct.unpack_from("<i", buf, pos)
            pos += 4
            value = buf[pos : pos + size]
            pos += size
            self.attrs.append([name, atype, value, start, pos])
            if name == b"channels":
                p = 0
                while value[p] != 0:
                    cname, p = cstr(value, p)
                    (ptype,) = struct.unpack_from("<i", value, p)
                    xs, ys = struct.unpack_from("<2i", value, p + 8)
                    if (xs, ys) != (1, 1):
                        raise ValueError(f"{path}: subsampled channel {cname!r}")
                    self.channels.append([cname, ptype, value[p + 4 : p + 8]])
                    p += 16
            elif name == b"compression":
                self.compression = value[0]
            elif name == b"dataWindow":
                self.window = struct.unpack("<4i", value)
        self.end = pos
        if self.compression not in LINES_PER_CHUNK or self.window is None:
            raise ValueError(f"{path}: unsupported compression {self.compression}")
        self.width = self.window[2] - self.window[0] + 1
        self.height = self.window[3] - self.window[1] + 1
        self.lines = LINES_PER_CHUNK[self.compression]
        self.chunks = -(-self.height // self.lines)
        self.offsets = struct.unpack_from(f"<{self.chunks}Q", buf, self.end + 1)


def unpredict(data):
    """ZIP's inverse: undo the delta predictor, then re-interleave the two halves."""
    d = bytearray(data)
    for i in range(1, len(d)):
        d[i] = (d[i - 1] + d[i] - 128) & 0xFF
    half = (len(d) + 1) // 2
    out = bytearray(len(d))
    out[0::2] = d[:half]
    out[1::2] = d[half:]
    return bytes(out)


def predict(raw):
    """ZIP's predictor: split even and odd bytes, then delta-code them."""
    d = bytearray(raw[0::2] + raw[1::2])
    for i in range(len(d) - 1, 0, -1):
        d[i] = (d[i] - d[i - 1] + 128) & 0xFF
    return bytes(d)
