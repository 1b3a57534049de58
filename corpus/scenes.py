"""The afterimage corpus: procedural Blender Cycles scenes, jittered 1-spp inputs, references.

Run inside Blender (3.4 or later), headless:

    blender -b --factory-startup --python corpus/scenes.py -- \
        --scene fence --out CACHE/fence --width 160 --height 90 --frames 8 \
        --ref-spp 256 [--half] [--threads 1] [--only input|reference]

Writes `OUT/input/frame_####.exr` (multilayer: Combined, Depth, Vector, Normal, IndexOB,
DiffCol, i.e. every channel afterimage's `blender` preset maps; 1 sample per pixel,
Blackman-Harris width 0.01 so the sample sits at the pixel centre, moved by a Halton(2,3)
sub-pixel camera shift per frame), `OUT/reference/frame_####.exr` (colour only, `R,G,B`,
`--ref-spp` samples with Cycles' default Blackman-Harris 1.5 px pixel filter, no shift),
`OUT/input/jitter.json` (a sidecar `{"frame": [x, y]}`) and `OUT/meta.json`.

Jitter convention (afterimage's `FrameMeta::jitter`): the offset of the input sample from
the pixel centre, in pixels, x right, y down. A camera shift of (sx, sy) (Blender units: a
fraction of the larger image side) moves the sample to (sx * M, -sy * M) with M = max(W, H).
Each input file carries it in its header as the v2f attribute `afterimage.jitter` (added
after rendering by `exr_attr.py`). Blender's motion vectors are computed with the current
frame's shift for both ends, so they exclude the jitter (afterimage's `blender` convention,
`jittered: false`); see corpus/README.md for the check.

Every scene is closed by an emissive sky dome (no infinite depth, which half floats would
turn into inf). Scenes meant to show aliasing rather than noise use one light with a hard
shadow, no bounces and an emission term for ambient light, so 1 spp is noise-free.
"""

import argparse
import json
import math
import os
import runpy
import sys
import time

import bpy
from mathutils import Euler, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import exr_attr  # noqa: E402

HALTON_PHASES = 8
# afterimage_client's jitter (`scene::halton_jitter` in Python), run from its file: Blender's
# Python has neither that package nor its dependencies, and the module imports nothing.
_JITTER = runpy.run_path(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "clients", "python", "src",
                                      "afterimage_client", "jitter.py"))


def halton_jitter(frame):
    """afterimage's `scene::halton_jitter(frame, 8)`: pixels, x right, y down."""
    return _JITTER["halton_jitter"](frame, HALTON_PHASES)


# --------------------------------------------------------------------------- materials


def _principled(name, color_node_fn=None, color=(0.6, 0.6, 0.6), ambient=0.0, roughness=0.5,
                metallic=0.0, specular=0.5, alpha_fn=None):
    """A Principled material; `color_node_fn(nodes, links)` returns a colour socket (a
    texture), `ambient` adds emission = colour * ambient (flat ambient light without noise),
    `alpha_fn` returns a 0/1 mask socket mixing in a Transparent BSDF."""
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    out = nodes["Material Output"]
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Metallic"].default_value = metallic
    bsdf.inputs["Specular"].default_value = specular
    if color_node_fn is not None:
        sock = color_node_fn(nodes, links)
        links.new(sock, bsdf.inputs["Base Color"])
        if ambient > 0:
            links.new(sock, bsdf.inputs["Emission"])
    else:
        bsdf.inputs["Base Color"].default_value = (*color, 1.0)
        bsdf.inputs["Emission"].default_value = (*color, 1.0)
    bsdf.inputs["Emission Strength"].default_value = ambient
    if alpha_fn is not None:
        mask = alpha_fn(nodes, links)
        transparent = nodes.new("ShaderNodeBsdfTransparent")
        mix = nodes.new("ShaderNodeMixShader")
        links.new(mask, mix.inputs["Fac"])
        links.new(transparent.outputs[0], mix.inputs[1])
        links.new(bsdf.outputs[0], mix.inputs[2])
        links.new(mix.outputs[0], out.inputs["Surface"])
    mat.cycles.sample_as_light = False
    return mat


def checker(scale, c1, c2):
    def fn(nodes, links):
        t = nodes.new("ShaderNodeTexChecker")
        t.inputs["Scale"].default_value = scale
        t.inputs["Color1"].default_value = (*c1, 1.0)
        t.inputs["Color2"].default_value = (*c2, 1.0)
        return t.outputs["Color"]

    return fn


