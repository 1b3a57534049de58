"""The EXR helpers: the presets' channel names (as crates/core/src/io/preset.rs), Blender's motion and
object ids on the committed renders, missing passes, frame directories, writing."""

import os

import numpy as np
import OpenEXR
import pytest

from afterimage_client.client import (
    FrameError,
    ProtocolError,
    decode_replies,
    encode_channel,
    encode_channels,
    frame_messages,
    Frame,
    planar,
)
from afterimage_client.proto import afterimage_pb2 as pb
from afterimage_client.exr import (
    ExrError,
    MissingPassError,
    Preset,
    channel_mapping,
    detect_preset,
    find_frames,
    read_colour,
    read_exr,
    read_frame,
    resolve_preset,
    write_filtered,
)

from conftest import FENCE, MOTION


def test_blender_preset_names_are_the_rust_tools():
    p = Preset("blender")
    assert p.names("color") == ["ViewLayer.Combined.R", "ViewLayer.Combined.G", "ViewLayer.Combined.B"]
    assert p.names("depth") == ["ViewLayer.Depth.Z"]
    assert p.names("motion") == ["ViewLayer.Vector.X", "ViewLayer.Vector.Y"]
    assert p.names("motion_next") == ["ViewLayer.Vector.Z", "ViewLayer.Vector.W"]
    assert p.names("normal") == ["ViewLayer.Normal.X", "ViewLayer.Normal.Y", "ViewLayer.Normal.Z"]
    assert p.names("object_id") == ["ViewLayer.IndexOB.X"]
    assert p.names("albedo") == ["ViewLayer.DiffCol.R", "ViewLayer.DiffCol.G", "ViewLayer.DiffCol.B"]
    assert p.names("reference") is None
    assert Preset("blender", "Beauty").names("depth") == ["Beauty.Depth.Z"]


def test_other_presets():
    a = Preset("afterimage")
    assert a.names("color") == ["color.R", "color.G", "color.B"]
    assert a.names("object_id") == ["object_id.id"]
    assert a.names("motion_next") == ["motion_next.X", "motion_next.Y"]
    assert Preset("nuke").names("color") == ["rgba.R", "rgba.G", "rgba.B"]
    assert Preset("nuke").names("depth") == ["depth.Z"]
    assert Preset("plain").names("depth") == ["Z"]
    assert Preset("plain").names("motion") is None


def test_detection():
    assert detect_preset(["ViewLayer.Combined.R", "ViewLayer.Depth.Z"]) == Preset("blender")
    assert detect_preset(["Beauty.Combined.R"]) == Preset("blender", "Beauty")
    assert detect_preset(["color.R", "ViewLayer.Combined.R"]) == Preset("afterimage")
    assert detect_preset(["rgba.R"]) == Preset("nuke")
    assert detect_preset(["R", "G", "B"]) == Preset("plain")
    assert detect_preset(["Y"]) is None
    with pytest.raises(ExrError, match=r"x\.exr: cannot tell the channel layout .* the file has: Y"):
        resolve_preset("auto", ["Y"], "x.exr")
    assert resolve_preset("blender", ["Y"]) == Preset("blender")
    with pytest.raises(ExrError, match="unknown preset 'maya'"):
        resolve_preset("maya", ["R"])


def test_blender_motion_fixture_maps_to_internal_motion():
    # The README: the square moves 5 px right and 3 px up per frame; its centre is at
    # (160, 90) in frame 2. Internal motion points to the previous position (5 left, 3
    # down with rows from the top); motion_next to the next one (5 right, 3 up).
    frame, image, preset = read_frame(os.path.join(MOTION, "frame_0002.exr"))
    assert preset == Preset("blender")
    assert set(frame.channels()) == {"color", "depth", "motion", "motion_next", "normal", "object_id", "albedo"}
    assert frame.color.shape == (180, 320, 3) and frame.color.dtype == np.float32
    assert frame.depth.shape == (180, 320)
    np.testing.assert_array_equal(frame.motion[90, 160], [-5.0, 3.0])
    np.testing.assert_array_equal(frame.motion_next[90, 160], [5.0, -3.0])
    np.testing.assert_array_equal(frame.motion[5, 5], [0.0, 0.0])
    # Object pass indices (meta.json): backdrop 1, square 2, as uint32.
    assert frame.object_id.dtype == np.uint32
    assert frame.object_id[90, 160] == 2 and frame.object_id[5, 5] == 1
    assert set(np.unique(frame.object_id)) == {1, 2}
    # The colour is the file's Combined pass, untouched.
    np.testing.assert_array_equal(frame.color[..., 0], image.channels["ViewLayer.Combined.R"])
    np.testing.assert_array_equal(frame.color[..., 2], image.channels["ViewLayer.Combined.B"])


