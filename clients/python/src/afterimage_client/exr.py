"""OpenEXR frames in and out, with the channel-name presets of `afterimage filter`.

The mapping is the Rust tool's (crates/core/src/io/preset.rs), so a directory that `afterimage filter`
reads gives this module the same frames:

========== ============================ ================== ======================
channel    blender (layer ``ViewLayer``) afterimage         nuke / plain
========== ============================ ================== ======================
color      ``L.Combined.{R,G,B}``        ``color.{R,G,B}``  ``rgba.{R,G,B}`` / ``R,G,B``
depth      ``L.Depth.Z``                 ``depth.Z``        afterimage's / ``Z``
motion     ``L.Vector.{X,Y}``            ``motion.{X,Y}``   afterimage's / -
motion_next ``L.Vector.{Z,W}``           ``motion_next.{X,Y}`` afterimage's / -
normal     ``L.Normal.{X,Y,Z}``          ``normal.{X,Y,Z}`` afterimage's / -
object_id  ``L.IndexOB.X`` (float)       ``object_id.id``   afterimage's / -
albedo     ``L.DiffCol.{R,G,B}``         ``albedo.{R,G,B}`` afterimage's / -
reference  -                             ``reference.{R,G,B}`` afterimage's / -
========== ============================ ================== ======================

Motion comes out in the internal convention (pixels, from the current pixel to its
position in the previous frame, x right, y down): Blender's ``Vector.XY`` points to the
previous frame with y up, so internal = ``(X, -Y)``; its ``Vector.ZW`` is minus the motion
to the next frame with y up, so internal motion_next = ``(-Z, W)``. Float object ids
(Blender's ``IndexOB``) are rounded; negative or non-finite ones are 0 (background).
A channel whose components are all missing is left out (the filter's stages that read it
are skipped); one with only some components is an error, as is any channel ``require``
names that is missing.

Files are read and written with the OpenEXR wheel, or with the package's own small reader
and writer (numpy and zlib: single-part scanline files, NONE/ZIPS/ZIP, what Blender writes)
inside Blender, whose own OpenEXR library crashes the wheel's when both are loaded in one
process. AFTERIMAGE_CLIENT_EXR=openexr or builtin forces one.
"""

from __future__ import annotations

import os
import re
import struct
import sys
import zlib
from dataclasses import dataclass
from typing import Any, Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from .client import COMPONENTS, AfterimageError, Frame

PRESET_CHOICES = ("auto", "afterimage", "blender", "nuke", "plain")

#: Channels as ordered by the Rust tool (ChannelKind::ALL).
CHANNELS = ("color", "depth", "motion", "motion_next", "normal", "object_id", "albedo", "reference")


class ExrError(AfterimageError):
    """A file that cannot be read as a frame, or a directory without frames."""


class MissingPassError(ExrError):
    """A pass the preset maps (or ``require`` asks for) is not in the file."""

    def __init__(self, path: str, channel: str, preset: "Preset", wanted: Sequence[str], present: Sequence[str], why: str = ""):
        self.path = path
        self.channel = channel
        self.preset = preset
        self.wanted = list(wanted)
        self.present = list(present)
        lead = f"{path}: no {', '.join(wanted)} for channel {channel} (preset {preset})"
        if why:
            lead += f"; {why}"
        super().__init__(f"{lead}; the file has: {', '.join(present)}")


