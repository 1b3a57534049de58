//! Streaming a session's frames: frames go out while replies come in, a bounded number
//! ahead, and replies come back in order.

use crate::connect::Inner;
use crate::frame::{decode_color, encode, Encoded, Encoding, FrameData};
use crate::proto::{self as pb, filtered_chunk, frame_chunk};
use crate::shm::SharedRegion;
use std::collections::VecDeque;
use std::sync::Mutex;
use std::time::Instant;
use tokio::sync::{mpsc, Semaphore};
use tokio_stream::wrappers::ReceiverStream;
use tokio_stream::StreamExt;
use tonic::Status;

/// A filtered frame as the client receives it.
#[derive(Clone, Debug)]
pub struct Reply {
    /// The frame's number.
    pub index: u64,
    /// The filtered colour: r, g and b planes of `width x height`, row-major.
    pub color: [Vec<f32>; 3],
    /// Its size.
    pub width: u32,
    /// Its size.
    pub height: u32,
    /// The server's report.
    pub report: pb::FrameReport,
    /// From sending the frame's header to holding its whole reply, ms.
    pub round_trip_ms: f64,
    /// Bytes sent for the frame plus bytes received for its reply.
    pub payload_bytes: u64,
}

/// A frame to stream: encoded already ([`Encoded`]), or encoded only as it is sent
/// ([`Unencoded`]), so that through a shared memory region a frame whose samples are its
/// planes' own bytes (f32, uncompressed) is written into its slot straight from its planes
/// ([`SharedRegion::write`]), with no encoded copy.
pub trait Outgoing: Sized {
    /// The frame encoded: its header and data chunks.
    fn encode(self) -> Encoded;

    /// Whether [`Outgoing::place`] writes it into a region without encoding it first: such
    /// a frame waits, unencoded, until its slot is free, where others are encoded while
    /// earlier frames are in flight.
    fn in_place(&self) -> bool {
        false
    }

    /// Writes it as the `n`th frame sent into its slot of `region` and returns the header
    /// to send for it (encoded, then [`SharedRegion::place`]d, unless overridden).
    fn place(self, region: &SharedRegion, n: u64) -> std::io::Result<Encoded> {
        region.place(n, self.encode())
    }
}

impl Outgoing for Encoded {
    fn encode(self) -> Encoded {
        self
    }
}

/// A frame not yet encoded: `frame` for session `session_id`, to be sent as `how` says.
#[derive(Clone, Debug)]
pub struct Unencoded<'a> {
    /// The frame.
    pub frame: FrameData<'a>,
    /// Its session.
    pub session_id: &'a str,
    /// How its samples travel.
    pub how: Encoding,
}

impl Outgoing for Unencoded<'_> {
    fn encode(self) -> Encoded {
        encode(&self.frame, self.session_id, self.how)
    }

    fn in_place(&self) -> bool {
        self.how.in_place()
    }

    fn place(self, region: &SharedRegion, n: u64) -> std::io::Result<Encoded> {
        region.write(n, &self.frame, self.session_id, self.how)
    }
}

/// Streams `frames` (encoded as they are taken, see [`Outgoing`]) to session
/// `session`, `in_flight` frames ahead of their replies (at least 1) beyond a windowed
/// filter's lookahead, and calls `on_reply` with each reply in order. With 1, the next
/// frame is sent when the last reply is in, so `round_trip_ms` is a latency; with 2 the
/// next goes out while the server filters the last (the server receives one frame while
/// it filters another; more gain nothing). With a windowed filter (`session.lookahead` =
/// L > 0) the reply to frame t comes after frame t + L is sent; the client closes its side
/// after the last frame and reads the rest.
pub async fn stream(
    inner: &mut Inner,
    session: &pb::Session,
    frames: impl IntoIterator<Item = impl Outgoing>,
    in_flight: usize,
    on_reply: impl FnMut(Reply),
) -> Result<(), Status> {
    stream_through(inner, session, frames, in_flight, None, on_reply).await
}