def _rewrite(src, dst, drop=(), change=None):
    f = OpenEXR.File(str(src), separate_channels=True)
    header = {k: v for k, v in f.header().items() if k not in ("channels", "chunkCount")}
    channels = {n: c.pixels for n, c in f.channels().items() if n not in drop}
    if change:
        change(channels)
    OpenEXR.File(header, channels).write(str(dst))


def test_float_object_ids_round_like_the_rust_tool(tmp_path):
    def ids(ch):
        ch["ViewLayer.IndexOB.X"] = np.full_like(ch["ViewLayer.IndexOB.X"], 2.5)
        ch["ViewLayer.IndexOB.X"][0, :4] = [np.nan, -3.0, 0.49, 1.5]

    _rewrite(os.path.join(MOTION, "frame_0001.exr"), tmp_path / "f_0001.exr", change=ids)
    frame, _, _ = read_frame(str(tmp_path / "f_0001.exr"))
    assert list(frame.object_id[0, :4]) == [0, 0, 0, 2]
    assert frame.object_id[1, 1] == 3  # half away from zero, as f32::round


def test_missing_pass_is_left_out_unless_required(tmp_path):
    path = tmp_path / "frame_0001.exr"
    _rewrite(os.path.join(FENCE, "frame_0001.exr"), path, drop=["ViewLayer.Depth.Z"])
    frame, _, _ = read_frame(str(path))
    assert frame.depth is None and frame.motion is not None
    with pytest.raises(MissingPassError) as e:
        read_frame(str(path), require=["depth"])
    msg = str(e.value)
    assert str(path) in msg
    assert "no ViewLayer.Depth.Z for channel depth (preset blender)" in msg
    assert "the channel is required" in msg
    assert "the file has: ViewLayer.Combined.A, ViewLayer.Combined.B" in msg
    assert "ViewLayer.Depth.Z," not in msg.split("the file has:")[1]


def test_a_partial_pass_is_an_error(tmp_path):
    path = tmp_path / "frame_0001.exr"
    _rewrite(os.path.join(FENCE, "frame_0001.exr"), path, drop=["ViewLayer.Vector.Y"])
    with pytest.raises(MissingPassError) as e:
        read_frame(str(path))
    assert e.value.channel == "motion"
    assert e.value.wanted == ["ViewLayer.Vector.Y"]
    assert "expected all of ViewLayer.Vector.X, ViewLayer.Vector.Y, found only ViewLayer.Vector.X" in str(e.value)


def test_no_colour_is_an_error():
    names = ["ViewLayer.Combined.R", "ViewLayer.Combined.G", "ViewLayer.Depth.Z"]
    with pytest.raises(MissingPassError, match=r"no ViewLayer.Combined.B for channel color"):
        channel_mapping(names, Preset("blender"), "f.exr")
    with pytest.raises(ExrError, match="cannot require 'colour'"):
        channel_mapping(names, Preset("blender"), "f.exr", require=["colour"])


