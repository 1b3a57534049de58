//! A session's shared memory region: a sealed memfd that the server makes and maps, and
//! that a client on the same machine opens through `/proc` and maps too, so that a frame's
//! bytes and its reply's colour are written in place and the stream carries only their
//! offsets (the idea of Triton's system shared memory extension).
//!
//! The mapping and why it is safe (a client cannot shrink the file under it) live in the
//! `afterimage-shm` crate, the one crate with `unsafe` code; this module checks a client's
//! offsets against the region and keeps the buffers a converted frame or reply is staged in.

use super::{lock, Reservation, SessionError};
use afterimage_shm::Mapping;
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::Mutex;

/// Copies in and out of the region go in pieces of this size over the filter threads: one
/// core's copy of a 720p frame (22 MB) takes 3-4 ms, as long as a fifth of taa's filtering.
const COPY_PIECE: usize = 1 << 20;

/// A region: its mapping, and the memory it holds against the budgets.
#[derive(Debug)]
pub struct Region {
    map: Mapping,
    /// The region's pages, and the staging buffers below.
    _hold: Reservation,
    /// Reused buffers for a frame's bytes read from the region and a reply's colour
    /// written to it, when they need converting (fresh multi-MiB buffers fault in page by
    /// page).
    inbound: Mutex<Vec<u8>>,
    outbound: Mutex<Vec<u8>>,
}

impl Region {
    /// Makes a region of `bytes` zero bytes, readable and writable by this user only (see
    /// [`Mapping::create`]). Its path names this process's descriptor, not the session:
    /// the session id is what opens a session.
    pub fn create(bytes: u64, hold: Reservation) -> Result<Region, SessionError> {
        let map = Mapping::create("afterimage-region", bytes)
            .map_err(|e| SessionError::Internal(format!("shared memory: {e}")))?;
        Ok(Region {
            map,
            _hold: hold,
            inbound: Mutex::new(Vec::new()),
            outbound: Mutex::new(Vec::new()),
        })
    }

    /// The file a client opens.
    pub fn path(&self) -> PathBuf {
        self.map.path()
    }

    /// Its size in bytes.
    pub fn bytes(&self) -> u64 {
        self.map.len()
    }

    /// Checks that frame `index`'s bytes (`len` from `offset`) and its reply (`reply_len`
    /// from `reply_offset`) lie in the region and do not overlap. All arithmetic is
    /// checked: the offsets are a client's.
    pub fn check(
        &self,
        index: u64,
        (offset, len): (u64, u64),
        (reply_offset, reply_len): (u64, u64),
    ) -> Result<(), SessionError> {
        let bad = |field: &str, message: String| {
            SessionError::invalid(format!("header.shared_memory.{field}"), message)
        };
        let end = |field: &str, at: u64, len: u64, what: &str| {
            at.checked_add(len).filter(|&e| e <= self.bytes()).ok_or_else(|| {
                bad(
                    field,
                    format!(
                        "frame {index}: {what} is {len} bytes from {at}, past the end of the {}-byte region",
                        self.bytes()
                    ),
                )
            })
        };
        let frame_end = end("offset", offset, len, "the frame")?;
        let reply_end = end("reply_offset", reply_offset, reply_len, "the reply")?;
        if offset < reply_end && reply_offset < frame_end {
            return Err(bad(
                "reply_offset",
                format!(
                    "frame {index}: the reply ({reply_offset}..{reply_end}) overlaps the frame's bytes ({offset}..{frame_end})"
                ),
            ));
        }
        Ok(())
    }

    /// Frame `index`'s `len` bytes from `offset`, in the reused inbound buffer (hand it
    /// back with [`Region::recycle`]).
    pub fn read(&self, index: u64, offset: u64, len: usize) -> Result<Vec<u8>, SessionError> {
        let mut buf = std::mem::take(&mut *lock(&self.inbound));
        buf.resize(len, 0);
        self.read_into(index, offset, &mut buf)?;
        Ok(buf)
    }

    /// Fills `dst` with frame `index`'s bytes from `offset`: straight into a plane's
    /// memory where its samples need no conversion, which saves a copy of the frame.
    pub fn read_into(&self, index: u64, offset: u64, dst: &mut [u8]) -> Result<(), SessionError> {
        self.read_pieces(index, offset, dst, |map, at, piece| {
            map.read(at, piece).map(|()| 0)
        })
        .map(|_| ())
    }

