"""afterimage-client: stream rendered frames to an afterimage server for temporal
anti-aliasing; numpy frames in, filtered numpy frames out, EXR helpers for Blender
multilayer frames, and ``python -m afterimage_client filter``.

    from afterimage_client import Client, Frame

    with Client("127.0.0.1:50051") as client:
        with client.create_session("taa", width=w, height=h, channels=["color", "depth", "motion"]) as s:
            for out in s.stream(Frame(color=c, depth=d, motion=m) for c, d, m in shot):
                print(out.index, out.figures.total_ms, out.color.shape)
"""

__version__ = "0.1.0"

from .client import (  # noqa: E402
    COMPONENTS,
    MOTION_CONVENTIONS,
    AfterimageError,
    Client,
    FilteredFrame,
    FilterInfo,
    Frame,
    FrameError,
    FrameFigures,
    FrameStream,
    ProtocolError,
    RequestRejected,
    ServerUnavailable,
    Session,
    StageTime,
)
from .jitter import halton_jitter  # noqa: E402

__all__ = [
    "COMPONENTS",
    "MOTION_CONVENTIONS",
    "AfterimageError",
    "Client",
    "FilteredFrame",
    "FilterInfo",
    "Frame",
    "FrameError",
    "FrameFigures",
    "FrameStream",
    "ProtocolError",
    "RequestRejected",
    "ServerUnavailable",
    "Session",
    "StageTime",
    "__version__",
    "halton_jitter",
]
