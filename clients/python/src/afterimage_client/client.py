"""A typed client for the afterimage gRPC service (crates/client/proto/afterimage/v1/afterimage.proto).

Frames go in as numpy arrays in image layout, height x width x components (``color`` is
HxWx3 float32, ``depth`` HxW or HxWx1, ``motion`` HxWx2, ``object_id`` HxW uint32, ...)
and the filtered colour comes back as an HxWx3 float32 array with the server's per-frame
figures. On the wire every channel is planar (components one after another), little-endian,
cut into chunks of at most the session's ``max_chunk_bytes``.
"""

from __future__ import annotations

import json
import os
import queue
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, Iterator, List, Mapping, Optional, Sequence, Tuple

import grpc
import numpy as np

from .proto import afterimage_pb2 as pb
from .proto import afterimage_pb2_grpc as pb_grpc

#: Components of every channel the protocol knows, in the proto's order.
COMPONENTS: Dict[str, int] = {
    "color": 3,
    "depth": 1,
    "motion": 2,
    "motion_next": 2,
    "normal": 3,
    "object_id": 1,
    "albedo": 3,
    "reference": 3,
}

#: Motion-vector conventions the server converts from (CreateSessionRequest.motion).
MOTION_CONVENTIONS = ("internal", "blender", "fsr2", "unreal", "unity", "bevy")


class AfterimageError(Exception):
    """Base of every error this package raises on purpose."""


class ServerUnavailable(AfterimageError):
    """No server answered at the address."""


class RequestRejected(AfterimageError):
    """The server refused a call; ``code`` is the gRPC status code, ``details`` its text."""

    def __init__(self, what: str, code: grpc.StatusCode, details: str):
        self.code = code
        self.details = details
        super().__init__(f"{what}: the server answered {code.name}: {details}")


class ProtocolError(AfterimageError):
    """The server's replies do not follow the contract (a bug on one side)."""


class FrameError(AfterimageError, ValueError):
    """A frame given to the client has the wrong shape, type or channels."""


def _rejected(what: str, e: grpc.RpcError) -> AfterimageError:
    code = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
    details = e.details() if hasattr(e, "details") else str(e)
    if code == grpc.StatusCode.UNAVAILABLE:
        return ServerUnavailable(f"{what}: the server is unavailable: {details}")
    return RequestRejected(what, code, details)


@dataclass
class Frame:
    """One rendered frame, channels in image layout (rows from the top).

    Only ``color`` is required; send what the filter uses (``FilterInfo.uses``). ``motion``
    and ``motion_next`` are in the session's convention (default ``internal``: pixels from
    the current pixel to its position in the previous frame, x right, y down; motion_next
    is always internal: to the next frame). ``jitter`` is the sub-pixel offset of this
    frame's samples from the pixel centres, in pixels (x right, y down, each in -1..1)."""

    color: np.ndarray
    depth: Optional[np.ndarray] = None
    motion: Optional[np.ndarray] = None
    motion_next: Optional[np.ndarray] = None
    normal: Optional[np.ndarray] = None
    object_id: Optional[np.ndarray] = None
    albedo: Optional[np.ndarray] = None
    reference: Optional[np.ndarray] = None
    index: Optional[int] = None
    reset: bool = False
    jitter: Tuple[float, float] = (0.0, 0.0)

    def channels(self) -> Dict[str, np.ndarray]:
        """The channels present, by protocol name, in the proto's order."""
        return {n: getattr(self, n) for n in COMPONENTS if getattr(self, n) is not None}

    @property
    def size(self) -> Tuple[int, int]:
        """(width, height) of the colour."""
        c = np.asarray(self.color)
        return int(c.shape[1]), int(c.shape[0])


@dataclass
class StageTime:
    name: str
    ms: Optional[float]
    skipped: str


