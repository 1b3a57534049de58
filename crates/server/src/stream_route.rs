//! The Stream call served from the HTTP/2 frames themselves, in front of tonic's router.
//!
//! tonic copies every DATA frame into its receive buffer and moves a part-read message to
//! the buffer's start, and prost copies every reply chunk into tonic's send buffer: three
//! copies of each frame's bytes on the server's core that the protocol does not need. Here
//! a data chunk's bytes go from the frame they arrived in straight to where the frame is
//! landed (as views of that frame, [`Inbound`]), and a reply chunk's bytes are handed to
//! HTTP/2 as they are, after a few bytes of framing ([`ReplyBody`]). Every other message,
//! any chunk not laid out as prost lays it out, and a chunk over the session's chunk size
//! (for `handle_stream` to refuse as any other) is gathered and decoded by prost as before;
//! what the call does with its messages is [`crate::grpc`]'s `handle_stream`.

use crate::grpc::{open_stream, Grpc};
use crate::proto::{self as pb, filtered_chunk, frame_chunk};
use crate::wire::KEEP_CHUNK_BYTES;
use bytes::{BufMut, Bytes, BytesMut};
use http::{HeaderMap, HeaderValue, Request, Response};
use http_body::{Body, Frame, SizeHint};
use prost::encoding::{decode_varint, encode_varint, encoded_len_varint};
use prost::Message;
use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use tokio::sync::mpsc;
use tokio_stream::Stream;
use tonic::metadata::MetadataMap;
use tonic::Status;

/// The path of the Stream call.
pub const STREAM_PATH: &str = "/afterimage.v1.Afterimage/Stream";

/// A gRPC message's prefix: a compression flag and a big-endian length.
const PREFIX: usize = 5;

/// Bytes enough to tell a data chunk's layout: its two tags and two lengths (each length
/// below 2^35, so five bytes of varint at most).
const DATA_HEAD: usize = 12;

/// A data chunk's bytes go on as views of the HTTP/2 frames they came in when at least
/// this many lie in one frame; shorter runs are copied together (up to this many, or to
/// the chunk's end), so a client that cuts its data into tiny frames costs the stream one
/// message a run, as a stream of whole chunks would.
const VIEW_BYTES: usize = KEEP_CHUNK_BYTES;

/// Tag of a chunk's `data` part (field 2, length-delimited) and of a `DataChunk`'s `data`
/// bytes (field 1, length-delimited).
const DATA_PART_TAG: u8 = 2 << 3 | 2;
const DATA_BYTES_TAG: u8 = 1 << 3 | 2;

/// Where [`Inbound`] is in the message stream.
#[derive(Debug)]
enum State {
    /// Reading a message's prefix (`small` holds what came of it).
    Prefix,
    /// Reading the first bytes of a message of `len` bytes, to tell a data chunk.
    Head { len: usize },
    /// Inside a data chunk's bytes: `left` still to come (beyond `runs`), handed on as they
    /// arrive.
    Data { left: usize },
    /// Gathering a whole message of `len` bytes into `whole`, for prost.
    Whole { len: usize },
}

/// A request body's bytes as the call's messages. A data chunk comes out as one or more
/// data chunks that add up to it (at least one): views of the HTTP/2 frames it arrived in
/// where [`VIEW_BYTES`] or more lie in one, else runs copied together; any other message
/// as prost decodes it.
pub struct Inbound<B> {
    body: B,
    /// The unread rest of the last frame.
    frame: Bytes,
    state: State,
    /// A prefix or a message's head, as it comes.
    small: Vec<u8>,
    /// A data chunk's bytes too short to go on as views, copied together.
    runs: BytesMut,
    whole: BytesMut,
    /// The largest message taken.
    limit: usize,
    /// The largest data chunk taken (the session's `max_chunk_bytes`).
    max_chunk: usize,
    ended: bool,
}

impl<B> Inbound<B> {
    /// The messages of `body`, each at most `limit` bytes; a data chunk over `max_chunk`
    /// bytes comes out whole, for the stream to refuse.
    pub fn new(body: B, limit: usize, max_chunk: usize) -> Self {
        Inbound {
            body,
            frame: Bytes::new(),
            state: State::Prefix,
            small: Vec::with_capacity(DATA_HEAD),
            runs: BytesMut::new(),
            whole: BytesMut::new(),
            limit,
            max_chunk,
            ended: false,
        }
    }

