"""Blender renders, afterimage filters: a headless Blender script that renders a small
animated scene with Cycles (1 sample per pixel, a Halton sub-pixel jitter per frame), streams
each frame's passes to an afterimage server with afterimage_client while the next frame
renders, and writes the filtered frames.

    blender -b --factory-startup --python clients/python/examples/blender_stream.py -- \\
        --server 127.0.0.1:50051 --site VENV/lib/python3.11/site-packages \\
        --filter taa --frames 8 --size 320x180 --out /tmp/blender-aa

Blender runs its own Python (Debian's blender: the system Python 3.11), without the
package: `--site` (or AFTERIMAGE_CLIENT_SITE) names the site-packages of a venv made with
the same Python minor version where `pip install ./clients/python` installed it.

Writes OUT/input/frame_####.exr (Blender's multilayer render of every pass afterimage's
`blender` preset reads, with the frame's jitter in the `afterimage.jitter` attribute, so
`afterimage filter -i OUT/input` sees the same frames), OUT/filtered/frame_####.exr (the
render with its colour replaced by the server's result) and OUT/timing.json. The scene:
a checkered ground, a fence of thin posts, a wire, a sphere rolling past and a camera
dollying sideways, lit by a sun with hard shadows plus an ambient emission term, so 1 spp
shows aliasing rather than noise.

Jitter (the conventions of corpus/scenes.py, checked there): Blender's camera shift is a
fraction of the larger image side, y up, so a sample offset of (jx, jy) pixels (x right, y
down) is shift (jx / M, -jy / M), M = max(width, height). Cycles computes motion vectors with
the current frame's shift at both ends, so they hold no jitter (the `blender` convention).
"""

