"""examples/blender_stream.py in a real headless Blender against a real server: the frames it
renders and streams come back filtered with the colour `afterimage filter` gives on the
inputs it wrote (jitter included, read back from the files' `afterimage.jitter`).

Needs `blender` on PATH (Debian's, with its system Python of the same minor version as
this venv's). Without it the test is skipped, unless AFTERIMAGE_REQUIRE_BLENDER=1.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig

import numpy as np
import pytest

from afterimage_client.exr import find_frames, read_colour, read_exr

from conftest import HERE
from test_server import compare, rust_filter

EXAMPLE = os.path.join(HERE, "..", "examples", "blender_stream.py")


@pytest.fixture(scope="module")
def blender():
    path = shutil.which("blender")
    if path is None:
        if os.environ.get("AFTERIMAGE_REQUIRE_BLENDER") == "1":
            pytest.fail("no blender on PATH and AFTERIMAGE_REQUIRE_BLENDER=1")
        pytest.skip("no blender on PATH")
    probe = subprocess.run(
        [path, "-b", "--factory-startup", "--python-expr", "import sys; print('PYVER', *sys.version_info[:2])"],
        capture_output=True, text=True, timeout=120,
    )
    line = next((l for l in probe.stdout.splitlines() if l.startswith("PYVER")), None)
    assert line is not None, probe.stdout + probe.stderr
    theirs = tuple(int(v) for v in line.split()[1:])
    if theirs != sys.version_info[:2]:
        msg = (f"Blender's Python is {theirs[0]}.{theirs[1]}, this venv's {sys.version_info[0]}.{sys.version_info[1]}: "
               f"the installed wheels would not load there")
        if os.environ.get("AFTERIMAGE_REQUIRE_BLENDER") == "1":
            pytest.fail(msg)
        pytest.skip(msg)
    return path


def test_blender_example_streams_what_afterimage_filter_gives(blender, server, afterimage_bin, tmp_path):
    site = sysconfig.get_paths()["purelib"]
    out = tmp_path / "run"
    r = subprocess.run(
        [blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python", EXAMPLE, "--",
         "--server", server, "--site", site, "--filter", "taa", "--frames", "6", "--size", "160x90",
         "--threads", "2", "--out", str(out)],
        capture_output=True, text=True, timeout=600,
    )
    log = "\n".join(l for l in (r.stdout + r.stderr).splitlines() if "blender_stream" in l or "rror" in l)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    print(log)
    timing = json.load(open(out / "timing.json"))
    assert timing["frames"] == 6 and len(timing["per_frame"]) == 6
    assert [n for n, _ in find_frames(str(out / "filtered"))] == list(range(1, 7))
    # The inputs carry their Halton jitter; afterimage filter on them gives the same colour.
    jitters = [tuple(read_exr(p).header["afterimage.jitter"]) for _, p in find_frames(str(out / "input"))]
    assert len(set(jitters)) == 6 and all(-0.5 <= v <= 0.5 for j in jitters for v in j)
    theirs = rust_filter(afterimage_bin, "taa", out / "input", tmp_path / "rust")
    worst, names = compare(out / "filtered", theirs)
    print(f"blender example, taa: {len(names)} frames, max |client - afterimage filter| = {worst}")
    assert len(names) == 6 and worst == 0.0
    last_in = read_colour(str(out / "input" / "frame_0006.exr"))
    last_out = read_colour(str(out / "filtered" / "frame_0006.exr"))
    assert np.abs(last_in - last_out).max() > 0.05  # filtered, not passed through