def bricks(scale):
    def fn(nodes, links):
        t = nodes.new("ShaderNodeTexBrick")
        t.inputs["Scale"].default_value = scale
        t.inputs["Color1"].default_value = (0.55, 0.2, 0.12, 1.0)
        t.inputs["Color2"].default_value = (0.35, 0.12, 0.08, 1.0)
        t.inputs["Mortar"].default_value = (0.8, 0.8, 0.75, 1.0)
        return t.outputs["Color"]

    return fn


def stripes(scale, c1, c2):
    """Sharp-edged sine stripes (a wave texture through a step)."""

    def fn(nodes, links):
        w = nodes.new("ShaderNodeTexWave")
        w.inputs["Scale"].default_value = scale
        w.inputs["Distortion"].default_value = 2.0
        step = nodes.new("ShaderNodeMath")
        step.operation = "GREATER_THAN"
        step.inputs[1].default_value = 0.5
        links.new(w.outputs["Fac"], step.inputs[0])
        mix = nodes.new("ShaderNodeMixRGB")
        mix.inputs["Color1"].default_value = (*c1, 1.0)
        mix.inputs["Color2"].default_value = (*c2, 1.0)
        links.new(step.outputs[0], mix.inputs["Fac"])
        return mix.outputs["Color"]

    return fn


def leaf_mask(nodes, links):
    """A 0/1 leaf-shaped mask: an ellipse in UV with a noisy, serrated edge."""
    tc = nodes.new("ShaderNodeTexCoord")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(tc.outputs["UV"], sep.inputs[0])
    # ((u - .5) / .5)^2 + ((v - .5) / .25)^2 < 1 - 0.35 * noise
    def axis(sock, scale):
        sub = nodes.new("ShaderNodeMath")
        sub.operation = "SUBTRACT"
        sub.inputs[1].default_value = 0.5
        links.new(sock, sub.inputs[0])
        mul = nodes.new("ShaderNodeMath")
        mul.operation = "MULTIPLY"
        mul.inputs[1].default_value = scale
        links.new(sub.outputs[0], mul.inputs[0])
        sq = nodes.new("ShaderNodeMath")
        sq.operation = "POWER"
        sq.inputs[1].default_value = 2.0
        links.new(mul.outputs[0], sq.inputs[0])
        return sq.outputs[0]

    add = nodes.new("ShaderNodeMath")
    add.operation = "ADD"
    links.new(axis(sep.outputs["X"], 2.0), add.inputs[0])
    links.new(axis(sep.outputs["Y"], 4.0), add.inputs[1])
    noise = nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = 12.0
    links.new(tc.outputs["UV"], noise.inputs["Vector"])
    thr = nodes.new("ShaderNodeMath")
    thr.operation = "MULTIPLY_ADD"
    thr.inputs[1].default_value = -0.6
    thr.inputs[2].default_value = 1.2
    links.new(noise.outputs["Fac"], thr.inputs[0])
    lt = nodes.new("ShaderNodeMath")
    lt.operation = "LESS_THAN"
    links.new(add.outputs[0], lt.inputs[0])
    links.new(thr.outputs[0], lt.inputs[1])
    return lt.outputs[0]


def emitter(name, color, strength):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    em = nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    em.inputs["Strength"].default_value = strength
    links.new(em.outputs[0], nodes["Material Output"].inputs["Surface"])
    mat.cycles.sample_as_light = False
    return mat


