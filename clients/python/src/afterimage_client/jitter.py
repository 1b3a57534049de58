"""Sub-pixel jitter for a renderer that sends `Frame.jitter`: afterimage's Halton sequence.

No imports, so corpus/scenes.py, which runs in Blender's Python without this package or its
dependencies, loads this file by path and renders with the same sequence.
"""


def radical_inverse(i, base):
    """`i`'s digits in `base` mirrored about the radix point: a number in [0, 1)."""
    f, r = 1.0, 0.0
    while i > 0:
        f /= base
        r += f * (i % base)
        i //= base
    return r


def halton_jitter(frame, phases=8):
    """Frame `frame`'s offset of the sample from the pixel centre, in pixels (x right, y
    down, each in [-0.5, 0.5)): Halton(2,3) over `phases` frames, as `afterimage scene
    --jitter N` renders and `afterimage filter --jitter-from halton:N` assumes."""
    i = frame % phases + 1
    return (radical_inverse(i, 2) - 0.5, radical_inverse(i, 3) - 0.5)