def test_find_frames(tmp_path):
    with pytest.raises(ExrError, match=r"no such directory"):
        find_frames(str(tmp_path / "nope"))
    with pytest.raises(ExrError, match=r"no \.exr frames \(it is empty\)"):
        find_frames(str(tmp_path))
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ExrError, match=r"no \.exr frames \(it holds: notes.txt\)"):
        find_frames(str(tmp_path))
    for n in (9, 10, 12):
        (tmp_path / f"shot.{n:04d}.exr").write_bytes(b"")
    with pytest.raises(ExrError, match=r"frames 11\.\.11 are missing \(between 10 and 12\)"):
        find_frames(str(tmp_path))
    (tmp_path / "shot.0011.exr").write_bytes(b"")
    assert [n for n, _ in find_frames(str(tmp_path))] == [9, 10, 11, 12]
    (tmp_path / "beauty.exr").write_bytes(b"")
    with pytest.raises(ExrError, match=r"beauty\.exr: no frame number"):
        find_frames(str(tmp_path))


def test_unreadable_file(tmp_path):
    bad = tmp_path / "frame_0001.exr"
    bad.write_bytes(b"not an exr")
    with pytest.raises(ExrError, match=r"frame_0001\.exr: not a readable OpenEXR file"):
        read_exr(str(bad))


def test_write_filtered_replaces_the_colour_and_keeps_the_rest(tmp_path):
    src = os.path.join(FENCE, "frame_0002.exr")
    image = read_exr(src)
    color = np.random.default_rng(1).random((image.height, image.width, 3), dtype=np.float32) * 8
    out = tmp_path / "frame_0002.exr"
    write_filtered(image, color, str(out), Preset("blender"), {"afterimage.record": '{"index":2}'})
    back = read_exr(str(out))
    np.testing.assert_array_equal(read_colour(str(out)), color)
    assert set(back.channels) == set(image.channels)
    for n in ("ViewLayer.Depth.Z", "ViewLayer.Vector.X", "ViewLayer.Combined.A", "ViewLayer.IndexOB.X"):
        np.testing.assert_array_equal(back.channels[n], image.channels[n])
    assert back.header["afterimage.record"] == '{"index":2}'
    assert back.header["Camera"] == image.header["Camera"]
    assert not os.path.exists(str(out) + ".partial")
    with pytest.raises(ExrError, match=r"filtered colour of shape \(2, 2, 3\)"):
        write_filtered(image, np.zeros((2, 2, 3), np.float32), str(out), Preset("blender"))


def test_wire_encoding_is_planar_little_endian():
    rgb = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)  # H=2, W=3
    header, data = encode_channel("color", rgb, 3, 2)
    assert header.byte_length == len(data) == 2 * 3 * 3 * 4
    planes = np.frombuffer(data, "<f4").reshape(3, 2, 3)
    np.testing.assert_array_equal(planes[0], rgb[..., 0])
    np.testing.assert_array_equal(planes[2], rgb[..., 2])
    _, half = encode_channel("color", rgb, 3, 2, f16=True)
    assert len(half) == len(data) // 2
    _, ids = encode_channel("object_id", np.array([[1, 2, 3], [4, 5, 70000]], np.uint32), 3, 2)
    assert list(np.frombuffer(ids, "<u4")) == [1, 2, 3, 4, 5, 70000]
    np.testing.assert_array_equal(planar("depth", np.ones((2, 3)), 3, 2).shape, (1, 2, 3))


def test_wire_encoding_refuses_wrong_shapes():
    with pytest.raises(FrameError, match=r"channel motion: expected an array of shape 2x3x2 .* got \(2, 3, 3\)"):
        encode_channel("motion", np.zeros((2, 3, 3), np.float32), 3, 2)
    with pytest.raises(FrameError, match=r"channel color: expected an array of shape 2x3x3 .* got \(3, 2, 3\)"):
        encode_channel("color", np.zeros((3, 2, 3), np.float32), 3, 2)
    with pytest.raises(FrameError, match="object_id: expected integer ids"):
        encode_channel("object_id", np.zeros((2, 3), np.float32), 3, 2)
    with pytest.raises(FrameError, match="unknown channel 'colour'"):
        encode_channel("colour", np.zeros((2, 3, 3), np.float32), 3, 2)