def metal(name, color, roughness=0.0):
    mat = bpy.data.materials.new(name)
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    g = nodes.new("ShaderNodeBsdfGlossy")
    g.distribution = "SHARP" if roughness == 0.0 else "GGX"
    g.inputs["Color"].default_value = (*color, 1.0)
    g.inputs["Roughness"].default_value = roughness
    links.new(g.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def sky_material(top=(0.35, 0.5, 0.8), bottom=(0.8, 0.85, 0.9), strength=1.0):
    """A vertical gradient, seen but never sampled as a light."""
    mat = bpy.data.materials.new("sky")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    tc = nodes.new("ShaderNodeTexCoord")
    sep = nodes.new("ShaderNodeSeparateXYZ")
    links.new(tc.outputs["Normal"], sep.inputs[0])
    ramp = nodes.new("ShaderNodeMixRGB")
    ramp.inputs["Color1"].default_value = (*bottom, 1.0)
    ramp.inputs["Color2"].default_value = (*top, 1.0)
    clamp = nodes.new("ShaderNodeMath")
    clamp.operation = "MULTIPLY"
    clamp.use_clamp = True
    clamp.inputs[1].default_value = -1.0  # the dome's normals point inwards
    links.new(sep.outputs["Z"], clamp.inputs[0])
    links.new(clamp.outputs[0], ramp.inputs["Fac"])
    em = nodes.new("ShaderNodeEmission")
    em.inputs["Strength"].default_value = strength
    links.new(ramp.outputs[0], em.inputs["Color"])
    links.new(em.outputs[0], nodes["Material Output"].inputs["Surface"])
    mat.cycles.sample_as_light = False
    return mat


# --------------------------------------------------------------------------- objects

_INDEX = {"next": 1, "names": {}}


def _finish(obj, name, mat):
    obj.name = name
    if mat is not None:
        obj.data.materials.append(mat)
    obj.pass_index = _INDEX["next"]
    _INDEX["names"][name] = _INDEX["next"]
    _INDEX["next"] += 1
    return obj


def box(name, loc, size, mat, rot=(0, 0, 0)):
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=loc, rotation=rot)
    obj = bpy.context.active_object
    obj.scale = size
    return _finish(obj, name, mat)


def sphere(name, loc, radius, mat):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=48, ring_count=24, radius=radius, location=loc)
    obj = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    return _finish(obj, name, mat)


def cylinder(name, a, b, radius, mat):
    """A thin cylinder from point a to point b."""
    a, b = Vector(a), Vector(b)
    d = b - a
    bpy.ops.mesh.primitive_cylinder_add(vertices=12, radius=radius, depth=d.length, location=(a + b) / 2)
    obj = bpy.context.active_object
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = d.to_track_quat("Z", "Y")
    return _finish(obj, name, mat)


def plane(name, loc, size, mat, rot=(0, 0, 0)):
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=loc, rotation=rot)
    obj = bpy.context.active_object
    obj.scale = (size[0], size[1], 1.0)
    return _finish(obj, name, mat)


def sky_dome(radius=80.0, **kw):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=32, ring_count=16, radius=radius)
    obj = bpy.context.active_object
    obj.name = "sky"
    obj.data.materials.append(sky_material(**kw))
    obj.visible_shadow = False
    obj.pass_index = 0
    return obj


def light_object(name, kind, energy, **settings):
    """A light of `kind` named `name` with `energy` and the light `settings`, linked
    into the scene."""
    light = bpy.data.lights.new(name, kind)
    light.energy = energy
    for key, value in settings.items():
        setattr(light, key, value)
    obj = bpy.data.objects.new(name, light)
    bpy.context.scene.collection.objects.link(obj)
    return obj


def sun(direction_euler, strength=3.0, angle=0.0):
    obj = light_object("sun", "SUN", strength, angle=angle)
    obj.rotation_euler = Euler(direction_euler)
    return obj


def point_light(loc, power=800.0, radius=0.0):
    obj = light_object("lamp", "POINT", power, shadow_soft_size=radius)
    obj.location = loc
    return obj


def keyframes(obj, frames, fn, constant=False):
    """Keys obj's location/rotation at every frame in `frames` from fn(frame) ->
    (location, rotation_euler or None)."""
    for f in frames:
        loc, rot = fn(f)
        obj.location = loc
        obj.keyframe_insert("location", frame=f)
        if rot is not None:
            obj.rotation_mode = "XYZ"
            obj.rotation_euler = rot
            obj.keyframe_insert("rotation_euler", frame=f)
    interp = "CONSTANT" if constant else "LINEAR"
    if obj.animation_data and obj.animation_data.action:
        for fc in obj.animation_data.action.fcurves:
            for kp in fc.keyframe_points:
                kp.interpolation = interp


def camera(lens=35.0):
    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens = lens
    cam_data.clip_start = 0.05
    cam_data.clip_end = 500.0
    cam = bpy.data.objects.new("camera", cam_data)
    bpy.context.scene.collection.objects.link(cam)
    bpy.context.scene.camera = cam
    return cam


def look_at(eye, target):
    eye, target = Vector(eye), Vector(target)
    return tuple(eye), (target - eye).to_track_quat("-Z", "Y").to_euler()