@dataclass(frozen=True)
class Preset:
    """A channel-name layout: ``kind`` is afterimage, blender, nuke or plain; ``layer`` is
    Blender's view layer name."""

    kind: str
    layer: str = "ViewLayer"

    def __str__(self) -> str:
        if self.kind == "blender" and self.layer != "ViewLayer":
            return f"blender (layer {self.layer})"
        return self.kind

    def names(self, channel: str) -> Optional[List[str]]:
        """The file channel names of a frame channel, or None when the preset has none."""
        if channel not in COMPONENTS:
            raise ValueError(f"unknown channel {channel!r}")

        def join(prefix: str, comps: Iterable[str]) -> List[str]:
            return [prefix + c for c in comps]

        if self.kind == "afterimage":
            p = channel + "."
            if channel in ("color", "albedo", "reference"):
                return join(p, "RGB")
            if channel == "normal":
                return join(p, "XYZ")
            if channel in ("motion", "motion_next"):
                return join(p, "XY")
            if channel == "depth":
                return [p + "Z"]
            return [p + "id"]
        if self.kind == "blender":
            table = {
                "color": ("Combined", "RGB"),
                "depth": ("Depth", "Z"),
                "motion": ("Vector", "XY"),
                "motion_next": ("Vector", "ZW"),
                "normal": ("Normal", "XYZ"),
                "object_id": ("IndexOB", "X"),
                "albedo": ("DiffCol", "RGB"),
            }
            if channel not in table:
                return None
            pass_, comps = table[channel]
            return join(f"{self.layer}.{pass_}.", comps)
        if self.kind == "nuke":
            if channel == "color":
                return join("rgba.", "RGB")
            return Preset("afterimage").names(channel)
        if self.kind == "plain":
            if channel == "color":
                return ["R", "G", "B"]
            if channel == "depth":
                return ["Z"]
            return None
        raise ValueError(f"unknown preset {self.kind!r}")

    @property
    def motion_convention(self) -> str:
        """The session motion convention of this preset's motion channel."""
        return "blender" if self.kind == "blender" else "internal"


def detect_preset(names: Iterable[str]) -> Optional[Preset]:
    """The preset a file's channel names suggest, as `afterimage filter --preset auto` does."""
    names = sorted(names)
    if "color.R" in names:
        return Preset("afterimage")
    for n in names:
        if n.endswith(".Combined.R"):
            return Preset("blender", n[: -len(".Combined.R")])
    if "rgba.R" in names:
        return Preset("nuke")
    if "R" in names:
        return Preset("plain")
    return None


def resolve_preset(choice: str, names: Sequence[str], path: str = "<file>") -> Preset:
    """The preset for a file under ``choice`` (one of :data:`PRESET_CHOICES`)."""
    if choice not in PRESET_CHOICES:
        raise ExrError(f"unknown preset {choice!r}; expected one of {', '.join(PRESET_CHOICES)}")
    if choice == "auto":
        p = detect_preset(names)
        if p is None:
            raise ExrError(
                f"{path}: cannot tell the channel layout (no colour as `color.R`, `<layer>.Combined.R`, "
                f"`rgba.R` or `R`); pass --preset; the file has: {', '.join(sorted(names))}"
            )
        return p
    if choice == "blender":
        p = detect_preset(names)
        return p if p is not None and p.kind == "blender" else Preset("blender")
    return Preset(choice)


def channel_mapping(names: Sequence[str], preset: Preset, path: str = "<file>", require: Sequence[str] = ()) -> Dict[str, List[str]]:
    """Which file channels make which frame channel: colour must be there; any other
    channel is taken when all its components are, and is an error when only some are (or
    when ``require`` names it)."""
    have = set(names)
    present = sorted(names)
    for r in require:
        if r not in COMPONENTS:
            raise ExrError(f"cannot require {r!r}: not a channel; expected one of {', '.join(CHANNELS)}")
    out: Dict[str, List[str]] = {}
    for channel in CHANNELS:
        wanted = preset.names(channel)
        if wanted is None:
            if channel in require:
                raise ExrError(f"{path}: channel {channel} is required, but preset {preset} has no name for it")
            continue
        missing = [n for n in wanted if n not in have]
        if len(missing) == len(wanted) and channel != "color" and channel not in require:
            continue
        if missing:
            why = ""
            if len(missing) < len(wanted):
                why = f"expected all of {', '.join(wanted)}, found only {', '.join(n for n in wanted if n in have)}"
            elif channel in require:
                why = "the channel is required"
            raise MissingPassError(path, channel, preset, missing, present, why)
        out[channel] = wanted
    return out


@dataclass
class ExrImage:
    """A decoded single-part EXR: its header (attributes) and channels by full name."""

    path: str
    header: Dict[str, Any]
    channels: Dict[str, np.ndarray]
    width: int
    height: int
    #: The attributes as stored (type, bytes), when the built-in reader read the file.
    raw_attributes: Optional[Dict[str, Tuple[str, bytes]]] = None


def exr_backend() -> str:
    """``openexr`` (the OpenEXR wheel) or ``builtin`` (numpy and zlib): AFTERIMAGE_CLIENT_EXR,
    else builtin inside Blender and openexr elsewhere."""
    b = os.environ.get("AFTERIMAGE_CLIENT_EXR", "")
    if b in ("openexr", "builtin"):
        return b
    if b:
        raise ExrError(f"AFTERIMAGE_CLIENT_EXR={b!r}: expected openexr or builtin")
    return "builtin" if "bpy" in sys.modules else "openexr"


