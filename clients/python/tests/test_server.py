"""Against a real `afterimage serve`: `python -m afterimage_client filter` gives the same
colour as `afterimage filter` on the committed Blender frames, and its errors say what
went wrong.

Tolerance: none. Both paths run the same Rust filter on the CPU over the same f32
samples (the wire carries f32 little-endian exactly, Blender's motion is converted by a
sign flip, which is exact, and the reply is f32), so the outputs must be bit for bit
equal; any difference is a mapping or encoding bug, not rounding.
"""

import glob
import json
import os
import socket
import subprocess

import numpy as np
import pytest

from afterimage_client import Client, Frame, RequestRejected, ServerUnavailable, halton_jitter
from afterimage_client.exr import find_frames, read_colour, read_exr, read_frame

from conftest import FENCE, MOTION, run_cli

SHOTS = {"fence": FENCE, "motion": MOTION}


def rust_filter(afterimage_bin, filter_name, src, dst, *extra):
    r = subprocess.run(
        [afterimage_bin, "filter", "--filter", filter_name, "-i", str(src), "-o", str(dst), "-j", "1", *extra],
        capture_output=True, text=True, timeout=300,
    )
    assert r.returncode == 0, r.stderr
    return dst


def compare(a_dir, b_dir):
    """Max |a - b| of the colour over every frame of b_dir, and the frames compared."""
    worst, names = 0.0, []
    for path in sorted(glob.glob(os.path.join(str(b_dir), "*.exr"))):
        name = os.path.basename(path)
        a, b = read_colour(os.path.join(str(a_dir), name)), read_colour(path)
        assert a.shape == b.shape, name
        assert np.isfinite(a).all(), name
        worst = max(worst, float(np.abs(a.astype(np.float64) - b.astype(np.float64)).max()))
        names.append(name)
    return worst, names


@pytest.mark.parametrize("filter_name", ["taa", "phlm"])
@pytest.mark.parametrize("shot", ["fence", "motion"])
def test_filter_command_gives_the_colour_of_afterimage_filter(server, afterimage_bin, tmp_path, filter_name, shot):
    src = SHOTS[shot]
    ours, theirs = tmp_path / "client", tmp_path / "rust"
    r = run_cli("filter", "--server", server, "--filter", filter_name, "-i", src, "-o", str(ours))
    assert r.returncode == 0, r.stderr
    rust_filter(afterimage_bin, filter_name, src, theirs)
    worst, names = compare(ours, theirs)
    n = len(find_frames(src))
    assert len(names) == n
    print(f"{filter_name} on {shot}: {n} frames, max |client - afterimage filter| = {worst}")
    assert worst == 0.0, f"{filter_name} on {shot}: colour differs from afterimage filter by up to {worst}"
    # Progress: one line per frame, and the summary.
    assert r.stderr.count("] frame ") == n, r.stderr
    assert f"{filter_name}: {n} frames -> {ours}" in r.stderr
    # The filter did something (the comparison is not of two copies of the input), and
    # every other channel of the input is kept.
    last = sorted(os.listdir(str(ours)))[-2]  # the last .exr before records.json
    inp, out = read_exr(os.path.join(src, last)), read_exr(os.path.join(str(ours), last))
    assert not np.array_equal(read_colour(os.path.join(src, last)), read_colour(os.path.join(str(ours), last)))
    for name, plane in inp.channels.items():
        if ".Combined." not in name or name.endswith(".A"):
            np.testing.assert_array_equal(out.channels[name], plane, err_msg=name)
    records = json.load(open(ours / "records.json"))
    assert [rec["index"] for rec in records] == [num for num, _ in find_frames(src)]
    assert json.loads(out.header["afterimage.record"])["index"] == records[-1]["index"]


