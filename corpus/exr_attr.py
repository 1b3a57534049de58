"""Adds a `v2f` attribute (e.g. `afterimage.jitter`) to a single-part scanline OpenEXR file.

Blender cannot write custom EXR header attributes, so the corpus driver inserts the
per-frame jitter after rendering. The attribute goes in front of the header's terminating
null byte, and every entry of the line-offset table moves by its size; pixel data are
copied unchanged. Pure Python (runs under Blender's interpreter or any python3).

    python3 exr_attr.py FILE NAME X Y
"""

import struct
import sys

# Scan lines per chunk, by compression code (OpenEXR file layout, "Line Offset Table").
LINES_PER_CHUNK = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 5: 16, 6: 32, 7: 32, 8: 32, 9: 256}


def _cstr(buf, pos):
    end = buf.index(b"\0", pos)
    return buf[pos:end].decode("latin-1"), end + 1


def set_v2f(path, name, x, y):
    """Writes attribute `name` = (x, y) as a v2f into the header of `path` (replacing it)."""
    with open(path, "rb") as f:
        buf = f.read()
    if buf[:4] != b"\x76\x2f\x31\x01":
        raise ValueError(f"{path}: not an OpenEXR file")
    (version,) = struct.unpack_from("<I", buf, 4)
    if version & (0x200 | 0x800 | 0x1000):
        raise ValueError(f"{path}: only single-part scanline files are supported")
    pos = 8
    attrs = []  # (start, end, name)
    compression = None
    window = None
    while buf[pos] != 0:
        start = pos
        aname, pos = _cstr(buf, pos)
        _atype, pos = _cstr(buf, pos)
        (size,) = struct.unpack_from("<i", buf, pos)
        pos += 4
        value = buf[pos : pos + size]
        pos += size
        attrs.append((start, pos, aname))
        if aname == "compression":
            compression = value[0]
        elif aname == "dataWindow":
            window = struct.unpack("<4i", value)
    header_end = pos  # the terminating null
    if compression not in LINES_PER_CHUNK or window is None:
        raise ValueError(f"{path}: unsupported compression {compression}")
    height = window[3] - window[1] + 1
    chunks = -(-height // LINES_PER_CHUNK[compression])
    table_start = header_end + 1
    offsets = struct.unpack_from(f"<{chunks}Q", buf, table_start)

    new_attr = name.encode() + b"\0" + b"v2f\0" + struct.pack("<i", 8) + struct.pack("<2f", x, y)
    head = bytearray(buf[8:header_end])
    # Drop an existing attribute of that name.
    for start, end, aname in attrs:
        if aname == name:
            head = bytearray(buf[8:start] + buf[end:header_end])
            break
    head += new_attr
    delta = (8 + len(head)) - header_end
    table = struct.pack(f"<{chunks}Q", *(o + delta for o in offsets))
    out = buf[:8] + bytes(head) + b"\0" + table + buf[table_start + 8 * chunks :]
    with open(path, "wb") as f:
        f.write(out)


if __name__ == "__main__":
    set_v2f(sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]))