@dataclass
class FrameFigures:
    """The server's record of one filtered frame (FrameReport)."""

    index: int
    total_ms: float
    server_ms: float
    stages: List[StageTime]
    history_reset: int
    history_rejected: int
    history_clipped: int
    non_finite_input: int
    negative_input: int
    state_bytes: int
    psnr: Optional[float]
    ssim: Optional[float]
    record: Dict[str, Any]

    @classmethod
    def from_pb(cls, r: "pb.FrameReport") -> "FrameFigures":
        return cls(
            index=r.index,
            total_ms=r.total_ms,
            server_ms=r.server_ms,
            stages=[StageTime(s.name, s.ms if s.HasField("ms") else None, s.skipped) for s in r.stages],
            history_reset=r.history_reset,
            history_rejected=r.history_rejected,
            history_clipped=r.history_clipped,
            non_finite_input=r.non_finite_input,
            negative_input=r.negative_input,
            state_bytes=r.state_bytes,
            psnr=r.psnr if r.HasField("psnr") else None,
            ssim=r.ssim if r.HasField("ssim") else None,
            record=json.loads(r.record_json) if r.record_json else {},
        )


@dataclass
class FilteredFrame:
    """A filtered frame: ``color`` is HxWx3 float32 (rows from the top)."""

    index: int
    color: np.ndarray
    figures: FrameFigures
    #: Seconds from sending this frame's first chunk to receiving its last reply chunk.
    round_trip_s: Optional[float] = None


@dataclass
class FilterInfo:
    """A filter the server has (ListFilters)."""

    name: str
    summary: str
    needs: List[str]
    uses: List[str]
    stages: List[str]
    params: Dict[str, "pb.ParamSpec"] = field(default_factory=dict)


# --- wire encoding -------------------------------------------------------------------------


def _sample_dtype(sample: int) -> str:
    if sample == pb.SAMPLE_TYPE_F16:
        return "<f2"
    if sample == pb.SAMPLE_TYPE_U32:
        return "<u4"
    return "<f4"


def planar(name: str, array: np.ndarray, width: int, height: int) -> np.ndarray:
    """``array`` (HxW or HxWxC) as C planes of HxW, checked against the channel's shape."""
    comps = COMPONENTS.get(name)
    if comps is None:
        raise FrameError(f"unknown channel {name!r}; expected one of {', '.join(COMPONENTS)}")
    a = np.asarray(array)
    if a.ndim == 2 and comps == 1:
        a = a[:, :, None]
    if a.ndim != 3 or a.shape[:2] != (height, width) or a.shape[2] != comps:
        want = f"{height}x{width}" + ("" if comps == 1 else f"x{comps}")
        raise FrameError(
            f"channel {name}: expected an array of shape {want} (height x width"
            f"{'' if comps == 1 else ' x components'}), got {a.shape}"
        )
    return a.transpose(2, 0, 1)


def _channel_sample(name: str, planes: np.ndarray, f16: bool) -> int:
    """The wire sample type of channel ``name`` (object_id always u32, its ids checked)."""
    if name == "object_id":
        if not np.issubdtype(planes.dtype, np.integer):
            raise FrameError(f"channel object_id: expected integer ids (uint32), got {planes.dtype}")
        if planes.size and (planes.min() < 0 or planes.max() > 0xFFFFFFFF):
            raise FrameError("channel object_id: ids must be in 0..2**32-1")
        return pb.SAMPLE_TYPE_U32
    return pb.SAMPLE_TYPE_F16 if f16 else pb.SAMPLE_TYPE_F32


def _put_planes(planes: np.ndarray, sample: int, out: np.ndarray) -> None:
    """Writes ``planes`` (C x H x W, any layout) into the bytes ``out`` as planar samples
    of ``sample``, a component at a time: numpy copies a strided component about three
    times faster than it transposes a whole HxWxC array in one go."""
    dst = out.view(_sample_dtype(sample)).reshape(planes.shape)
    for k in range(planes.shape[0]):
        dst[k] = planes[k]


def encode_channel(name: str, array: np.ndarray, width: int, height: int, f16: bool = False) -> Tuple["pb.ChannelHeader", bytes]:
    """One channel's ChannelHeader and wire bytes: planar little-endian f32 (f16 with
    ``f16``; object_id always u32)."""
    headers, payload = encode_channels({name: array}, width, height, f16)
    return headers[0], payload.tobytes()