    /// The next message (or piece of a data chunk) from the bytes at hand, if they hold one.
    fn step(&mut self) -> Result<Option<pb::FrameChunk>, Status> {
        loop {
            match self.state {
                State::Data { left } => {
                    if self.frame.is_empty() {
                        return Ok(None);
                    }
                    let n = left.min(self.frame.len());
                    if n >= VIEW_BYTES && !self.runs.is_empty() {
                        // The copied run first, then this frame's bytes as a view.
                        return Ok(Some(data_chunk(self.runs.split().freeze())));
                    }
                    self.state = if n == left {
                        State::Prefix
                    } else {
                        State::Data { left: left - n }
                    };
                    if n >= VIEW_BYTES {
                        return Ok(Some(data_chunk(self.frame.split_to(n))));
                    }
                    self.runs.extend_from_slice(&self.frame.split_to(n));
                    if self.runs.len() >= VIEW_BYTES || n == left {
                        return Ok(Some(data_chunk(self.runs.split().freeze())));
                    }
                }
                State::Prefix => {
                    if !self.fill(PREFIX) {
                        return Ok(None);
                    }
                    let flag = self.small[0];
                    let len = u32::from_be_bytes([self.small[1], self.small[2], self.small[3], self.small[4]])
                        as usize;
                    self.small.clear();
                    if flag != 0 {
                        return Err(Status::internal(format!(
                            "protocol error: a message with compression flag {flag}; this call takes uncompressed messages (flag 0)"
                        )));
                    }
                    if len > self.limit {
                        return Err(Status::out_of_range(format!(
                            "decoded message length too large: found {len} bytes, the limit is: {} bytes",
                            self.limit
                        )));
                    }
                    self.state = State::Head { len };
                }
                State::Head { len } => {
                    if !self.fill(len.min(DATA_HEAD)) {
                        return Ok(None);
                    }
                    match data_layout(&self.small, len).filter(|&(_, bytes)| bytes <= self.max_chunk) {
                        Some((at, bytes)) => {
                            // What of the data came with the head, then the rest as it comes.
                            self.runs.clear();
                            self.runs.extend_from_slice(&self.small[at..]);
                            let left = bytes - self.runs.len();
                            self.small.clear();
                            if left == 0 {
                                self.state = State::Prefix;
                                return Ok(Some(data_chunk(self.runs.split().freeze())));
                            }
                            self.state = State::Data { left };
                        }
                        None => {
                            self.whole.clear();
                            self.whole.reserve(len);
                            self.whole.extend_from_slice(&self.small);
                            self.small.clear();
                            self.state = State::Whole { len };
                        }
                    }
                }
                State::Whole { len } => {
                    let n = (len - self.whole.len()).min(self.frame.len());
                    self.whole.extend_from_slice(&self.frame.split_to(n));
                    if self.whole.len() < len {
                        return Ok(None);
                    }
                    self.state = State::Prefix;
                    let m = pb::FrameChunk::decode(self.whole.split().freeze())
                        .map_err(|e| Status::internal(format!("failed to decode a FrameChunk: {e}")))?;
                    return Ok(Some(m));
                }
            }
        }
    }

    /// Moves bytes from the frame into `small` until it holds `n`; whether it does.
    fn fill(&mut self, n: usize) -> bool {
        let take = n.saturating_sub(self.small.len()).min(self.frame.len());
        self.small.extend_from_slice(&self.frame.split_to(take));
        self.small.len() >= n
    }

    /// Whether a message is part-read (the stream may not end here).
    fn in_message(&self) -> bool {
        !matches!(self.state, State::Prefix) || !self.small.is_empty()
    }
}

/// A chunk of a frame's data.
fn data_chunk(data: Bytes) -> pb::FrameChunk {
    pb::FrameChunk {
        part: Some(frame_chunk::Part::Data(pb::DataChunk { data })),
    }
}