# --------------------------------------------------------------------------- scenes
# Each builder takes the frame range (with one extra frame either side, so motion vectors
# are defined at both ends) and returns the render settings that differ from the default
# aliasing setup ({"gi": True} for path-traced noise, {"glossy": True} for mirror bounces).


def ground(scale=40.0, squares=160.0, specular=0.5):
    return plane("ground", (0, 0, 0), (scale, scale), _principled(
        "ground", checker(squares, (0.75, 0.75, 0.7), (0.15, 0.15, 0.15)), ambient=0.3, specular=specular))


def scene_fence(frames, gi=False):
    """Thin geometry and wires: 4 cm posts, rails, poles, a 4 mm wire; a sphere moving
    0.5 m/frame; a camera on a curved path; one sun with hard shadows."""
    amb = 0.0 if gi else 0.3
    ground(squares=120.0)
    wood = _principled("wood", color=(0.55, 0.42, 0.3), ambient=amb)
    for i in range(21):
        box(f"post_{i:02d}", (-5 + 0.5 * i, 2.0, 0.5), (0.04, 0.04, 1.0), wood)
    for k, z in enumerate((0.35, 0.85)):
        box(f"rail_{k}", (0, 2.0, z), (10.0, 0.02, 0.03), wood)
    steel = _principled("steel", color=(0.3, 0.3, 0.32), ambient=amb, metallic=0.0, roughness=0.3)
    for k, x in enumerate((-3.0, 0.5, 4.0)):
        cylinder(f"pole_{k}", (x, 4.0, 0), (x, 4.0, 4.0), 0.03, steel)
    cylinder("wire", (-3.0, 4.0, 3.8), (4.0, 4.0, 3.6), 0.004, steel)
    cylinder("wire_1", (-3.0, 4.0, 3.3), (4.0, 4.0, 3.0), 0.004, steel)
    ball = sphere("sphere", (0, 0, 0.5), 0.5, _principled(
        "ball", checker(8.0, (0.8, 0.2, 0.1), (0.9, 0.85, 0.2)), ambient=amb))
    keyframes(ball, frames, lambda f: ((-4.0 + 0.5 * f, 0.8, 0.5), (0, 0, 0.3 * f)))
    cam = camera(35.0)
    keyframes(cam, frames, lambda f: look_at(
        (-1.5 + 0.12 * f + 0.6 * math.sin(0.25 * f), -6.0 + 0.05 * f * f / 4, 1.6 + 0.2 * math.sin(0.4 * f)),
        (0.3 * math.sin(0.2 * f), 2.5, 1.0)))
    sun((math.radians(50), 0, math.radians(30)), strength=3.0, angle=math.radians(3.0) if gi else 0.0)
    sky_dome()
    return {"gi": gi}


def scene_fence_gi(frames):
    """`fence` path traced: bounces, sky light, soft sun, so 1 spp is noisy."""
    return scene_fence(frames, gi=True)


def scene_pan(frames):
    """Fast camera with disocclusion: near pillars sweep across a brick wall and a
    checkered floor while the camera strafes 0.35 m/frame and turns."""
    ground(squares=80.0)
    plane("wall", (0, 6.0, 2.5), (30.0, 5.0), _principled("wall", bricks(6.0), ambient=0.3),
          rot=(math.radians(90), 0, 0))
    for i in range(12):
        box(f"pillar_{i:02d}", (-8 + 1.5 * i, 1.0 + (i % 3) * 0.7, 1.2), (0.25, 0.25, 2.4),
            _principled(f"pillar_{i}", color=(0.2 + 0.06 * i, 0.5, 0.8 - 0.05 * i), ambient=0.3))
    cam = camera(30.0)
    keyframes(cam, frames, lambda f: look_at(
        (-5.0 + 0.35 * f, -3.0, 1.5), (-5.0 + 0.35 * f + 1.5 * math.sin(0.15 * f), 6.0, 1.2)))
    sun((math.radians(45), 0, math.radians(-40)), strength=3.0)
    sky_dome()
    return {}