def encode_channels(
    channels: Mapping[str, np.ndarray], width: int, height: int, f16: bool = False
) -> Tuple[List["pb.ChannelHeader"], np.ndarray]:
    """The ChannelHeaders of ``channels`` and their wire bytes one after another, written
    straight into one buffer (a uint8 array): each sample is copied once on its way in."""
    prepared = []
    for name, array in channels.items():
        planes = planar(name, array, width, height)
        sample = _channel_sample(name, planes, f16)
        prepared.append((name, planes, sample, planes.size * np.dtype(_sample_dtype(sample)).itemsize))
    payload = np.empty(sum(n for *_, n in prepared), np.uint8)
    headers, at = [], 0
    for name, planes, sample, n in prepared:
        _put_planes(planes, sample, payload[at : at + n])
        headers.append(pb.ChannelHeader(name=name, sample=sample, compression=pb.COMPRESSION_NONE, byte_length=n))
        at += n
    return headers, payload


def frame_messages(
    session_id: str,
    index: int,
    frame: Frame,
    max_chunk_bytes: int,
    f16: bool = False,
    reply_f16: bool = False,
) -> Iterator["pb.FrameChunk"]:
    """One frame as a FrameHeader message then DataChunk messages of at most
    ``max_chunk_bytes`` each."""
    width, height = frame.size
    headers, payload = encode_channels(frame.channels(), width, height, f16)
    jx, jy = (float(v) for v in frame.jitter)
    reply_sample = pb.SAMPLE_TYPE_F16 if reply_f16 else pb.SAMPLE_TYPE_F32
    yield pb.FrameChunk(
        header=pb.FrameHeader(
            session_id=session_id,
            index=index,
            reset=frame.reset,
            jitter_x=jx,
            jitter_y=jy,
            channels=headers,
            reply_sample=reply_sample,
            reply_compression=pb.COMPRESSION_NONE,
        )
    )
    step = max_chunk_bytes or (1 << 20)
    for at in range(0, len(payload), step):
        yield pb.FrameChunk(data=pb.DataChunk(data=payload[at : at + step].tobytes()))


def decode_replies(
    responses: Iterable["pb.FilteredChunk"], size: Optional[Tuple[int, int]] = None
) -> Iterator[Tuple["pb.FilteredHeader", np.ndarray]]:
    """Reassembles FilteredChunks into (header, colour of shape HxWx3 float32), each reply
    of ``size`` (width, height) when given. Each chunk is copied once, into the reply's
    planes; the planes then once more, into the image layout."""
    header, buf, have = None, None, 0
    for msg in responses:
        if msg.HasField("header"):
            if header is not None:
                raise ProtocolError(
                    f"reply header for frame {msg.header.index} before frame {header.index}'s data was complete "
                    f"({have} of {header.color.byte_length} bytes)"
                )
            header, have = msg.header, 0
            if size is not None and (header.width, header.height) != tuple(size):
                raise ProtocolError(
                    f"frame {header.index}: a reply of {header.width}x{header.height} in a session of {size[0]}x{size[1]}"
                )
            if header.color.compression != pb.COMPRESSION_NONE:
                raise ProtocolError(f"frame {header.index}: compressed reply colour, which this client never asks for")
            dtype = np.dtype(_sample_dtype(header.color.sample))
            expected = 3 * header.width * header.height * dtype.itemsize
            if header.color.byte_length != expected:
                raise ProtocolError(
                    f"frame {header.index}: {header.color.byte_length} bytes of colour announced, expected {expected} "
                    f"(3 x {header.width} x {header.height} {dtype.name} samples)"
                )
            buf = np.empty(expected, np.uint8)
        else:
            if header is None:
                raise ProtocolError("reply data before its header")
            data = msg.data.data
            if have + len(data) > header.color.byte_length:
                raise ProtocolError(
                    f"frame {header.index}: {have + len(data)} bytes of colour, the header announced {header.color.byte_length}"
                )
            buf[have : have + len(data)] = np.frombuffer(data, np.uint8)
            have += len(data)
        if header is not None and have == header.color.byte_length:
            planes = buf.view(_sample_dtype(header.color.sample)).reshape(3, header.height, header.width)
            color = np.empty((header.height, header.width, 3), np.float32)
            for k in range(3):
                color[..., k] = planes[k]
            yield header, color
            header, buf = None, None
    if header is not None:
        raise ProtocolError(f"the stream ended inside frame {header.index}'s reply ({have} of {header.color.byte_length} bytes)")