/// Where a message of `len` bytes that starts with `head` has its data chunk's bytes, and
/// how many, when it is a data chunk laid out as prost writes one (the part's tag and
/// length, the bytes' tag and length, the bytes, and nothing else); else None.
fn data_layout(head: &[u8], len: usize) -> Option<(usize, usize)> {
    let (&tag, rest) = head.split_first()?;
    if tag != DATA_PART_TAG {
        return None;
    }
    let (part_len, rest) = varint(rest)?;
    let part_at = head.len() - rest.len();
    let (&tag, rest) = rest.split_first()?;
    if tag != DATA_BYTES_TAG {
        return None;
    }
    let (bytes, rest) = varint(rest)?;
    let at = head.len() - rest.len();
    // Both lengths end exactly where the message does.
    let ends = |start: usize, n: u64| (start as u64).checked_add(n) == Some(len as u64);
    (ends(part_at, part_len) && ends(at, bytes)).then_some((at, len - at))
}

/// A varint at the start of `b` and the bytes after it; None when `b` holds no whole one.
fn varint(b: &[u8]) -> Option<(u64, &[u8])> {
    let mut rest = b;
    let v = decode_varint(&mut rest).ok()?;
    Some((v, rest))
}

impl<B> Stream for Inbound<B>
where
    B: Body<Data = Bytes> + Unpin,
    B::Error: Into<Status>,
{
    type Item = Result<pb::FrameChunk, Status>;

    fn poll_next(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<Option<Self::Item>> {
        let this = &mut *self;
        loop {
            if this.ended {
                return Poll::Ready(None);
            }
            match this.step() {
                Ok(Some(m)) => return Poll::Ready(Some(Ok(m))),
                Ok(None) => {}
                Err(e) => {
                    this.ended = true;
                    return Poll::Ready(Some(Err(e)));
                }
            }
            match ready!(Pin::new(&mut this.body).poll_frame(cx)) {
                Some(Ok(frame)) => {
                    if let Ok(data) = frame.into_data() {
                        this.frame = data;
                    }
                }
                Some(Err(e)) => {
                    this.ended = true;
                    return Poll::Ready(Some(Err(e.into())));
                }
                None => {
                    this.ended = true;
                    if this.in_message() {
                        return Poll::Ready(Some(Err(Status::internal(
                            "the request ended inside a message (Unexpected EOF decoding stream)",
                        ))));
                    }
                    return Poll::Ready(None);
                }
            }
        }
    }
}

/// The replies of a call as a gRPC response body: each message framed; a data chunk's
/// bytes handed on as they are, after its framing; then the status as trailers.
pub struct ReplyBody {
    replies: mpsc::Receiver<Result<pb::FilteredChunk, Status>>,
    /// A data chunk's bytes, to follow the framing just sent.
    next: Option<Bytes>,
    done: bool,
}

impl ReplyBody {
    /// The body of the replies `replies` gives.
    pub fn new(replies: mpsc::Receiver<Result<pb::FilteredChunk, Status>>) -> Self {
        ReplyBody {
            replies,
            next: None,
            done: false,
        }
    }
}

/// The framing of a reply: the whole message for a header; for a data chunk, its prefix,
/// tags and lengths, and its bytes apart.
fn framed(m: pb::FilteredChunk) -> (Bytes, Option<Bytes>) {
    match m.part {
        Some(filtered_chunk::Part::Data(d)) => {
            let bytes = d.data.len() as u64;
            let part = 1 + encoded_len_varint(bytes) as u64 + bytes;
            let len = 1 + encoded_len_varint(part) as u64 + part;
            let mut out = BytesMut::with_capacity(PREFIX + DATA_HEAD);
            out.put_u8(0);
            // A reply chunk is at most `max_chunk_bytes`, which the config caps at 1 GiB.
            out.put_u32(len as u32);
            out.put_u8(DATA_PART_TAG);
            encode_varint(part, &mut out);
            out.put_u8(DATA_BYTES_TAG);
            encode_varint(bytes, &mut out);
            (out.freeze(), Some(d.data).filter(|b| !b.is_empty()))
        }
        part => {
            let m = pb::FilteredChunk { part };
            let len = m.encoded_len();
            let mut out = BytesMut::with_capacity(PREFIX + len);
            out.put_u8(0);
            out.put_u32(len as u32);
            m.encode(&mut out).expect("the buffer has room for the message");
            (out.freeze(), None)
        }
    }
}

/// A status as gRPC trailers.
fn trailers(status: &Status) -> HeaderMap {
    let mut map = HeaderMap::new();
    if status.add_header(&mut map).is_err() {
        map.insert("grpc-status", HeaderValue::from(tonic::Code::Internal as i32));
    }
    map
}

impl Body for ReplyBody {
    type Data = Bytes;
    type Error = Status;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Status>>> {
        if let Some(b) = self.next.take() {
            return Poll::Ready(Some(Ok(Frame::data(b))));
        }
        if self.done {
            return Poll::Ready(None);
        }
        match ready!(self.replies.poll_recv(cx)) {
            Some(Ok(m)) => {
                let (head, rest) = framed(m);
                self.next = rest;
                Poll::Ready(Some(Ok(Frame::data(head))))
            }
            Some(Err(status)) => {
                self.done = true;
                Poll::Ready(Some(Ok(Frame::trailers(trailers(&status)))))
            }
            None => {
                self.done = true;
                Poll::Ready(Some(Ok(Frame::trailers(trailers(&Status::ok(""))))))
            }
        }
    }

    fn is_end_stream(&self) -> bool {
        self.done && self.next.is_none()
    }

    fn size_hint(&self) -> SizeHint {
        SizeHint::default()
    }
}

/// Serves [`STREAM_PATH`] itself (see the module's text) and hands every other request to
/// the router it wraps.
#[derive(Clone)]
pub struct StreamRouteLayer(pub Grpc);

impl<S> tower::Layer<S> for StreamRouteLayer {
    type Service = StreamRoute<S>;
    fn layer(&self, inner: S) -> StreamRoute<S> {
        StreamRoute {
            inner,
            grpc: self.0.clone(),
        }
    }
}

/// See [`StreamRouteLayer`].
#[derive(Clone)]
pub struct StreamRoute<S> {
    inner: S,
    grpc: Grpc,
}

type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send>>;

impl<S> tower::Service<Request<tonic::body::Body>> for StreamRoute<S>
where
    S: tower::Service<Request<tonic::body::Body>, Response = Response<tonic::body::Body>, Error = Infallible>,
    S::Future: Send + 'static,
{
    type Response = Response<tonic::body::Body>;
    type Error = Infallible;
    type Future = BoxFuture<Result<Self::Response, Infallible>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), Infallible>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: Request<tonic::body::Body>) -> Self::Future {
        if req.uri().path() != STREAM_PATH {
            return Box::pin(self.inner.call(req));
        }
        let grpc = self.grpc.clone();
        Box::pin(async move { Ok(serve_stream(&grpc, req).unwrap_or_else(|s| s.into_http())) })
    }
}

