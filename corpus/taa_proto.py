"""A minimal TAA in pure Python, to measure jitter-aware reconstruction on the corpus before
building it into the filters (issue 39, item 2).

Bilinear history fetch along Blender's motion, RGB clip to the 3x3 mean +- 1 sigma in
c/(1+c), blend weight max(`alpha`, 1/n) with n the pixel's frames of history (as our taa
counts), no dilation. The current frame's contribution is either the
pixel's own sample ("blind") or, when the jitter is known ("jitter"), the 3x3 samples
weighted by exp(-2.29 d^2), d the distance from the pixel centre to where each sample
really fell (Karis 2014's Gaussian fit of Blackman-Harris), or the same weights with the
jitter taken as 0 ("gauss0", which separates the gain of knowing the jitter from that of
a softer reconstruction). PSNR as `afterimage eval`:
linear and clamped to [0, 1], or c/(1+c) when the first reference exceeds 1.

    python3 corpus/taa_proto.py CORPUS_DIR SCENE [SCENE...] [--alpha 0.1]

Slow (about 1 s a frame at 160x90): a measuring tool, not a filter.
"""

import json
import math
import os
import struct
import sys
import zlib

from exr import HALF, Header, unpredict

def read_exr(path, wanted):
    """Channels `wanted` (names) of a single-part scanline EXR (none/zips/zip) as flat
    row-major lists, and the width and height."""
    with open(path, "rb") as f:
        buf = f.read()
    h = Header(buf, path)
    w = h.width
    out = {c: [] for c in wanted}
    row_bytes = sum((2 if c[1] == HALF else 4) * w for c in h.channels)
    for off in h.offsets:
        y, size = struct.unpack_from("<ii", buf, off)
        data = buf[off + 8 : off + 8 + size]
        n = min(h.lines, h.window[3] + 1 - y)
        if size < n * row_bytes:
            data = unpredict(zlib.decompress(data))
        p = 0
        for _ in range(n):
            for cname, t, _rest in h.channels:
                step = (2 if t == HALF else 4) * w
                if cname.decode() in out:
                    out[cname.decode()].extend(struct.unpack_from(f"<{w}{'e' if t == HALF else 'f'}", data, p))
                p += step
    return out, w, h.height


def tm(v):
    return v / (1.0 + v)


def run(scene_dir, alpha, mode):
    inp = os.path.join(scene_dir, "input")
    ref = os.path.join(scene_dir, "reference")
    jit = json.load(open(os.path.join(inp, "jitter.json")))
    frames = sorted(f for f in os.listdir(inp) if f.endswith(".exr"))
    names = ["ViewLayer.Combined." + c for c in "RGB"] + ["ViewLayer.Vector.X", "ViewLayer.Vector.Y"]
    hist = None
    count = None
    psnrs = []
    space = None
    for fname in frames:
        number = int(fname[-8:-4])
        ch, w, h = read_exr(os.path.join(inp, fname), names)
        rc, _, _ = read_exr(os.path.join(ref, fname), ["R", "G", "B"])
        cur = [[tm(max(0.0, v)) for v in ch["ViewLayer.Combined." + c]] for c in "RGB"]
        mx, my = ch["ViewLayer.Vector.X"], ch["ViewLayer.Vector.Y"]
        jx, jy = jit[str(number)] if mode == "jitter" else (0.0, 0.0)
        # Reconstruction weights of the 3x3 for this frame's jitter (the same at every pixel).
        taps = []
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                d2 = (dx + jx) ** 2 + (dy + jy) ** 2
                taps.append((dx, dy, math.exp(-2.29 * d2)))
        out = [[0.0] * (w * h) for _ in range(3)]
        new_count = [1] * (w * h)
        for y in range(h):
            for x in range(w):
                i = y * w + x
                m = [0.0] * 3
                m2 = [0.0] * 3
                rec = [0.0] * 3
                wsum = 0.0
                for dx, dy, wt in taps:
                    xx = min(w - 1, max(0, x + dx))
                    yy = min(h - 1, max(0, y + dy))
                    k = yy * w + xx
                    wsum += wt
                    for c in range(3):
                        v = cur[c][k]
                        m[c] += v
                        m2[c] += v * v
                        rec[c] += wt * v
                if mode != "blind":
                    now = [rec[c] / wsum for c in range(3)]
                else:
                    now = [cur[c][i] for c in range(3)]
                if hist is None:
                    for c in range(3):
                        out[c][i] = now[c]
                    continue
                px = x + mx[i]
                py = y - my[i]
                if px < 0 or py < 0 or px > w - 1 or py > h - 1:
                    for c in range(3):
                        out[c][i] = now[c]
                    continue
                n = min(255, count[int(py + 0.5) * w + int(px + 0.5)] + 1) if count else 2
                new_count[i] = n
                a = max(alpha, 1.0 / n)
                x0, y0 = int(px), int(py)
                x1, y1 = min(w - 1, x0 + 1), min(h - 1, y0 + 1)
                fx, fy = px - x0, py - y0
                for c in range(3):
                    hc = hist[c]
                    hv = (hc[y0 * w + x0] * (1 - fx) + hc[y0 * w + x1] * fx) * (1 - fy) + (
                        hc[y1 * w + x0] * (1 - fx) + hc[y1 * w + x1] * fx
                    ) * fy
                    mean = m[c] / 9.0
                    sd = math.sqrt(max(0.0, m2[c] / 9.0 - mean * mean))
                    hv = min(mean + sd, max(mean - sd, hv))
                    out[c][i] = hv + a * (now[c] - hv)
        hist = out
        count = new_count
        # PSNR as `afterimage eval`.
        if space is None:
            space = "tonemapped" if max(max(rc[c]) for c in "RGB") > 1.0 else "linear"
        se = 0.0
        for c, cn in enumerate("RGB"):
            for i in range(w * h):
                o = out[c][i]
                lin = o / max(1e-6, 1.0 - o)  # back to linear
                r = rc[cn][i]
                if space == "tonemapped":
                    a, b = o, tm(max(0.0, r))
                else:
                    a, b = min(1.0, max(0.0, lin)), min(1.0, max(0.0, r))
                se += (a - b) ** 2
        mse = se / (3 * w * h)
        psnrs.append(10 * math.log10(1.0 / max(mse, 1e-12)))
    return sum(psnrs) / len(psnrs)


def main():
    args = sys.argv[1:]
    alpha = 0.1
    if "--alpha" in args:
        k = args.index("--alpha")
        alpha = float(args[k + 1])
        del args[k : k + 2]
    corpus, scenes = args[0], args[1:]
    print(f"| scene (alpha {alpha}) | blind | Gaussian 3x3, jitter taken as 0 | jitter-aware | jitter-aware minus Gaussian |")
    print("|---|---:|---:|---:|---:|")
    for s in scenes:
        d = os.path.join(corpus, s)
        a, g, b = (run(d, alpha, m) for m in ("blind", "gauss0", "jitter"))
        print(f"| {s} | {a:.2f} | {g:.2f} | {b:.2f} | {b - g:+.2f} |", flush=True)


if __name__ == "__main__":
    main()