# --- connection ----------------------------------------------------------------------------


class _CallMetadata(grpc.UnaryUnaryClientInterceptor, grpc.StreamStreamClientInterceptor):
    """Adds ``authorization: Bearer KEY`` (with a key) and the routing key
    ``x-afterimage-route`` to every call: a proxy in front of several replicas hashes on the
    routing key, so all of this client's calls reach the replica holding its sessions."""

    def __init__(self, key: Optional[str], route: str):
        self.metadata = [("x-afterimage-route", route)]
        if key:
            self.metadata.append(("authorization", f"Bearer {key}"))

    def _details(self, d):
        return d._replace(metadata=list(d.metadata or []) + self.metadata)

    def intercept_unary_unary(self, continuation, details, request):
        return continuation(self._details(details), request)

    def intercept_stream_stream(self, continuation, details, requests):
        return continuation(self._details(details), requests)


def open_channel(address: str, tls_ca: Optional[str] = None, tls_domain: Optional[str] = None) -> grpc.Channel:
    """A plain channel, or a TLS one trusting the PEM file ``tls_ca`` (the CA, or the
    self-signed certificate) with ``tls_domain`` as the expected certificate name when it
    is not the address's host."""
    options = [("grpc.max_receive_message_length", 64 << 20)]
    if tls_ca:
        try:
            with open(tls_ca, "rb") as f:
                creds = grpc.ssl_channel_credentials(root_certificates=f.read())
        except OSError as e:
            raise AfterimageError(f"--tls-ca {tls_ca}: cannot read the CA certificate: {e.strerror}") from e
        if tls_domain:
            options.append(("grpc.ssl_target_name_override", tls_domain))
        return grpc.secure_channel(address, creds, options=options)
    return grpc.insecure_channel(address, options=options)


class Client:
    """A connection to an afterimage server.

    >>> with Client("127.0.0.1:50051") as client:
    ...     with client.create_session("taa", width=1280, height=720) as session:
    ...         for out in session.stream(frames):
    ...             use(out.color)
    """

    def __init__(
        self,
        address: str,
        *,
        api_key: Optional[str] = None,
        tls_ca: Optional[str] = None,
        tls_domain: Optional[str] = None,
        route: Optional[str] = None,
        wait: float = 10.0,
    ):
        self.address = address
        #: The channel without the API key and routing metadata (for checks of a keyed server).
        self.raw_channel = open_channel(address, tls_ca, tls_domain)
        if wait > 0:
            try:
                grpc.channel_ready_future(self.raw_channel).result(timeout=wait)
            except grpc.FutureTimeoutError:
                self.raw_channel.close()
                scheme = "TLS" if tls_ca else "plain-text"
                raise ServerUnavailable(
                    f"no afterimage server answered at {address} ({scheme} gRPC) within {wait:g} s; "
                    f"is `afterimage serve` running there (its gRPC address is AFTERIMAGE_GRPC_ADDR)?"
                ) from None
        self.route = route or os.urandom(8).hex()
        self.channel = grpc.intercept_channel(self.raw_channel, _CallMetadata(api_key, self.route))
        self.stub = pb_grpc.AfterimageStub(self.channel)

    def close(self) -> None:
        self.raw_channel.close()

    def __enter__(self) -> "Client":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def filters(self) -> Dict[str, FilterInfo]:
        """Every filter the server has, by name."""
        try:
            resp = self.stub.ListFilters(pb.ListFiltersRequest())
        except grpc.RpcError as e:
            raise _rejected(f"listing the filters of {self.address}", e) from None
        return {
            f.name: FilterInfo(
                name=f.name,
                summary=f.summary,
                needs=list(f.needs),
                uses=list(f.uses),
                stages=list(f.stages),
                params={p.name: p for p in f.params},
            )
            for f in resp.filters
        }

    def create_session(
        self,
        filter: str,
        *,
        width: int,
        height: int,
        params: Optional[Mapping[str, Any]] = None,
        channels: Optional[Sequence[str]] = None,
        motion: str = "internal",
        backend: str = "",
    ) -> "Session":
        """A new session of ``filter`` for frames of ``width`` x ``height``. ``params``
        overrides defaults (values are sent as text; booleans as true/false); ``channels``
        is what the frames will carry (default: the filter's ``uses``); ``motion`` is the
        motion-vector convention of the frames."""
        text = {k: (str(v).lower() if isinstance(v, bool) else str(v)) for k, v in (params or {}).items()}
        req = pb.CreateSessionRequest(
            filter=filter,
            params=text,
            width=width,
            height=height,
            motion=motion,
            channels=list(channels or []),
            backend=backend,
        )
        try:
            s = self.stub.CreateSession(req)
        except grpc.RpcError as e:
            raise _rejected(f"creating a {filter} session of {width}x{height}", e) from None
        return Session(self, s)