/// Starts a Stream call: the caller checked, its messages read by [`Inbound`] and its
/// replies sent by [`ReplyBody`].
fn serve_stream(grpc: &Grpc, req: Request<tonic::body::Body>) -> Result<Response<tonic::body::Body>, Status> {
    if let Some(e) = req.headers().get("grpc-encoding").filter(|e| *e != "identity") {
        return Err(Status::unimplemented(format!(
            "messages compressed with {:?}; this call takes uncompressed messages (channels may be zstd inside them)",
            e
        )));
    }
    let md = MetadataMap::from_headers(req.headers().clone());
    let limit = grpc.message_limit();
    let inbound = Inbound::new(req.into_body(), limit, grpc.0.config.max_chunk_bytes);
    let replies = open_stream(grpc, &md, inbound)?;
    let mut resp = Response::new(tonic::body::Body::new(ReplyBody::new(replies)));
    resp.headers_mut().insert(
        http::header::CONTENT_TYPE,
        HeaderValue::from_static("application/grpc"),
    );
    Ok(resp)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use http_body_util::{BodyExt, StreamBody};
    use tokio_stream::StreamExt;

    /// A request body of the frames given.
    type TestBody = StreamBody<tokio_stream::Iter<std::vec::IntoIter<Result<Frame<Bytes>, Status>>>>;

    /// `bytes` cut into frames at `cuts`.
    fn frames_of(bytes: &[u8], cuts: &[usize]) -> Vec<Bytes> {
        let mut frames = Vec::new();
        let mut at = 0;
        for &c in cuts.iter().chain([bytes.len()].iter()) {
            let c = c.min(bytes.len()).max(at);
            frames.push(Bytes::copy_from_slice(&bytes[at..c]));
            at = c;
        }
        frames
    }

    /// A request body of `frames`.
    fn body(frames: &[Bytes]) -> TestBody {
        let frames: Vec<_> = frames.iter().map(|f| Ok(Frame::data(f.clone()))).collect();
        StreamBody::new(tokio_stream::iter(frames))
    }

    /// Messages as a client's request body: each framed, the bytes cut at `cuts`.
    fn body_of(bytes: &[u8], cuts: &[usize]) -> TestBody {
        body(&frames_of(bytes, cuts))
    }

    fn framed_request(messages: &[pb::FrameChunk]) -> Vec<u8> {
        let mut out = Vec::new();
        for m in messages {
            let b = m.encode_to_vec();
            out.push(0);
            out.extend_from_slice(&(b.len() as u32).to_be_bytes());
            out.extend_from_slice(&b);
        }
        out
    }

    /// The messages (and pieces of data chunks) read back.
    async fn read_back(bytes: &[u8], cuts: &[usize], limit: usize) -> Result<Vec<pb::FrameChunk>, Status> {
        let mut inbound = Inbound::new(body_of(bytes, cuts), limit, limit);
        let mut out = Vec::new();
        while let Some(m) = inbound.next().await {
            out.push(m?);
        }
        Ok(out)
    }

    fn header(index: u64) -> pb::FrameChunk {
        pb::FrameChunk {
            part: Some(frame_chunk::Part::Header(pb::FrameHeader {
                session_id: "s".into(),
                index,
                ..Default::default()
            })),
        }
    }

    /// However the bytes are cut into HTTP/2 frames, the messages come out as sent: headers
    /// whole, each data chunk's bytes in order (as pieces that add up to it, at least one).
    #[tokio::test]
    async fn messages_come_out_as_sent_however_the_frames_cut_them() {
        let mut rng = SplitMix64::new(11);
        let payload = |n: usize, seed: u8| {
            Bytes::from(
                (0..n)
                    .map(|i| (i as u8).wrapping_mul(31) ^ seed)
                    .collect::<Vec<u8>>(),
            )
        };
        let sent = vec![
            header(0),
            data_chunk(payload(1000, 1)),
            data_chunk(payload(0, 2)),
            data_chunk(payload(3, 3)),
            header(1),
            data_chunk(payload(200_000, 4)),
            data_chunk(payload(127, 5)),
            data_chunk(payload(128, 6)),
            data_chunk(payload(16_384, 7)),
        ];
        let bytes = framed_request(&sent);
        let mut cut_sets: Vec<Vec<usize>> = vec![
            vec![],
            (1..bytes.len()).collect(),
            (0..bytes.len()).step_by(7).collect(),
        ];
        for _ in 0..20 {
            let mut cuts: Vec<usize> = (0..1 + (rng.next_f64() * 40.0) as usize)
                .map(|_| (rng.next_f64() * bytes.len() as f64) as usize)
                .collect();
            cuts.sort_unstable();
            cut_sets.push(cuts);
        }
        for cuts in &cut_sets {
            let got = read_back(&bytes, cuts, 1 << 20).await.unwrap();
            // The pieces of each data message join back into it, in order.
            let mut pieces = got.into_iter();
            for want in &sent {
                match &want.part {
                    Some(frame_chunk::Part::Data(d)) => {
                        let mut acc = Vec::new();
                        let mut first = true;
                        while first || acc.len() < d.data.len() {
                            first = false;
                            match pieces.next().and_then(|p| p.part) {
                                Some(frame_chunk::Part::Data(p)) => acc.extend_from_slice(&p.data),
                                other => panic!("cuts {cuts:?}: expected data, got {other:?}"),
                            }
                        }
                        assert_eq!(acc, d.data.to_vec(), "cuts {} long", cuts.len());
                    }
                    _ => {
                        let got = pieces
                            .next()
                            .unwrap_or_else(|| panic!("cuts {cuts:?}: a message short"));
                        assert_eq!(&got, want);
                    }
                }
            }
            assert!(pieces.next().is_none(), "more messages than sent");
        }
    }

    /// A data chunk in another layout than prost's (an unknown field after its bytes) is
    /// read too, and so is one whose length is a varint of more bytes than needed.
    #[tokio::test]
    async fn other_layouts_are_read_too() {
        // part 2 { bytes 1 = "abc", unknown field 9 = 5 }, then a padded-varint length.
        let inner = [DATA_BYTES_TAG, 3, b'a', b'b', b'c', 9 << 3, 5];
        let mut m = vec![DATA_PART_TAG, inner.len() as u8];
        m.extend_from_slice(&inner);
        let padded = [DATA_PART_TAG, 0x85, 0x00, DATA_BYTES_TAG, 3, b'x', b'y', b'z'];
        let mut bytes = Vec::new();
        for msg in [&m[..], &padded[..]] {
            bytes.push(0);
            bytes.extend_from_slice(&(msg.len() as u32).to_be_bytes());
            bytes.extend_from_slice(msg);
        }
        let got = read_back(&bytes, &[3, 9], 1 << 20).await.unwrap();
        let data: Vec<Vec<u8>> = got
            .into_iter()
            .map(|c| match c.part {
                Some(frame_chunk::Part::Data(d)) => d.data.to_vec(),
                other => panic!("{other:?}"),
            })
            .collect();
        assert_eq!(data, vec![b"abc".to_vec(), b"xyz".to_vec()]);
    }

    /// A data chunk's long runs in one frame go on as views of that frame, tiny frames are
    /// copied together (a handful of pieces, not one a frame), and a chunk over the session's
    /// chunk size comes out whole, cut as it was, for the stream to refuse.
    #[tokio::test]
    async fn long_runs_are_views_and_tiny_frames_are_copied_together() {
        let data = Bytes::from((0..300_000u32).map(|i| (i % 251) as u8).collect::<Vec<u8>>());
        let bytes = framed_request(&[data_chunk(data.clone())]);
        let mut cuts: Vec<usize> = (1..2000).collect();
        cuts.extend((2000..bytes.len()).step_by(100_000).skip(1));
        let frames = frames_of(&bytes, &cuts);
        let mut inbound = Inbound::new(body(&frames), 1 << 20, 1 << 20);
        let mut pieces = Vec::new();
        while let Some(m) = inbound.next().await {
            match m.unwrap().part {
                Some(frame_chunk::Part::Data(d)) => pieces.push(d.data),
                other => panic!("{other:?}"),
            }
        }
        assert!(
            pieces.len() <= 6,
            "{} pieces for {} frames",
            pieces.len(),
            frames.len()
        );
        assert_eq!(pieces.concat(), data.to_vec());
        let within = |p: &Bytes, f: &Bytes| {
            let (p0, f0) = (p.as_ptr() as usize, f.as_ptr() as usize);
            f0 <= p0 && p0 + p.len() <= f0 + f.len()
        };
        let views = pieces
            .iter()
            .filter(|p| frames.iter().any(|f| within(p, f)))
            .count();
        let long = pieces.iter().filter(|p| p.len() >= VIEW_BYTES).count();
        assert!(long >= 2 && views == long, "{long} long pieces, {views} views");

        let big = framed_request(&[data_chunk(Bytes::from(vec![1u8; 101]))]);
        let mut inbound = Inbound::new(body_of(&big, &[20, 60]), 1 << 20, 100);
        let whole = inbound.next().await.unwrap().unwrap();
        assert_eq!(whole, data_chunk(Bytes::from(vec![1u8; 101])));
        assert!(inbound.next().await.is_none());
    }

    /// Hostile framing: a compressed flag, a message over the limit (refused from its prefix,
    /// before its bytes), the body ending inside a prefix or a message, bytes that are not
    /// a message.
    #[tokio::test]
    async fn bad_framing_is_refused_precisely() {
        let ok = framed_request(&[header(0)]);
        let mut compressed = ok.clone();
        compressed[0] = 1;
        let e = read_back(&compressed, &[], 1 << 20).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::Internal);
        assert!(e.message().contains("compression flag 1"), "{e:?}");

        let mut huge = vec![0u8];
        huge.extend_from_slice(&u32::MAX.to_be_bytes());
        let e = read_back(&huge, &[], 1 << 20).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::OutOfRange);
        assert!(
            e.message().contains(&format!("found {} bytes", u32::MAX)),
            "{e:?}"
        );

        for end in [1, PREFIX, ok.len() - 1] {
            let e = read_back(&ok[..end], &[], 1 << 20).await.unwrap_err();
            assert!(e.message().contains("ended inside a message"), "{end}: {e:?}");
        }
        let data = framed_request(&[data_chunk(Bytes::from(vec![7u8; 5000]))]);
        let e = read_back(&data[..data.len() - 10], &[100], 1 << 20)
            .await
            .unwrap_err();
        assert!(e.message().contains("ended inside a message"), "{e:?}");

        let garbage = [0, 0, 0, 0, 3, 0xff, 0xff, 0xff];
        let e = read_back(&garbage, &[], 1 << 20).await.unwrap_err();
        assert_eq!(e.code(), tonic::Code::Internal);
        assert!(e.message().contains("decode a FrameChunk"), "{e:?}");
    }

    /// Random bytes, cut at random, never panic, and never come out as more data than sent.
    #[tokio::test]
    async fn random_bytes_never_panic() {
        let mut rng = SplitMix64::new(5);
        for case in 0..300 {
            let n = (rng.next_f64() * 200.0) as usize;
            let mut bytes: Vec<u8> = (0..n).map(|_| (rng.next_f64() * 256.0) as u8).collect();
            if case % 2 == 0 && n > 6 {
                // A plausible prefix: flag 0 and a small length.
                bytes[0] = 0;
                bytes[1..5].copy_from_slice(&((n as u32 - 5) / 2).to_be_bytes());
                bytes[5] = if case % 4 == 0 { DATA_PART_TAG } else { bytes[5] };
            }
            let cuts: Vec<usize> = (0..n).filter(|_| rng.next_f64() < 0.2).collect();
            if let Ok(got) = read_back(&bytes, &cuts, 1000).await {
                let data: usize = got
                    .iter()
                    .map(|c| match &c.part {
                        Some(frame_chunk::Part::Data(d)) => d.data.len(),
                        _ => 0,
                    })
                    .sum();
                assert!(data <= n, "case {case}");
            }
        }
    }

    /// The path served here is the generated service's `Stream`.
    #[test]
    fn the_path_is_the_generated_services() {
        use tonic::server::NamedService;
        let name = <crate::proto::afterimage_server::AfterimageServer<Grpc> as NamedService>::NAME;
        assert_eq!(STREAM_PATH, format!("/{name}/Stream"));
    }

    /// Replies framed here decode with prost to what was sent, and the call's status ends
    /// the body as trailers.
    #[tokio::test]
    async fn replies_are_framed_as_grpc_messages_then_the_status() {
        let sent = vec![
            pb::FilteredChunk {
                part: Some(filtered_chunk::Part::Header(pb::FilteredHeader {
                    session_id: "s".into(),
                    index: 3,
                    width: 7,
                    ..Default::default()
                })),
            },
            pb::FilteredChunk {
                part: Some(filtered_chunk::Part::Data(pb::DataChunk {
                    data: Bytes::from(vec![5u8; 300]),
                })),
            },
            pb::FilteredChunk {
                part: Some(filtered_chunk::Part::Data(pb::DataChunk { data: Bytes::new() })),
            },
        ];
        for end in [Ok(()), Err(Status::invalid_argument("frame 3: bad"))] {
            let (tx, rx) = mpsc::channel(8);
            for m in &sent {
                tx.send(Ok(m.clone())).await.unwrap();
            }
            if let Err(s) = &end {
                tx.send(Err(s.clone())).await.unwrap();
            }
            drop(tx);
            let collected = ReplyBody::new(rx).collect().await.unwrap();
            let trailers = collected.trailers().cloned().unwrap();
            let mut bytes = collected.to_bytes();
            let mut got = Vec::new();
            while !bytes.is_empty() {
                assert_eq!(bytes[0], 0);
                let len = u32::from_be_bytes([bytes[1], bytes[2], bytes[3], bytes[4]]) as usize;
                let msg = bytes.slice(PREFIX..PREFIX + len);
                bytes = bytes.slice(PREFIX + len..);
                got.push(pb::FilteredChunk::decode(msg).unwrap());
            }
            assert_eq!(got, sent);
            let status = Status::from_header_map(&trailers).unwrap();
            match end {
                Ok(()) => assert_eq!(status.code(), tonic::Code::Ok),
                Err(s) => {
                    assert_eq!(status.code(), s.code());
                    assert_eq!(status.message(), s.message());
                }
            }
        }
    }
}
