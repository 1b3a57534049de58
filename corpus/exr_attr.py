"""Adds a `v2f` attribute (e.g. `afterimage.jitter`) to a single-part scanline OpenEXR file.

Blender cannot write custom EXR header attributes, so the corpus driver inserts the
per-frame jitter after rendering. The attribute goes in front of the header's terminating
null byte, and every entry of the line-offset table moves by its size; pixel data are
copied unchanged. Pure Python (runs under Blender's interpreter or any python3).

    python3 exr_attr.py FILE NAME X Y
"""

import struct
import sys

from exr import Header


def set_v2f(path, name, x, y):
    """Writes attribute `name` = (x, y) as a v2f into the header of `path` (replacing it)."""
    with open(path, "rb") as f:
        buf = f.read()
    h = Header(buf, path)
    new_attr = name.encode() + b"\0" + b"v2f\0" + struct.pack("<i", 8) + struct.pack("<2f", x, y)
    head = bytearray(buf[8 : h.end])
    # Drop an existing attribute of that name.
    for aname, _atype, _value, start, end in h.attrs:
        if aname == name.encode():
            head = bytearray(buf[8:start] + buf[end : h.end])
            break
    head += new_attr
    delta = (8 + len(head)) - h.end
    table = struct.pack(f"<{h.chunks}Q", *(o + delta for o in h.offsets))
    out = buf[:8] + bytes(head) + b"\0" + table + buf[h.end + 1 + 8 * h.chunks :]
    with open(path, "wb") as f:
        f.write(out)


if __name__ == "__main__":
    set_v2f(sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4]))