_END = object()


class Session:
    """One filter instance with its history on the server."""

    def __init__(self, client: Client, info: "pb.Session"):
        self.client = client
        self.info = info
        self.id: str = info.id
        self.width: int = info.width
        self.height: int = info.height
        self.params: Dict[str, Any] = json.loads(info.params_json) if info.params_json else {}
        self.channels: List[str] = list(info.channels)
        self.lookahead: int = info.lookahead
        self.max_chunk_bytes: int = info.max_chunk_bytes or (1 << 20)
        self._next_index = 0
        self.closed = False

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        if not self.closed:
            try:
                self.close()
            except AfterimageError:
                if exc[0] is None:
                    raise

    def refresh(self) -> "pb.Session":
        """The session's figures now (GetSession)."""
        try:
            self.info = self.client.stub.GetSession(pb.GetSessionRequest(id=self.id))
        except grpc.RpcError as e:
            raise _rejected(f"session {self.id[:8]}", e) from None
        return self.info

    def close(self) -> int:
        """Frees the session's state on the server; returns the frames it filtered."""
        try:
            resp = self.client.stub.CloseSession(pb.CloseSessionRequest(id=self.id))
        except grpc.RpcError as e:
            raise _rejected(f"closing session {self.id[:8]}", e) from None
        self.closed = True
        return resp.frames

    def _check(self, frame: Frame) -> None:
        if (frame.size) != (self.width, self.height):
            raise FrameError(
                f"frame of {frame.size[0]}x{frame.size[1]} for a session of {self.width}x{self.height}"
            )
        sent = [c for c in frame.channels() if c != "reference"]
        extra = [c for c in sent if c not in self.channels]
        if extra:
            raise FrameError(
                f"frame carries {', '.join(extra)}, which the session was not created with "
                f"(its channels: {', '.join(self.channels)})"
            )

    def stream(self, frames: Iterable[Frame], *, f16: bool = False, reply_f16: bool = False) -> Iterator[FilteredFrame]:
        """Streams ``frames`` over one Stream call and yields the filtered frames in order.

        ``frames`` is consumed on gRPC's sending thread, ahead of the replies; pass a list,
        or use :meth:`open_stream` to hand frames over one at a time from your own thread
        (a renderer's main thread). ``f16``: send half floats (11 significant bits, at most
        65504); ``reply_f16``: receive half floats."""
        s = self.open_stream(f16=f16, reply_f16=reply_f16)
        feeder = threading.Thread(target=s._feed_from, args=(iter(frames),), daemon=True)
        feeder.start()
        complete = False
        try:
            yield from s
            complete = True
        finally:
            if not complete:  # the caller stopped early, or a reply failed: end the call
                s._call.cancel()
        feeder.join()
        if s._feed_error is not None:
            raise s._feed_error

    def filter(self, frame: Frame, *, f16: bool = False, reply_f16: bool = False) -> FilteredFrame:
        """Filters one frame (its own Stream call) and returns the result. Only for causal
        filters (lookahead 0); a windowed filter needs :meth:`stream`."""
        if self.lookahead:
            raise AfterimageError(
                f"{self.info.filter} replies {self.lookahead} frames late; use Session.stream or open_stream"
            )
        out = list(self.stream([frame], f16=f16, reply_f16=reply_f16))
        if len(out) != 1:
            raise ProtocolError(f"one frame sent, {len(out)} replies")
        return out[0]

    def open_stream(self, *, f16: bool = False, reply_f16: bool = False) -> "FrameStream":
        """A stream to :meth:`FrameStream.send` frames into and iterate replies from."""
        return FrameStream(self, f16, reply_f16)