def scene_movers(frames):
    """Moving objects and their shadows: boxes and spheres crossing and spinning over a
    checkered floor under a low sun; the camera dollies slowly."""
    ground(squares=60.0)
    for i in range(6):
        mat = _principled(f"mover_{i}", color=(0.9 - 0.12 * i, 0.3 + 0.1 * i, 0.2 + 0.1 * (i % 3)), ambient=0.3)
        if i % 2 == 0:
            obj = box(f"box_{i}", (0, 0, 0.4), (0.6, 0.6, 0.8), mat)
        else:
            obj = sphere(f"ball_{i}", (0, 0, 0.4), 0.4, mat)
        speed = 0.15 + 0.07 * i
        y0 = -1.0 + 0.8 * i
        keyframes(obj, frames, lambda f, s=speed, y=y0, k=i: (
            ((-3.0 + s * f) if k % 2 == 0 else (3.0 - s * f), y, 0.4 + (0.3 * abs(math.sin(0.5 * f)) if k == 3 else 0)),
            (0, 0, 0.2 * f * (1 + k))))
    cam = camera(35.0)
    keyframes(cam, frames, lambda f: look_at((0.5, -6.5 + 0.04 * f, 3.0), (0, 1.0, 0.3)))
    sun((math.radians(68), 0, math.radians(60)), strength=3.0)
    sky_dome()
    return {}


def scene_hdr(frames):
    """HDR emitters and specular highlights: thin strips and small bulbs at 20-200x the
    diffuse level, sharp mirror and glossy spheres reflecting them; an orbiting camera."""
    ground(squares=40.0, specular=0.0)
    for i in range(5):
        box(f"strip_{i}", (-2 + i, 3.0, 1.5 + 0.3 * (i % 2)), (0.6, 0.02, 0.02),
            emitter(f"strip_{i}", (1.0, 0.85, 0.6), 60.0))
    for i in range(8):
        sphere(f"bulb_{i}", (-3 + 0.85 * i, 1.0 + (i % 2), 2.2), 0.02, emitter(f"bulb_{i}", (0.6, 0.8, 1.0), 200.0))
    sphere("mirror", (-0.8, 0.5, 0.6), 0.6, metal("mirror", (0.9, 0.9, 0.9)))
    sphere("gold", (0.9, 0.9, 0.5), 0.5, metal("gold", (1.0, 0.75, 0.3)))
    box("chrome", (0.0, -0.6, 0.25), (0.5, 0.5, 0.5), metal("chrome", (0.8, 0.8, 0.85)), rot=(0, 0, 0.6))
    cam = camera(40.0)
    keyframes(cam, frames, lambda f: look_at(
        (5.0 * math.sin(-0.6 + 0.04 * f), -5.0 * math.cos(-0.6 + 0.04 * f), 1.8), (0, 0.8, 0.8)))
    sun((math.radians(35), 0, math.radians(150)), strength=2.0)
    sky_dome(top=(0.05, 0.06, 0.1), bottom=(0.1, 0.1, 0.12))
    return {"glossy": True}


def scene_texture(frames):
    """High-frequency textures: a fine checker floor, bricks and sharp wave stripes at
    grazing angles; the camera glides forward and pans."""
    ground(squares=400.0)
    plane("stripes", (-3.0, 3.0, 1.5), (6.0, 3.0), _principled(
        "stripes", stripes(25.0, (0.9, 0.9, 0.85), (0.1, 0.1, 0.15)), ambient=0.3), rot=(math.radians(90), 0, math.radians(-30)))
    plane("bricks", (3.0, 3.0, 1.5), (6.0, 3.0), _principled(
        "bricks", bricks(14.0), ambient=0.3), rot=(math.radians(90), 0, math.radians(30)))
    cam = camera(35.0)
    keyframes(cam, frames, lambda f: look_at(
        (0.1 * math.sin(0.3 * f), -6.0 + 0.08 * f, 1.0), (0.4 * math.sin(0.1 * f), 4.0, 0.6)))
    sun((math.radians(40), 0, math.radians(20)), strength=3.0)
    sky_dome()
    return {}