def test_a_frame_payload_is_its_channels_encoded_one_after_another():
    rng = np.random.default_rng(7)
    h, w = 5, 7  # odd sizes: no accidental alignment
    channels = {
        "color": rng.standard_normal((h, w, 3)).astype(np.float32),
        "depth": rng.random((h, w)),  # float64: cast to f32 as the channel's samples
        "motion": rng.standard_normal((h, w, 2)).astype(np.float32)[:, ::-1],  # not contiguous
        "object_id": rng.integers(0, 2**32, (h, w), dtype=np.uint64),
    }
    for f16 in (False, True):
        headers, payload = encode_channels(channels, w, h, f16)
        want = b"".join(encode_channel(n, a, w, h, f16)[1] for n, a in channels.items())
        # The scalar definition: each component's plane, row by row, little-endian.
        ref = b"".join(
            np.asarray(a if a.ndim == 3 else a[..., None])[..., k].astype(
                "<u4" if n == "object_id" else ("<f2" if f16 else "<f4")
            ).tobytes()
            for n, a in channels.items()
            for k in range(np.asarray(a if a.ndim == 3 else a[..., None]).shape[2])
        )
        assert payload.tobytes() == want == ref
        assert [hd.byte_length for hd in headers] == [len(encode_channel(n, a, w, h, f16)[1]) for n, a in channels.items()]


def _reply(index, planes, sample, cuts):
    """A reply's FilteredChunks: its header, then its planes' bytes cut at ``cuts``."""
    data = np.ascontiguousarray(planes).astype("<f2" if sample == pb.SAMPLE_TYPE_F16 else "<f4").tobytes()
    _, h, w = planes.shape
    head = pb.FilteredHeader(index=index, width=w, height=h, color=pb.ChannelHeader(name="color", sample=sample, byte_length=len(data)))
    bounds = [0, *sorted(cuts), len(data)]
    return [pb.FilteredChunk(header=head)] + [
        pb.FilteredChunk(data=pb.DataChunk(data=data[a:b])) for a, b in zip(bounds, bounds[1:])
    ]