class FrameStream:
    """One Stream call: ``send(frame)`` from any thread, ``finish()`` when done, and
    iterate (or ``recv()``) the filtered frames in order. Sending does not wait for the
    replies, so the next frame can be rendered while this one is filtered."""

    def __init__(self, session: Session, f16: bool, reply_f16: bool):
        self.session = session
        self.f16 = f16
        self.reply_f16 = reply_f16
        self._queue: "queue.Queue[Any]" = queue.Queue(maxsize=4)
        self._sent_at: Dict[int, float] = {}
        self._finished = False
        self._feed_error: Optional[BaseException] = None
        self._call = session.client.stub.Stream(self._requests())
        self._replies = self._decode()

    def _requests(self) -> Iterator["pb.FrameChunk"]:
        s = self.session
        while True:
            item = self._queue.get()
            if item is _END:
                return
            index, frame = item
            self._sent_at[index] = _now()
            yield from frame_messages(s.id, index, frame, s.max_chunk_bytes, self.f16, self.reply_f16)

    def send(self, frame: Frame) -> int:
        """Queues ``frame`` (checked first); returns the index it is sent under (the
        frame's own ``index``, else one more than the previous)."""
        if self._finished:
            raise AfterimageError("send after finish()")
        self.session._check(frame)
        index = self.session._next_index if frame.index is None else int(frame.index)
        self.session._next_index = index + 1
        while True:  # bounded: at most a few frames wait to be sent
            try:
                self._queue.put((index, frame), timeout=0.1)
                return index
            except queue.Full:
                if self._call.done():
                    raise AfterimageError(
                        f"frame {index}: the stream to session {self.session.id[:8]} has ended "
                        f"(read the replies for the server's reason)"
                    ) from None

    def finish(self) -> None:
        """Closes the sending side: the server replies to what is left (a windowed
        filter's last frames) and ends the stream."""
        if not self._finished:
            self._finished = True
            self._queue.put(_END)

    def _feed_from(self, frames: Iterator[Frame]) -> None:
        try:
            for f in frames:
                self.send(f)
        except BaseException as e:
            # Reported by Session.stream once the frames already sent have come back.
            self._feed_error = e
        finally:
            self.finish()

    def _decode(self) -> Iterator[FilteredFrame]:
        s = self.session
        try:
            for header, color in decode_replies(self._call, (s.width, s.height)):
                sent = self._sent_at.pop(header.index, None)
                yield FilteredFrame(
                    index=header.index,
                    color=color,
                    figures=FrameFigures.from_pb(header.report),
                    round_trip_s=None if sent is None else _now() - sent,
                )
        except grpc.RpcError as e:
            if self._feed_error is not None:
                raise self._feed_error from None
            raise _rejected(f"streaming frames to session {s.id[:8]} ({s.info.filter})", e) from None

    def recv(self) -> FilteredFrame:
        """The next filtered frame (blocks); StopIteration when the stream has ended."""
        return next(self._replies)

    def __iter__(self) -> Iterator[FilteredFrame]:
        return self._replies

    def __enter__(self) -> "FrameStream":
        return self

    def __exit__(self, *exc) -> None:
        self.finish()
        if exc[0] is not None:
            self._call.cancel()


def _now() -> float:
    return time.perf_counter()