def read_exr(path: str, backend: Optional[str] = None) -> ExrImage:
    """Reads every channel of a single-part EXR file (scanline or tiled with the OpenEXR
    backend; scanline NONE/ZIPS/ZIP with the built-in one)."""
    if (backend or exr_backend()) == "builtin":
        from . import _exr_numpy

        if not os.path.exists(path):
            raise ExrError(f"{path}: no such file")
        try:
            attrs, raw, channels = _exr_numpy.read(str(path))
        except _exr_numpy.Unsupported as e:
            raise ExrError(f"{path}: {e}") from None
        except (OSError, ValueError, IndexError, KeyError, struct.error, zlib.error) as e:
            raise ExrError(f"{path}: not a readable OpenEXR file: {e}") from None
        if not channels:
            raise ExrError(f"{path}: no channels")
        height, width = next(iter(channels.values())).shape
        return ExrImage(str(path), attrs, channels, width, height, raw)
    import OpenEXR

    try:
        f = OpenEXR.File(str(path), separate_channels=True)
    except Exception as e:  # OpenEXR raises RuntimeError/OSError with its own message
        if not os.path.exists(path):
            raise ExrError(f"{path}: no such file") from None
        raise ExrError(f"{path}: not a readable OpenEXR file: {e}") from None
    if len(f.parts) != 1:
        raise ExrError(f"{path}: {len(f.parts)} parts; only single-part files (as Blender writes) are read here")
    header = dict(f.header())
    channels = {name: c.pixels for name, c in f.channels().items()}
    for name, ch in f.channels().items():
        if ch.xSampling != 1 or ch.ySampling != 1:
            raise ExrError(f"{path}: channel {name} is subsampled ({ch.xSampling}x{ch.ySampling}); not supported")
    if not channels:
        raise ExrError(f"{path}: no channels")
    shapes = {c.shape for c in channels.values()}
    if len(shapes) != 1:
        raise ExrError(f"{path}: channels of different sizes: {sorted(shapes)}")
    height, width = shapes.pop()
    return ExrImage(str(path), header, channels, width, height)


def frame_from_exr(image: ExrImage, preset: str | Preset = "auto", require: Sequence[str] = (), index: Optional[int] = None) -> Tuple[Frame, Preset]:
    """The frame in ``image`` under ``preset``, motion in the internal convention."""
    names = list(image.channels)
    if "afterimage.shading" in image.header:
        raise ExrError(f"{image.path}: sparse shading (the afterimage.shading attribute) is not read by this client; "
                       f"use `afterimage filter` for it")
    p = preset if isinstance(preset, Preset) else resolve_preset(preset, names, image.path)
    mapping = channel_mapping(names, p, image.path, require)
    kw: Dict[str, Any] = {}
    for channel, file_names in mapping.items():
        planes = [np.asarray(image.channels[n]) for n in file_names]
        if channel == "object_id":
            v = planes[0]
            if np.issubdtype(v.dtype, np.integer):
                ids = v.astype(np.uint32)
            else:
                v = v.astype(np.float32)
                ok = np.isfinite(v) & (v > 0)
                # Rust's f32::round (half away from zero), for positive values.
                ids = np.where(ok, np.floor(np.where(ok, v, 0) + np.float32(0.5)), 0).astype(np.uint32)
            kw[channel] = ids
            continue
        a = np.stack([pl.astype(np.float32) for pl in planes], axis=-1)
        if channel == "motion" and p.motion_convention == "blender":
            a[..., 1] = -a[..., 1]
        if channel == "motion_next" and p.kind == "blender":
            a[..., 0] = -a[..., 0]
        kw[channel] = a[..., 0] if channel == "depth" else a
    jitter = image.header.get("afterimage.jitter")
    if jitter is not None:
        j = tuple(float(x) for x in np.asarray(jitter).reshape(-1)[:2])
        jitter = j if all(np.isfinite(j)) and all(-1 <= x <= 1 for x in j) else None
    reset = image.header.get("afterimage.reset")
    frame = Frame(
        index=index,
        reset=bool(reset) if reset is not None else False,
        jitter=jitter if jitter is not None else (0.0, 0.0),
        **kw,
    )
    return frame, p