/// [`stream`], with the frames' bytes and the replies' colour going through `region` (the
/// session's shared memory region, cut into at least `lookahead + in_flight` slots) when
/// given, so that only headers cross the socket.
pub async fn stream_through(
    inner: &mut Inner,
    session: &pb::Session,
    frames: impl IntoIterator<Item = impl Outgoing>,
    in_flight: usize,
    region: Option<&SharedRegion>,
    mut on_reply: impl FnMut(Reply),
) -> Result<(), Status> {
    let lookahead = session.lookahead as usize;
    if let Some(r) = region {
        // A slot per frame in flight, or a frame would overwrite one still in use.
        let need = (lookahead + in_flight.max(1)) as u64;
        if r.slots() < need {
            return Err(Status::invalid_argument(format!(
                "a shared memory region of {} slots for {need} frames in flight",
                r.slots()
            )));
        }
    }
    let (tx, rx) = mpsc::channel::<pb::FrameChunk>(4);
    let mut replies = inner.stream(ReceiverStream::new(rx)).await?.into_inner();
    // Frames sent whose reply has not come: when, and how many bytes.
    let sent_at: Mutex<VecDeque<(Instant, u64)>> = Mutex::new(VecDeque::new());
    // A permit per frame that may be in flight; each reply gives one back.
    let permits = Semaphore::new(lookahead + in_flight.max(1));
    // Frames go out while replies come in: a server that answers frame t while it
    // receives frame t + 1 never waits on a client busy sending.
    let send = async {
        for (n, frame) in (0u64..).zip(frames) {
            // Encoded now, while earlier frames are in flight, unless it is to be written
            // into its slot straight from its planes, which waits for the slot.
            let frame = match region {
                Some(_) if frame.in_place() => Staged::Unencoded(frame),
                _ => Staged::Encoded(frame.encode()),
            };
            match permits.acquire().await {
                Ok(p) => p.forget(),
                Err(_) => return Ok::<(), Status>(()),
            }
            // Into its slot only now: the reply that used the slot before has been read.
            let frame = match (region, frame) {
                (Some(r), Staged::Encoded(e)) => r.place(n, e),
                (Some(r), Staged::Unencoded(f)) => f.place(r, n),
                (None, Staged::Encoded(e)) => Ok(e),
                (None, Staged::Unencoded(f)) => Ok(f.encode()),
            }
            .map_err(|e| Status::internal(format!("shared memory region: {e}")))?;
            // As the header gives them: a frame in the region has no chunks.
            let bytes = frame.header.channels.iter().map(|c| c.byte_length).sum();
            lock(&sent_at).push_back((Instant::now(), bytes));
            let parts = std::iter::once(frame_chunk::Part::Header(frame.header))
                .chain(frame.chunks.into_iter().map(frame_chunk::Part::Data));
            for part in parts {
                if tx.send(pb::FrameChunk { part: Some(part) }).await.is_err() {
                    // The server ended the stream: the replies' status says why.
                    return Ok(());
                }
            }
        }
        // Closing our side makes a windowed filter give its last frames.
        drop(tx);
        Ok(())
    };
    let receive = async {
        // The replies' bytes out of the region, one buffer for them all.
        let mut from_region = Vec::new();
        while let Some(reply) = read_reply(&mut replies, &sent_at, region, &mut from_region).await? {
            permits.add_permits(1);
            on_reply(reply);
        }
        let unanswered = lock(&sent_at).len();
        if unanswered > 0 {
            return Err(Status::unavailable(format!(
                "the server ended the stream with {unanswered} frames unanswered"
            )));
        }
        Ok(())
    };
    tokio::pin!(send, receive);
    let mut sending = true;
    loop {
        tokio::select! {
            r = &mut send, if sending => {
                r?;
                sending = false;
            }
            r = &mut receive => return r,
        }
    }
}

/// A frame taken to be sent, before its slot is free.
enum Staged<F> {
    Encoded(Encoded),
    Unencoded(F),
}

/// The queue of frames in flight (never held across an await).
fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// Reads one reply (header, then the colour's chunks, or its colour from `region` through
/// `from_region` where it needs converting), matched to the oldest frame in flight; None
/// when the stream ended cleanly (read to its end, so the server has let go of the session).
async fn read_reply(
    replies: &mut tonic::Streaming<pb::FilteredChunk>,
    sent_at: &Mutex<VecDeque<(Instant, u64)>>,
    region: Option<&SharedRegion>,
    from_region: &mut Vec<u8>,
) -> Result<Option<Reply>, Status> {
    let head = match replies.next().await {
        Some(Ok(pb::FilteredChunk {
            part: Some(filtered_chunk::Part::Header(h)),
        })) => h,
        Some(Ok(_)) => return Err(Status::internal("reply data before its header")),
        Some(Err(s)) => return Err(s),
        None => return Ok(None),
    };
    let color_h = head
        .color
        .clone()
        .ok_or_else(|| Status::internal("reply without colour"))?;
    let color = match (&head.shared_memory, region) {
        (Some(at), Some(r)) => r
            .read_color(at.reply_offset, &color_h, (head.width, head.height), from_region)
            .map_err(|e| Status::internal(format!("shared memory region: reading the reply: {e}")))?,
        (Some(_), None) => {
            return Err(Status::internal(
                "a reply in shared memory on a stream without a region",
            ))
        }
        (None, _) => {
            // The chunks as they came (views of the receive buffers): decoding reads
            // across them.
            let mut chunks = Vec::new();
            let mut received = 0u64;
            while received < color_h.byte_length {
                match replies.next().await {
                    Some(Ok(pb::FilteredChunk {
                        part: Some(filtered_chunk::Part::Data(d)),
                    })) => {
                        received += d.data.len() as u64;
                        chunks.push(d.data);
                    }
                    Some(Err(s)) => return Err(s),
                    _ => return Err(Status::internal("reply ended before its colour")),
                }
            }
            let pieces: Vec<&[u8]> = chunks.iter().map(|c| &c[..]).collect();
            decode_color(&color_h, &pieces, head.width, head.height)
                .map_err(|e| Status::internal(e.to_string()))?
        }
    };
    let received = color_h.byte_length;
    let (t, sent) = lock(sent_at)
        .pop_front()
        .ok_or_else(|| Status::internal("a reply to no frame sent"))?;
    Ok(Some(Reply {
        index: head.index,
        color,
        width: head.width,
        height: head.height,
        report: head.report.unwrap_or_default(),
        round_trip_ms: t.elapsed().as_secs_f64() * 1e3,
        payload_bytes: sent + received,
    }))
}