    /// Fills `dst` with frame `index`'s f32 samples from `offset`, as [`Region::read_into`],
    /// and counts the NaN and infinite ones among them in the same pass (a pass of its own
    /// over a colour costs about as much again as reading it).
    pub fn read_counting(&self, index: u64, offset: u64, dst: &mut [f32]) -> Result<u64, SessionError> {
        self.read_pieces(index, offset, dst, Mapping::read_f32)
    }

    /// Reads `dst` from `offset` in pieces of [`COPY_PIECE`] bytes over the filter threads
    /// with `read`, summing what it returns.
    fn read_pieces<T: Send>(
        &self,
        index: u64,
        offset: u64,
        dst: &mut [T],
        read: impl Fn(&Mapping, u64, &mut [T]) -> Result<u64, afterimage_shm::Error> + Sync,
    ) -> Result<u64, SessionError> {
        let size = std::mem::size_of::<T>().max(1);
        let per_piece = COPY_PIECE / size;
        dst.par_chunks_mut(per_piece)
            .enumerate()
            .map(|(k, piece)| {
                // Past u64's end: refused by the mapping's range check, not wrapped.
                let at = offset.saturating_add((k * per_piece * size) as u64);
                read(&self.map, at, piece)
            })
            .try_reduce(|| 0, |a, b| Ok(a + b))
            .map_err(|e| out_of_range(index, e))
    }

    /// Writes `src` (a reply's plane, say) at `offset`.
    pub fn write_from(&self, index: u64, offset: u64, src: &[u8]) -> Result<(), SessionError> {
        src.par_chunks(COPY_PIECE)
            .enumerate()
            .try_for_each(|(k, piece)| {
                self.map
                    .write(offset.saturating_add((k * COPY_PIECE) as u64), piece)
            })
            .map_err(|e| out_of_range(index, e))
    }

    /// Takes back the buffer [`Region::read`] gave, for the next frame.
    pub fn recycle(&self, buf: Vec<u8>) {
        *lock(&self.inbound) = buf;
    }

    /// Writes a reply's colour at `offset`: `fill` writes it into a buffer of `len` bytes.
    pub fn write(
        &self,
        index: u64,
        offset: u64,
        len: usize,
        fill: impl FnOnce(&mut [u8]),
    ) -> Result<(), SessionError> {
        let mut buf = std::mem::take(&mut *lock(&self.outbound));
        buf.resize(len, 0);
        fill(&mut buf);
        let r = self.write_from(index, offset, &buf);
        *lock(&self.outbound) = buf;
        r
    }
}

/// A copy outside the region: the header check should have caught it first.
fn out_of_range(index: u64, e: afterimage_shm::Error) -> SessionError {
    SessionError::invalid("shared_memory", format!("frame {index}: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::count_non_finite;
    use crate::session::Budget;
    use std::os::unix::fs::FileExt;

    /// The count made piece by piece is the count of the samples read, across pieces, at an
    /// offset that is not a sample's, with NaNs and infinities on the pieces' edges.
    #[test]
    fn a_counted_read_counts_every_non_finite_sample() {
        let n = COPY_PIECE / 4 * 2 + 37;
        let mut samples: Vec<f32> = (0..n).map(|i| i as f32 * 0.5 - 3.0).collect();
        for i in [0, COPY_PIECE / 4 - 1, COPY_PIECE / 4, COPY_PIECE / 2 + 1, n - 1] {
            samples[i] = f32::NAN;
        }
        for i in [7, COPY_PIECE / 4 + 1, n - 2] {
            samples[i] = if i % 2 == 0 {
                f32::INFINITY
            } else {
                f32::NEG_INFINITY
            };
        }
        let bytes = (n * 4 + 13) as u64;
        let hold = Reservation::take(&[&Budget::new("test", 1 << 30)], bytes, "region").unwrap();
        let region = Region::create(bytes, hold).unwrap();
        let file = std::fs::File::options().write(true).open(region.path()).unwrap();
        file.write_all_at(bytemuck::cast_slice(&samples), 13).unwrap();
        let mut got = vec![0f32; n];
        let bad = region.read_counting(0, 13, &mut got).unwrap();
        assert_eq!(bad, 8);
        assert_eq!(bad, count_non_finite(&samples));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&got), bits(&samples));
        // Past the region's end: refused, not read.
        assert!(region.read_counting(0, 14, &mut got).is_err());
    }
}