def scene_foliage(frames):
    """Foliage with alpha: leaf quads cut out by a procedural 0/1 mask (a Transparent BSDF
    mix), swaying each frame, in front of the sky and a trunk; the camera drifts."""
    ground(squares=30.0)
    box("trunk", (0, 1.0, 1.2), (0.25, 0.25, 2.4), _principled("bark", color=(0.3, 0.2, 0.12), ambient=0.3))
    leaf = _principled("leaf", color=(0.2, 0.55, 0.15), ambient=0.35, alpha_fn=leaf_mask)
    import random
    rng = random.Random(7)
    for i in range(90):
        base = (rng.uniform(-1.6, 1.6), 1.0 + rng.uniform(-1.2, 1.2), rng.uniform(1.6, 3.4))
        rot0 = (rng.uniform(0, math.pi), rng.uniform(-0.6, 0.6), rng.uniform(0, 2 * math.pi))
        obj = plane(f"leaf_{i:02d}", base, (0.35, 0.35), leaf, rot=rot0)
        ph = rng.uniform(0, 2 * math.pi)
        keyframes(obj, frames, lambda f, b=base, r=rot0, p=ph: (
            (b[0] + 0.03 * math.sin(0.7 * f + p), b[1], b[2]),
            (r[0] + 0.12 * math.sin(0.6 * f + p), r[1], r[2])))
    cam = camera(40.0)
    keyframes(cam, frames, lambda f: look_at((-1.5 + 0.06 * f, -4.5, 2.0), (0, 1.0, 2.3)))
    sun((math.radians(40), 0, math.radians(-20)), strength=3.0)
    sky_dome()
    # Cutouts stacked several deep: enough transparent bounces for the shadow rays.
    bpy.context.scene.cycles.transparent_max_bounces = 32
    return {}


def scene_light(frames):
    """A moving light: static camera and objects, a point light circling them, so only the
    shading and the shadows move (zero motion vectors on changing pixels)."""
    ground(squares=50.0)
    for i in range(4):
        box(f"block_{i}", (-1.5 + i, 0.8 * (i % 2), 0.35 + 0.15 * i), (0.5, 0.5, 0.7 + 0.3 * i),
            _principled(f"block_{i}", color=(0.7, 0.6 - 0.1 * i, 0.3 + 0.15 * i), ambient=0.2))
    cylinder("rod", (-2.5, 1.5, 0), (2.5, 1.5, 1.8), 0.02, _principled("rod", color=(0.8, 0.8, 0.8), ambient=0.2))
    lamp = point_light((0, 0, 2.5), power=600.0)
    keyframes(lamp, frames, lambda f: ((2.5 * math.cos(0.3 * f), 0.5 + 2.5 * math.sin(0.3 * f), 2.5), None))
    cam = camera(35.0)
    keyframes(cam, frames, lambda f: look_at((0.0, -6.0, 3.5), (0, 0.5, 0.3)))
    sky_dome(top=(0.1, 0.12, 0.2), bottom=(0.15, 0.15, 0.18))
    return {}


def scene_gi(frames):
    """Path-traced 1-spp noise: a closed room with coloured walls and a small area light
    (soft shadows, colour bleeding, 4 bounces); objects and a slowly moving camera."""
    white = _principled("white", color=(0.75, 0.75, 0.72))
    plane("floor", (0, 0, 0), (6, 6), white)
    plane("ceiling", (0, 0, 3), (6, 6), white, rot=(math.pi, 0, 0))
    plane("back", (0, 3, 1.5), (6, 3), white, rot=(math.radians(90), 0, 0))
    plane("front", (0, -3, 1.5), (6, 3), white, rot=(math.radians(-90), 0, 0))
    plane("left", (-3, 0, 1.5), (3, 6), _principled("red", color=(0.7, 0.12, 0.1)), rot=(0, math.radians(90), 0))
    plane("right", (3, 0, 1.5), (3, 6), _principled("green", color=(0.12, 0.6, 0.15)), rot=(0, math.radians(-90), 0))
    box("tall", (-0.9, 1.0, 0.9), (0.8, 0.8, 1.8), white, rot=(0, 0, 0.35))
    sphere("ball", (0.9, 0.2, 0.5), 0.5, _principled("ball", color=(0.8, 0.7, 0.3), roughness=0.2))
    light = bpy.data.lights.new("area", "AREA")
    light.size = 0.8
    light.energy = 250.0
    lobj = bpy.data.objects.new("area", light)
    lobj.location = (0, 0.3, 2.95)
    bpy.context.scene.collection.objects.link(lobj)
    cam = camera(28.0)
    keyframes(cam, frames, lambda f: look_at((0.6 * math.sin(0.15 * f), -2.8, 1.5), (0, 1.0, 1.0)))
    return {"gi": True, "world": (0.0, 0.0, 0.0)}