@pytest.mark.parametrize("filter_name", ["traa", "pixel_trace", "upsample"])
@pytest.mark.parametrize("shot", ["fence", "motion"])
def test_filters_reading_object_ids_albedo_normals_and_motion_next_agree_too(server, afterimage_bin, tmp_path, filter_name, shot):
    """traa reads object ids and albedo, pixel_trace motion_next (and replies frames late),
    upsample normals and object ids: their mappings are checked the same way."""
    src = SHOTS[shot]
    ours, theirs = tmp_path / "client", tmp_path / "rust"
    r = run_cli("filter", "--server", server, "--filter", filter_name, "-q", "-i", src, "-o", str(ours))
    assert r.returncode == 0, r.stderr
    rust_filter(afterimage_bin, filter_name, src, theirs)
    worst, names = compare(ours, theirs)
    assert len(names) == len(find_frames(src))
    print(f"{filter_name} on {shot}: max |client - afterimage filter| = {worst}")
    assert worst == 0.0


def test_the_comparison_sees_a_motion_mapping_error(server, afterimage_bin, tmp_path):
    """Blender's Vector pass sent without its y flipped (as if it were internal motion)
    gives another colour: the exact comparison above would catch a wrong mapping."""
    theirs = rust_filter(afterimage_bin, "taa", FENCE, tmp_path / "rust")
    frames = find_frames(FENCE)
    with Client(server) as client:
        first, _, _ = read_frame(frames[0][1])
        w, h = first.size
        with client.create_session("taa", width=w, height=h, channels=["color", "depth", "motion"]) as s:
            good, bad = [], []
            for n, path in frames:
                f, _, _ = read_frame(path, index=n)
                good.append(Frame(color=f.color, depth=f.depth, motion=f.motion, index=n))
            outs = list(s.stream(good))
        with client.create_session("taa", width=w, height=h, channels=["color", "depth", "motion"]) as s:
            for f in good:
                wrong = f.motion.copy()
                wrong[..., 1] = -wrong[..., 1]
                bad.append(Frame(color=f.color, depth=f.depth, motion=wrong, index=f.index))
            wrong_outs = list(s.stream(bad))
    last = os.path.basename(frames[-1][1])
    expect = read_colour(os.path.join(str(theirs), last))
    np.testing.assert_array_equal(outs[-1].color, expect)
    assert np.abs(wrong_outs[-1].color - expect).max() > 1e-3


def test_library_stream_returns_figures(server):
    frames = find_frames(MOTION)
    with Client(server) as client:
        info = client.filters()
        assert {"taa", "phlm", "passthrough"} <= set(info)
        first, _, _ = read_frame(frames[0][1])
        w, h = first.size
        with client.create_session("passthrough", width=w, height=h, channels=["color"]) as s:
            st = s.open_stream()
            for n, path in frames:
                f, _, _ = read_frame(path, index=n)
                st.send(Frame(color=f.color, index=n))
                out = st.recv()  # a causal filter replies before the next frame is sent
                assert out.index == n
                np.testing.assert_array_equal(out.color, f.color)
                assert out.figures.total_ms >= 0 and out.round_trip_s is not None
            st.finish()
            assert list(st) == []
            assert s.refresh().frames == len(frames)
        assert s.closed