import argparse
import json
import math
import os
import site
import sys
import threading
import time


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    p = argparse.ArgumentParser(prog="blender -b --factory-startup --python blender_stream.py --",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--server", required=True, metavar="HOST:PORT", help="the afterimage server's gRPC address")
    p.add_argument("--site", default=os.environ.get("AFTERIMAGE_CLIENT_SITE"), metavar="DIR",
                   help="site-packages holding afterimage_client and its dependencies (default: $AFTERIMAGE_CLIENT_SITE)")
    p.add_argument("--filter", default="taa", help="the filter (default: taa)")
    p.add_argument("--param", action="append", default=[], metavar="KEY=VALUE", help="a filter parameter; repeatable")
    p.add_argument("--frames", type=int, default=8, help="frames to render (default: 8)")
    p.add_argument("--size", default="320x180", metavar="WxH", help="image size (default: 320x180)")
    p.add_argument("--out", required=True, metavar="DIR", help="where input/, filtered/ and timing.json go")
    p.add_argument("--threads", type=int, default=0, help="Cycles render threads (default: 0, every core)")
    p.add_argument("--no-jitter", action="store_true", help="render every frame at the pixel centres")
    p.add_argument("--api-key", default=os.environ.get("AFTERIMAGE_API_KEY"), help="API key (default: $AFTERIMAGE_API_KEY)")
    p.add_argument("--tls-ca", help="PEM file of the CA to trust (TLS)")
    p.add_argument("--tls-domain", help="the name in the server's certificate, when not the host")
    args = p.parse_args(argv)
    args.width, args.height = (int(v) for v in args.size.lower().split("x"))
    return args


def import_client(site_dir):
    if site_dir:
        if not os.path.isdir(site_dir):
            sys.exit(f"blender_stream: --site {site_dir}: no such directory")
        site.addsitedir(site_dir)
    try:
        import afterimage_client  # noqa: F401
    except ImportError as e:
        v = sys.version_info
        sys.exit(
            f"blender_stream: cannot import afterimage_client in Blender's Python {v.major}.{v.minor}.{v.micro} ({e}); "
            f"make a venv with python{v.major}.{v.minor}, `pip install ./clients/python` into it and pass "
            f"--site VENV/lib/python{v.major}.{v.minor}/site-packages"
        )


# --- the scene ------------------------------------------------------------------------------


def build_scene(bpy, args, frames):
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    index = iter(range(1, 1000))

    def material(name, color, checker=None):
        m = bpy.data.materials.new(name)
        m.use_nodes = True
        nodes, links = m.node_tree.nodes, m.node_tree.links
        bsdf = nodes["Principled BSDF"]
        bsdf.inputs["Roughness"].default_value = 0.6
        if checker:
            tex = nodes.new("ShaderNodeTexChecker")
            tex.inputs["Scale"].default_value = checker
            tex.inputs["Color1"].default_value = (*color, 1.0)
            tex.inputs["Color2"].default_value = (0.12, 0.12, 0.12, 1.0)
            links.new(tex.outputs["Color"], bsdf.inputs["Base Color"])
            links.new(tex.outputs["Color"], bsdf.inputs["Emission"])
        else:
            bsdf.inputs["Base Color"].default_value = (*color, 1.0)
            bsdf.inputs["Emission"].default_value = (*color, 1.0)
        bsdf.inputs["Emission Strength"].default_value = 0.25  # ambient light without noise
        # The emission is not a light: sampled as one, it would be noise at 1 spp.
        if hasattr(m.cycles, "emission_sampling"):  # Blender 3.5+
            m.cycles.emission_sampling = "NONE"
        else:
            m.cycles.sample_as_light = False
        return m

    def add(obj_name, mesh_op, mat, **kw):
        mesh_op(**kw)
        obj = bpy.context.active_object
        obj.name = obj_name
        obj.data.materials.append(mat)
        obj.pass_index = next(index)
        obj.visible_diffuse = False  # emissive surfaces must not light each other (noise)
        obj.visible_glossy = False
        return obj

    add("ground", bpy.ops.mesh.primitive_plane_add, material("ground", (0.8, 0.78, 0.7), checker=60.0), size=40.0)
    wood = material("wood", (0.55, 0.42, 0.3))
    for i in range(15):  # 4 cm posts, 1 m tall, and a rail: thin geometry that aliases
        add(f"post_{i}", bpy.ops.mesh.primitive_cube_add, wood, size=1.0, location=(-3.5 + 0.5 * i, 2.0, 0.5),
            scale=(0.04, 0.04, 1.0))
    add("rail", bpy.ops.mesh.primitive_cube_add, wood, size=1.0, location=(0, 2.0, 0.8), scale=(7.5, 0.02, 0.03))
    steel = material("steel", (0.3, 0.3, 0.33))
    add("wire", bpy.ops.mesh.primitive_cylinder_add, steel, radius=0.004, depth=9.0,
        location=(0.5, 3.5, 2.2), rotation=(0.0, math.radians(88.0), 0.0))
    ball = add("ball", bpy.ops.mesh.primitive_uv_sphere_add, material("ball", (0.85, 0.25, 0.1), checker=6.0),
               radius=0.5, location=(-3.0, 0.6, 0.5))
    bpy.ops.object.shade_smooth()
    for f in range(frames[0] - 1, frames[-1] + 2):  # keys either side: vectors at both ends
        ball.location = (-3.0 + 0.35 * f, 0.6, 0.5)
        ball.rotation_euler = (0.0, 0.35 * f / 0.5, 0.0)
        ball.keyframe_insert("location", frame=f)
        ball.keyframe_insert("rotation_euler", frame=f)

    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens = 35.0
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam
    for f in range(frames[0] - 1, frames[-1] + 2):
        eye = Vector((-1.0 + 0.08 * f, -6.0, 1.6))
        cam.location = eye
        cam.rotation_euler = (Vector((0.2 * math.sin(0.3 * f), 2.5, 0.9)) - eye).to_track_quat("-Z", "Y").to_euler()
        cam.keyframe_insert("location", frame=f)
        cam.keyframe_insert("rotation_euler", frame=f)
    for obj in (ball, cam):
        for fc in obj.animation_data.action.fcurves:
            for kp in fc.keyframe_points:
                kp.interpolation = "LINEAR"

    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy = 3.0
    sun_data.angle = 0.0
    sun = bpy.data.objects.new("sun", sun_data)
    sun.rotation_euler = (math.radians(50), 0, math.radians(30))
    scene.collection.objects.link(sun)
    # A sky the camera sees but that lights nothing (lighting from it would be noise at 1
    # spp): the background is black except on camera rays.
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    wn, wl = world.node_tree.nodes, world.node_tree.links
    sky = wn["Background"]
    sky.inputs["Color"].default_value = (0.45, 0.55, 0.75, 1.0)
    dark = wn.new("ShaderNodeBackground")
    dark.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    path = wn.new("ShaderNodeLightPath")
    mix = wn.new("ShaderNodeMixShader")
    wl.new(path.outputs["Is Camera Ray"], mix.inputs["Fac"])
    wl.new(dark.outputs["Background"], mix.inputs[1])
    wl.new(sky.outputs["Background"], mix.inputs[2])
    wl.new(mix.outputs["Shader"], wn["World Output"].inputs["Surface"])
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.cycles.filter_width = 0.01  # a point sample at the (jittered) pixel centre
    scene.cycles.max_bounces = 0
    scene.render.use_motion_blur = False  # Cycles writes the Vector pass only without it
    scene.render.resolution_x, scene.render.resolution_y = args.width, args.height
    scene.render.resolution_percentage = 100
    if args.threads:
        scene.render.threads_mode = "FIXED"
        scene.render.threads = args.threads
    scene.view_settings.view_transform = "Standard"
    layer = scene.view_layers[0]
    for p in ("combined", "z", "vector", "normal", "object_index", "diffuse_color"):
        setattr(layer, f"use_pass_{p}", True)
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "32"
    s.exr_codec = "ZIP"
    return scene


# --- render and stream -------------------------------------------------------------------


def main():
    args = parse_args()
    import_client(args.site)
    import bpy
    import numpy as np

    from afterimage_client import AfterimageError, Client, halton_jitter
    from afterimage_client.exr import Preset, frame_from_exr, read_exr, write_filtered

    frames = list(range(1, args.frames + 1))
    scene = build_scene(bpy, args, frames)
    big = max(args.width, args.height)
    in_dir, out_dir = os.path.join(args.out, "input"), os.path.join(args.out, "filtered")
    os.makedirs(in_dir, exist_ok=True)
    os.makedirs(out_dir, exist_ok=True)

    t_start = time.perf_counter()
    try:
        client = Client(args.server, api_key=args.api_key, tls_ca=args.tls_ca, tls_domain=args.tls_domain)
        info = client.filters().get(args.filter)
        if info is None:
            sys.exit(f"blender_stream: the server has no filter {args.filter!r}")
        channels = [c for c in ("color", "depth", "motion", "normal", "object_id", "albedo") if c == "color" or c in info.uses]
        params = dict(kv.split("=", 1) for kv in args.param)
        session = client.create_session(args.filter, width=args.width, height=args.height, params=params, channels=channels)
    except AfterimageError as e:
        sys.exit(f"blender_stream: {e}")
    print(f"[blender_stream] session {session.id[:8]}: {args.filter} at {args.width}x{args.height}, "
          f"sending {', '.join(channels)}", flush=True)

    preset = Preset("blender", scene.view_layers[0].name)
    stream = session.open_stream()
    inputs, timing, failure = {}, [], []

    def receive():
        try:
            for out in stream:
                image, rendered = inputs.pop(out.index)
                dest = os.path.join(out_dir, f"frame_{out.index:04d}.exr")
                write_filtered(image, out.color, dest, preset,
                               {"afterimage.record": json.dumps(out.figures.record, separators=(",", ":"))})
                timing.append({"frame": out.index, "render_s": rendered, "filter_ms": out.figures.total_ms,
                               "round_trip_ms": out.round_trip_s * 1000})
                print(f"[blender_stream] frame {out.index}: rendered in {rendered:.2f} s, filtered in "
                      f"{out.figures.total_ms:.2f} ms (round trip {out.round_trip_s * 1000:.1f} ms) -> {dest}", flush=True)
        except BaseException as e:  # reported on the main thread
            failure.append(e)

    receiver = threading.Thread(target=receive)
    receiver.start()
    render_total = 0.0
    for f in frames:
        j = (0.0, 0.0) if args.no_jitter else halton_jitter(f)
        scene.camera.data.shift_x = j[0] / big
        scene.camera.data.shift_y = -j[1] / big
        scene.frame_set(f)
        path = os.path.join(in_dir, f"frame_{f:04d}.exr")
        scene.render.filepath = path
        t = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        rendered = time.perf_counter() - t
        render_total += rendered
        # The jitter goes into the file as `afterimage filter` reads it, and into the frame.
        image = read_exr(path)
        image.header["afterimage.jitter"] = np.array(j, dtype=np.float32)
        write_filtered(image, np.stack([image.channels[n] for n in preset.names("color")], axis=-1), path, preset)
        frame, _ = frame_from_exr(image, preset, index=f)
        for c in list(frame.channels()):
            if c not in channels:
                setattr(frame, c, None)
        inputs[f] = (image, rendered)
        if failure:
            break
        stream.send(frame)  # returns at once: the next frame renders while this one is filtered
    stream.finish()
    receiver.join()
    session.close()
    client.close()
    wall = time.perf_counter() - t_start
    if failure:
        sys.exit(f"blender_stream: {failure[0]}")
    if len(timing) != len(frames):
        sys.exit(f"blender_stream: {len(frames)} frames sent, {len(timing)} came back")
    summary = {
        "blender": bpy.app.version_string,
        "filter": args.filter,
        "size": [args.width, args.height],
        "frames": len(frames),
        "wall_s": round(wall, 3),
        "render_s": round(render_total, 3),
        "median_filter_ms": float(np.median([t["filter_ms"] for t in timing])),
        "median_round_trip_ms": float(np.median([t["round_trip_ms"] for t in timing])),
        "per_frame": timing,
    }
    with open(os.path.join(args.out, "timing.json"), "w") as fh:
        json.dump(summary, fh, indent=1)
    print(f"[blender_stream] {len(frames)} frames of {args.width}x{args.height} in {wall:.1f} s: rendering "
          f"{render_total:.1f} s, filter median {summary['median_filter_ms']:.2f} ms, round trip median "
          f"{summary['median_round_trip_ms']:.1f} ms; filtered frames in {out_dir}", flush=True)


main()