def scene_cut(frames):
    """A camera cut: half-way through, the camera jumps to another view of the same set
    (its motion vectors then point at the previous shot); a sphere keeps moving."""
    ground(squares=100.0)
    for i in range(8):
        box(f"crate_{i}", (-3 + 0.9 * i, 1.0 + (i % 3) * 0.8, 0.3), (0.6, 0.6, 0.6),
            _principled(f"crate_{i}", checker(4.0, (0.8, 0.6, 0.3), (0.5, 0.3, 0.1)), ambient=0.3), rot=(0, 0, 0.3 * i))
    wood = _principled("wood", color=(0.55, 0.42, 0.3), ambient=0.3)
    for i in range(15):
        box(f"post_{i:02d}", (-3.5 + 0.5 * i, 3.5, 0.6), (0.05, 0.05, 1.2), wood)
    ball = sphere("sphere", (0, 0, 0.4), 0.4, _principled("ball", checker(8.0, (0.2, 0.3, 0.9), (0.9, 0.9, 0.9)), ambient=0.3))
    keyframes(ball, frames, lambda f: ((-2.0 + 0.3 * f, 0.0, 0.4), (0, 0, 0.4 * f)))
    cut = (frames[0] + frames[-1] + 1) // 2
    cam = camera(35.0)

    def shot(f):
        if f < cut:
            return look_at((-2.0 + 0.05 * f, -6.0, 2.0), (0, 1.5, 0.5))
        return look_at((5.5, -1.0 + 0.05 * f, 1.2), (0, 1.5, 0.6))

    keyframes(cam, frames, shot, constant=True)
    sun((math.radians(55), 0, math.radians(-35)), strength=3.0)
    sky_dome()
    return {"cut_at": cut}


SCENES = {
    "fence": scene_fence,
    "fence_gi": scene_fence_gi,
    "pan": scene_pan,
    "movers": scene_movers,
    "hdr": scene_hdr,
    "texture": scene_texture,
    "foliage": scene_foliage,
    "light": scene_light,
    "gi": scene_gi,
    "cut": scene_cut,
}


# --------------------------------------------------------------------------- render


def setup(args, extra):
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.render.resolution_x = args.width
    scene.render.resolution_y = args.height
    scene.render.resolution_percentage = 100
    scene.render.use_motion_blur = False
    scene.render.threads_mode = "FIXED"
    scene.render.threads = args.threads
    scene.cycles.use_denoising = False
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.seed = 1
    scene.cycles.use_animated_seed = True
    scene.cycles.pixel_filter_type = "BLACKMAN_HARRIS"
    scene.view_settings.view_transform = "Standard"
    scene.render.film_transparent = False
    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (*extra.get("world", (0.0, 0.0, 0.0)), 1.0)
    scene.world = world
    if extra.get("gi"):
        scene.cycles.max_bounces = 4
        scene.cycles.diffuse_bounces = 4
        scene.cycles.glossy_bounces = 4
        if "world" not in extra:
            world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.35, 0.45, 0.6, 1.0)
        # The sky dome is seen, the world lights: hide the dome from indirect rays.
        for obj in scene.objects:
            if obj.name == "sky":
                obj.visible_diffuse = False
                obj.visible_glossy = False
    else:
        # Emission on every surface (the ambient term) would make each object a light
        # that BSDF rays find at random: hide objects from diffuse rays (and from glossy
        # ones unless the scene has mirrors), so 1 spp is deterministic up to aliasing.
        for obj in scene.objects:
            obj.visible_diffuse = False
            obj.visible_glossy = bool(extra.get("glossy"))
        scene.cycles.max_bounces = 1 if extra.get("glossy") else 0
        scene.cycles.diffuse_bounces = 0
        scene.cycles.glossy_bounces = 1 if extra.get("glossy") else 0
        scene.cycles.transmission_bounces = 0
    scene.cycles.caustics_reflective = True
    scene.cycles.sample_clamp_direct = 0.0
    scene.cycles.sample_clamp_indirect = 0.0


def set_jitter(scene, j):
    """Moves the camera so every pixel's sample lands at its centre + j (pixels, x right,
    y down). Blender's shift is a fraction of the larger image side, y up."""
    big = max(scene.render.resolution_x, scene.render.resolution_y)
    scene.camera.data.shift_x = j[0] / big
    scene.camera.data.shift_y = -j[1] / big


def set_gbuffer_passes(layer, on):
    """Turns the view layer's G-buffer passes (what the inputs carry beside the colour
    and the reference leaves out) on or off."""
    for name in ("z", "vector", "normal", "object_index", "diffuse_color"):
        setattr(layer, f"use_pass_{name}", on)