def test_server_unreachable(tmp_path):
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]  # bound, not listening: nothing answers
        r = run_cli("filter", "--server", f"127.0.0.1:{port}", "--filter", "taa", "--wait", "1",
                    "-i", FENCE, "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert f"error: no afterimage server answered at 127.0.0.1:{port} (plain-text gRPC) within 1 s" in r.stderr
    assert not (tmp_path / "out").exists()
    with pytest.raises(ServerUnavailable):
        Client(f"127.0.0.1:{port}", wait=0.5)


def test_no_frames_in_the_input(tmp_path):
    (tmp_path / "in").mkdir()
    r = run_cli("filter", "--server", "127.0.0.1:1", "--filter", "taa", "-i", str(tmp_path / "in"), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert r.stderr.strip() == f"error: {tmp_path / 'in'}: no .exr frames (it is empty)"


def test_a_frame_missing_a_pass_the_session_sends(server, tmp_path, copy_frames):
    import OpenEXR

    src = copy_frames(FENCE)
    victim = src / "frame_0003.exr"
    f = OpenEXR.File(str(victim), separate_channels=True)
    header = {k: v for k, v in f.header().items() if k not in ("channels", "chunkCount")}
    OpenEXR.File(header, {n: c.pixels for n, c in f.channels().items() if n != "ViewLayer.Depth.Z"}).write(str(victim))
    r = run_cli("filter", "--server", server, "--filter", "taa", "-i", str(src), "-o", str(tmp_path / "out"))
    assert r.returncode == 2, r.stderr
    assert f"error: {victim}: no ViewLayer.Depth.Z (depth, which {src / 'frame_0001.exr'} had and the session was created with)" in r.stderr
    # The frames before it were filtered and written.
    assert sorted(os.listdir(tmp_path / "out")) == ["frame_0001.exr", "frame_0002.exr", "records.json"]


def test_required_pass_missing_from_the_first_frame(server, tmp_path, copy_frames):
    import OpenEXR

    src = copy_frames(MOTION)
    for p in sorted(src.iterdir()):
        f = OpenEXR.File(str(p), separate_channels=True)
        header = {k: v for k, v in f.header().items() if k not in ("channels", "chunkCount")}
        OpenEXR.File(header, {n: c.pixels for n, c in f.channels().items() if ".Vector." not in n}).write(str(p))
    r = run_cli("filter", "--server", server, "--filter", "taa", "--require", "motion", "-i", str(src), "-o", str(tmp_path / "out"))
    assert r.returncode == 2
    assert (f"error: {src / 'frame_0001.exr'}: no ViewLayer.Vector.X, ViewLayer.Vector.Y for channel motion "
            f"(preset blender); the channel is required; the file has: ViewLayer.Combined.A") in r.stderr
    # Without --require the stages that read motion are left out, as afterimage filter does.
    r = run_cli("filter", "--server", server, "--filter", "taa", "-i", str(src), "-o", str(tmp_path / "out2"))
    assert r.returncode == 0, r.stderr
    assert "sending color, depth\n" in r.stderr


def test_unknown_filter_and_bad_parameter(server, tmp_path):
    r = run_cli("filter", "--server", server, "--filter", "tea", "-i", FENCE, "-o", str(tmp_path / "o"))
    assert r.returncode == 2
    assert f"error: the server at {server} has no filter 'tea'; it has: passthrough, fxaa, taa" in r.stderr
    r = run_cli("filter", "--server", server, "--filter", "taa", "--param", "alpha=7", "-i", FENCE, "-o", str(tmp_path / "o"))
    assert r.returncode == 2
    assert "error: creating a taa session of 160x90: the server answered INVALID_ARGUMENT:" in r.stderr
    assert "alpha" in r.stderr
    r = run_cli("filter", "--server", server, "--filter", "taa", "--param", "alpha", "-i", FENCE, "-o", str(tmp_path / "o"))
    assert r.returncode == 2 and "'alpha' is not KEY=VALUE" in r.stderr
    with Client(server) as client, pytest.raises(RequestRejected) as e:
        client.create_session("taa", width=16, height=16, params={"no_such_param": 1})
    assert "no_such_param" in e.value.details


def test_a_parameter_reaches_the_filter(server, afterimage_bin, tmp_path):
    ours, theirs = tmp_path / "client", tmp_path / "rust"
    r = run_cli("filter", "--server", server, "--filter", "taa", "--param", "alpha=0.5", "-q", "-i", FENCE, "-o", str(ours))
    assert r.returncode == 0, r.stderr
    rust_filter(afterimage_bin, "taa", FENCE, theirs, "--set", "alpha=0.5")
    assert compare(ours, theirs)[0] == 0.0
    rust_filter(afterimage_bin, "taa", FENCE, tmp_path / "default")
    assert compare(ours, tmp_path / "default")[0] > 0.0


def test_filters_command_lists_filters_with_their_parameters(server):
    r = run_cli("filters", "--server", server)
    assert r.returncode == 0, r.stderr
    assert "taa: " in r.stdout and "phlm: " in r.stdout
    assert "  needs color; uses color, depth, motion" in r.stdout
    assert "  --param alpha=0.2 (number [" in r.stdout


def test_a_frame_the_server_refuses_ends_the_stream_with_its_reason(server):
    frames = [Frame(color=np.full((16, 16, 3), 0.5, np.float32)) for _ in range(3)]
    frames[1].jitter = (2.0, 0.0)  # outside -1..1 pixels
    with Client(server) as client, client.create_session("taa", width=16, height=16, channels=["color"]) as s:
        got = []
        with pytest.raises(RequestRejected) as e:
            for out in s.stream(frames):
                got.append(out.index)
        assert got == [0]
        assert e.value.code.name == "INVALID_ARGUMENT"
        assert "jitter" in e.value.details and "(2, 0)" in e.value.details


def test_a_wrong_frame_is_refused_after_the_frames_before_it_come_back(server):
    from afterimage_client import FrameError

    good = Frame(color=np.full((16, 16, 3), 0.5, np.float32))
    wrong = Frame(color=np.full((8, 16, 3), 0.5, np.float32))
    with Client(server) as client, client.create_session("taa", width=16, height=16, channels=["color"]) as s:
        got = []
        with pytest.raises(FrameError, match=r"frame of 16x8 for a session of 16x16"):
            for out in s.stream([good, good, wrong, good]):
                got.append(out.index)
        assert got == [0, 1]
        undeclared = Frame(color=good.color, depth=np.ones((16, 16), np.float32))
        with pytest.raises(FrameError, match=r"frame carries depth, which the session was not created with \(its channels: color\)"):
            list(s.stream([undeclared]))


@pytest.mark.parametrize("filter_name", ["taa", "phlm"])
def test_afterimage_layout_with_jitter_and_reference(server, afterimage_bin, tmp_path, filter_name):
    """Frames in this project's own layout (`afterimage scene`: Halton jitter in the
    header, a reference channel): the same colour, and the PSNR against the reference that
    afterimage filter prints."""
    import re

    src = tmp_path / "scene"
    r = subprocess.run([afterimage_bin, "scene", "fence", "--frames", "5", "--size", "96x54", "--spp", "4",
                        "--jitter", "8", "-o", str(src)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    # Every frame its own jitter, the one afterimage_client.halton_jitter gives a renderer.
    for number, p in find_frames(str(src)):
        np.testing.assert_array_equal(read_exr(p).header["afterimage.jitter"], np.float32(halton_jitter(number)))
    ours, theirs = tmp_path / "client", tmp_path / "rust"
    c = run_cli("filter", "--server", server, "--filter", filter_name, "-q", "-i", str(src), "-o", str(ours))
    assert c.returncode == 0, c.stderr
    rr = subprocess.run([afterimage_bin, "filter", "--filter", filter_name, "-i", str(src), "-o", str(theirs), "-j", "1"],
                        capture_output=True, text=True, timeout=120)
    assert rr.returncode == 0, rr.stderr
    assert compare(ours, theirs)[0] == 0.0
    theirs_psnr = re.search(r"mean PSNR ([0-9.]+) dB, mean SSIM ([0-9.]+)", rr.stdout + rr.stderr)
    ours_psnr = re.search(r"mean PSNR ([0-9.]+) dB, mean SSIM ([0-9.]+)", c.stderr)
    assert theirs_psnr and ours_psnr, (rr.stdout + rr.stderr, c.stderr)
    assert ours_psnr.groups() == theirs_psnr.groups()


def test_session_filter_one_frame(server):
    color = np.random.default_rng(2).random((12, 20, 3), dtype=np.float32)
    with Client(server) as client, client.create_session("passthrough", width=20, height=12, channels=["color"]) as s:
        out = s.filter(Frame(color=color))
        assert out.index == 0 and out.color.shape == (12, 20, 3)
        np.testing.assert_array_equal(out.color, color)
        half = s.filter(Frame(color=color), f16=True, reply_f16=True)
        assert half.index == 1
        np.testing.assert_array_equal(half.color, color.astype(np.float16).astype(np.float32))