def test_replies_reassemble_across_any_chunking():
    rng = np.random.default_rng(3)
    planes = [rng.standard_normal((3, 3, 5)).astype(np.float32) for _ in range(2)]
    for sample in (pb.SAMPLE_TYPE_F32, pb.SAMPLE_TYPE_F16):
        n = 3 * 3 * 5 * (2 if sample == pb.SAMPLE_TYPE_F16 else 4)
        for cuts in ([], [1], [3, 4, 5], list(range(1, n)), rng.choice(np.arange(1, n), 7, replace=False)):
            msgs = _reply(0, planes[0], sample, cuts) + _reply(1, planes[1], sample, [n // 2])
            out = list(decode_replies(msgs))
            assert [h.index for h, _ in out] == [0, 1]
            for (_, color), p in zip(out, planes):
                want = p.astype(np.float16).astype(np.float32) if sample == pb.SAMPLE_TYPE_F16 else p
                assert color.dtype == np.float32 and color.flags.c_contiguous
                np.testing.assert_array_equal(color, want.transpose(1, 2, 0))


def test_a_reply_that_disagrees_with_its_header_is_refused():
    p = np.zeros((3, 2, 2), np.float32)
    msgs = _reply(4, p, pb.SAMPLE_TYPE_F32, [])
    msgs[0].header.color.byte_length += 4
    with pytest.raises(ProtocolError, match=r"frame 4: 52 bytes of colour announced, expected 48"):
        list(decode_replies(msgs))
    msgs = _reply(4, p, pb.SAMPLE_TYPE_F32, [20])
    msgs.append(pb.FilteredChunk(data=pb.DataChunk(data=b"1234")))
    with pytest.raises(ProtocolError, match=r"reply data before its header"):
        list(decode_replies(msgs))
    with pytest.raises(ProtocolError, match=r"frame 4: a reply of 2x2 in a session of 3x2"):
        list(decode_replies(_reply(4, p, pb.SAMPLE_TYPE_F32, []), size=(3, 2)))
    assert len(list(decode_replies(_reply(4, p, pb.SAMPLE_TYPE_F32, []), size=(2, 2)))) == 1
    msgs = _reply(4, p, pb.SAMPLE_TYPE_F32, [20])[:-1]
    with pytest.raises(ProtocolError, match=r"ended inside frame 4's reply \(20 of 48 bytes\)"):
        list(decode_replies(msgs))


def test_frame_messages_cut_the_payload_into_chunks():
    rgb = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3)
    msgs = list(frame_messages("s", 9, Frame(color=rgb), max_chunk_bytes=7))
    assert msgs[0].header.index == 9 and [c.name for c in msgs[0].header.channels] == ["color"]
    data = [m.data.data for m in msgs[1:]]
    assert all(len(d) == 7 for d in data[:-1]) and 0 < len(data[-1]) <= 7
    assert b"".join(data) == encode_channel("color", rgb, 5, 4)[1]


def _fixture_files():
    import glob

    root = os.path.dirname(FENCE.rstrip("/"))
    return sorted(glob.glob(os.path.join(root, "**", "*.exr"), recursive=True)) + sorted(
        glob.glob(os.path.join(MOTION, "*.exr")))


def test_builtin_reader_reads_the_fixtures_as_openexr_does():
    files = _fixture_files()
    assert len(files) == 11
    for path in files:
        a, b = read_exr(path, "builtin"), read_exr(path, "openexr")
        assert (a.width, a.height) == (b.width, b.height)
        assert sorted(a.channels) == sorted(b.channels), path
        for n in b.channels:
            assert a.channels[n].dtype == b.channels[n].dtype, (path, n)
            np.testing.assert_array_equal(a.channels[n], b.channels[n], err_msg=f"{path} {n}")
        assert a.header["compression"] == "ZIP"
        for k in ("Camera", "Frame"):
            if k in b.header:
                assert a.header[k] == b.header[k]


def test_builtin_writer_is_read_back_by_openexr(tmp_path):
    image = read_exr(os.path.join(MOTION, "frame_0003.exr"), "builtin")
    image.header["afterimage.jitter"] = np.array([0.25, -0.125], np.float32)
    color = np.random.default_rng(3).random((image.height, image.width, 3), dtype=np.float32)
    out = tmp_path / "frame_0003.exr"
    write_filtered(image, color, str(out), Preset("blender"), {"afterimage.record": '{"index":3}', "afterimage.reset": 1})
    back = read_exr(str(out), "openexr")
    np.testing.assert_array_equal(read_colour(str(out), backend="openexr"), color)
    for n, plane in image.channels.items():
        if ".Combined." not in n or n.endswith(".A"):
            np.testing.assert_array_equal(back.channels[n], plane, err_msg=n)
    assert back.header["afterimage.record"] == '{"index":3}'
    assert back.header["afterimage.reset"] == 1
    np.testing.assert_array_equal(back.header["afterimage.jitter"], [0.25, -0.125])
    assert back.header["Camera"] == image.header["Camera"]
    assert str(back.header["compression"]).endswith("ZIP_COMPRESSION")
    assert out.stat().st_size < 0.5 * image.width * image.height * 4 * len(image.channels)
    frame, _, _ = read_frame(str(out), backend="builtin")
    assert frame.jitter == (0.25, -0.125) and frame.reset


def test_builtin_reader_refuses_what_it_does_not_read(tmp_path):
    import OpenEXR

    f = OpenEXR.File(os.path.join(FENCE, "frame_0001.exr"), separate_channels=True)
    header = {k: v for k, v in f.header().items() if k not in ("channels", "chunkCount")}
    header["compression"] = OpenEXR.PIZ_COMPRESSION
    OpenEXR.File(header, {n: c.pixels for n, c in f.channels().items()}).write(str(tmp_path / "piz.exr"))
    with pytest.raises(ExrError, match=r"piz\.exr: PIZ compression is not read by the built-in reader \(NONE, ZIPS, ZIP are\)"):
        read_exr(str(tmp_path / "piz.exr"), "builtin")
    assert read_exr(str(tmp_path / "piz.exr"), "openexr").width == 160