def read_frame(path: str, preset: str | Preset = "auto", require: Sequence[str] = (), index: Optional[int] = None, backend: Optional[str] = None) -> Tuple[Frame, ExrImage, Preset]:
    """Reads one EXR frame: the frame (internal motion), the file, and the preset used."""
    image = read_exr(path, backend)
    frame, p = frame_from_exr(image, preset, require, index)
    return frame, image, p


_NUMBER = re.compile(r"(\d+)(?=\.exr$)", re.IGNORECASE)


def find_frames(directory: str) -> List[Tuple[int, str]]:
    """The EXR files of a directory as (frame number, path), by number: the number is the
    last digits before ``.exr`` (``shot_0001.exr``, ``beauty.1001.exr``). Gaps and files
    without a number are errors (as `afterimage filter --missing error`)."""
    if not os.path.isdir(directory):
        if os.path.exists(directory):
            raise ExrError(f"{directory}: not a directory (give the directory holding the frames)")
        raise ExrError(f"{directory}: no such directory")
    files = sorted(f for f in os.listdir(directory) if f.lower().endswith(".exr"))
    if not files:
        others = sorted(os.listdir(directory))
        shown = ", ".join(others[:8]) + (", ..." if len(others) > 8 else "")
        raise ExrError(f"{directory}: no .exr frames" + (f" (it holds: {shown})" if others else " (it is empty)"))
    numbered = []
    for f in files:
        m = _NUMBER.search(f)
        if m is None:
            raise ExrError(f"{os.path.join(directory, f)}: no frame number before .exr (expected names like frame_0001.exr)")
        numbered.append((int(m.group(1)), os.path.join(directory, f)))
    numbered.sort()
    seen: Dict[int, str] = {}
    for n, path in numbered:
        if n in seen:
            raise ExrError(f"frame {n} twice: {seen[n]} and {path}")
        seen[n] = path
    for (a, _), (b, _) in zip(numbered, numbered[1:]):
        if b != a + 1:
            raise ExrError(f"{directory}: frames {a + 1}..{b - 1} are missing (between {a} and {b})")
    return numbered


def write_filtered(image: ExrImage, color: np.ndarray, path: str, preset: Preset, attributes: Optional[Dict[str, Any]] = None) -> None:
    """Writes ``image`` with its colour channels replaced by ``color`` (HxWx3), every other
    channel and attribute kept: a drop-in replacement of the input (`afterimage filter
    --keep all`). The colour keeps the input's sample type (half or float)."""
    names = preset.names("color")
    assert names is not None
    c = np.asarray(color)
    if c.shape != (image.height, image.width, 3):
        raise ExrError(f"{path}: filtered colour of shape {c.shape}, the input is {image.height}x{image.width}x3")
    channels = dict(image.channels)
    for i, n in enumerate(names):
        dtype = image.channels[n].dtype if n in image.channels else np.float32
        channels[n] = np.ascontiguousarray(c[..., i]).astype(dtype)
    if image.raw_attributes is None:
        import OpenEXR
    tmp = f"{path}.partial"
    try:
        if image.raw_attributes is not None:
            from . import _exr_numpy

            extra = {k: v for k, v in image.header.items() if k not in image.raw_attributes}
            extra.update(attributes or {})
            _exr_numpy.write(tmp, image.raw_attributes, extra, channels)
            os.replace(tmp, path)
            return
        header = {k: v for k, v in image.header.items() if k not in ("channels", "chunkCount")}
        for k, v in (attributes or {}).items():
            header[k] = v
        OpenEXR.File(header, channels).write(tmp)
        os.replace(tmp, path)
    except Exception as e:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise ExrError(f"{path}: cannot write: {e}") from None


def read_colour(path: str, preset: str = "auto", backend: Optional[str] = None) -> np.ndarray:
    """The colour of an EXR as HxWx3 float32 (for comparisons)."""
    image = read_exr(path, backend)
    p = resolve_preset(preset, list(image.channels), path)
    names = p.names("color")
    assert names is not None
    missing = [n for n in names if n not in image.channels]
    if missing:
        raise MissingPassError(path, "color", p, missing, sorted(image.channels))
    return np.stack([image.channels[n].astype(np.float32) for n in names], axis=-1)