def render_input(args, out, frames):
    scene = bpy.context.scene
    layer = scene.view_layers[0]
    layer.use_pass_combined = True
    set_gbuffer_passes(layer, True)
    scene.cycles.samples = 1
    scene.cycles.filter_width = 0.01
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR_MULTILAYER"
    s.color_depth = "16" if args.half else "32"
    s.exr_codec = "ZIP"
    os.makedirs(os.path.join(out, "input"), exist_ok=True)
    jitters = {}
    for f in frames:
        j = halton_jitter(f) if not args.no_jitter else (0.0, 0.0)
        set_jitter(scene, j)
        scene.frame_set(f)
        path = os.path.join(out, "input", f"frame_{f:04d}.exr")
        scene.render.filepath = path
        t = time.time()
        bpy.ops.render.render(write_still=True)
        exr_attr.set_v2f(path, "afterimage.jitter", j[0], j[1])
        jitters[str(f)] = [j[0], j[1]]
        print(f"[corpus] {args.scene} input frame {f}: {time.time() - t:.1f} s", flush=True)
    with open(os.path.join(out, "input", "jitter.json"), "w") as fh:
        json.dump(jitters, fh, indent=1)
    return jitters


def render_reference(args, out, frames):
    scene = bpy.context.scene
    layer = scene.view_layers[0]
    set_gbuffer_passes(layer, False)
    scene.cycles.samples = args.ref_spp
    scene.cycles.filter_width = 1.5
    # Another seed than the inputs': the reference's first sample must not be the input's.
    scene.cycles.seed = 1000
    scene.camera.data.shift_x = 0.0
    scene.camera.data.shift_y = 0.0
    s = scene.render.image_settings
    s.file_format = "OPEN_EXR"
    s.color_mode = "RGB"
    s.color_depth = "16" if args.half else "32"
    s.exr_codec = "ZIP"
    os.makedirs(os.path.join(out, "reference"), exist_ok=True)
    for f in frames:
        scene.frame_set(f)
        scene.render.filepath = os.path.join(out, "reference", f"frame_{f:04d}.exr")
        t = time.time()
        bpy.ops.render.render(write_still=True)
        print(f"[corpus] {args.scene} reference frame {f}: {time.time() - t:.1f} s", flush=True)


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", required=True, choices=sorted(SCENES))
    p.add_argument("--out", required=True)
    p.add_argument("--width", type=int, default=320)
    p.add_argument("--height", type=int, default=180)
    p.add_argument("--frames", type=int, default=24)
    p.add_argument("--ref-spp", type=int, default=256)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--half", action="store_true", help="half-float EXR (the committed subset)")
    p.add_argument("--no-jitter", action="store_true", help="inputs at pixel centres")
    p.add_argument("--only", choices=("input", "reference"))
    args = p.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    frames = list(range(1, args.frames + 1))
    keyed = list(range(0, args.frames + 2))
    extra = SCENES[args.scene](keyed) or {}
    setup(args, extra)
    os.makedirs(args.out, exist_ok=True)
    t0 = time.time()
    jitters = None
    if args.only in (None, "input"):
        jitters = render_input(args, args.out, frames)
    if args.only in (None, "reference"):
        render_reference(args, args.out, frames)
    meta = {
        "scene": args.scene,
        "about": SCENES[args.scene].__doc__.strip().replace("\n    ", " "),
        "blender": bpy.app.version_string,
        "resolution": [args.width, args.height],
        "frames": frames,
        "input": {"samples": 1, "pixel_filter": ["BLACKMAN_HARRIS", 0.01], "half": args.half},
        "reference": {"samples": args.ref_spp, "pixel_filter": ["BLACKMAN_HARRIS", 1.5], "jitter": [0.0, 0.0]},
        "jitter": "Halton(2,3), 8 phases: afterimage scene::halton_jitter(frame, 8); pixels, x right, y down (offset of the input sample from the pixel centre); header attribute afterimage.jitter and input/jitter.json",
        "per_frame_jitter": jitters,
        "settings": {k: v for k, v in extra.items()},
        "object_pass_index": _INDEX["names"],
        "render_seconds": round(time.time() - t0, 1),
    }
    if args.only != "reference":
        with open(os.path.join(args.out, "meta.json"), "w") as fh:
            json.dump(meta, fh, indent=1)


if __name__ == "__main__":
    main()
