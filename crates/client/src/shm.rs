//! The shared memory transport, for a client on the server's machine: the server makes a
//! region (a sealed memfd, `OpenRegion`), the client maps it, writes each frame's bytes into
//! it and sends only the header with their offsets, and the server writes the reply's
//! colour back into it. The region is cut into one slot per frame that may be in flight,
//! each a frame's bytes followed by its reply's colour; a frame is written into its slot
//! only when the reply that used the slot before has been read.
//!
//! Both sides copy through their mappings (`afterimage-shm`, the one crate with `unsafe`
//! code). A frame whose samples are its planes' own bytes (f32 and u32, uncompressed)
//! is written straight from its planes ([`SharedRegion::write`]), others encoded first;
//! an f32 reply is read straight into planes.

use crate::codec::in_host_order;
use crate::frame::{
    decode_color, encode, header, in_place, raw_bytes, Encoded, Encoding, FrameData, ReplyError,
};
use crate::proto::{ChannelHeader, FrameHeader, Region, SampleType, SharedMemory};
use afterimage_shm::Mapping;
use std::io;
use std::path::Path;

/// A session's region, opened by the client and cut into slots.
#[derive(Debug)]
pub struct SharedRegion {
    map: Mapping,
    slot_bytes: u64,
    frame_bytes: u64,
    slots: u64,
}

impl SharedRegion {
    /// Bytes a region needs for `slots` frames in flight of at most `frame_bytes` each
    /// with replies of at most `reply_bytes` each.
    pub fn size_for(frame_bytes: u64, reply_bytes: u64, slots: u64) -> u64 {
        (frame_bytes + reply_bytes) * slots
    }

    /// Opens the region the server made (read and write), cut into `slots` slots whose
    /// frames take at most `frame_bytes` and replies at most `reply_bytes`.
    pub fn open(region: &Region, frame_bytes: u64, reply_bytes: u64, slots: u64) -> io::Result<SharedRegion> {
        let map = Mapping::open(Path::new(&region.path)).map_err(io::Error::other)?;
        if map.len() != region.bytes {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "the region {} is {} bytes, the server said {}",
                    region.path,
                    map.len(),
                    region.bytes
                ),
            ));
        }
        let slots = slots.max(1);
        let slot_bytes = region.bytes / slots;
        if slot_bytes < frame_bytes + reply_bytes {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "a region of {} bytes cut into {slots} slots has {slot_bytes} bytes a slot, less than a frame's {frame_bytes} and a reply's {reply_bytes}",
                    region.bytes
                ),
            ));
        }
        Ok(SharedRegion {
            map,
            slot_bytes,
            frame_bytes,
            slots,
        })
    }

    /// Frames it can hold at once.
    pub fn slots(&self) -> u64 {
        self.slots
    }

    /// Where the `n`th frame sent goes: its slot's offset, after checking that the frame
    /// (`index`, `len` bytes) fits.
    fn slot(&self, n: u64, index: u64, len: u64) -> io::Result<u64> {
        if len > self.frame_bytes {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("frame {index}: {len} bytes, a slot holds {}", self.frame_bytes),
            ));
        }
        Ok((n % self.slots) * self.slot_bytes)
    }

    /// `header` pointing at the slot at `at` (no data chunks follow).
    fn placed(&self, mut header: FrameHeader, at: u64) -> Encoded {
        header.shared_memory = Some(SharedMemory {
            offset: at,
            reply_offset: at + self.frame_bytes,
        });
        Encoded {
            header,
            chunks: Vec::new(),
        }
    }

    /// Writes the `n`th frame sent, encoded, into its slot and returns the header to send
    /// for it (no data chunks follow).
    pub fn place(&self, n: u64, frame: Encoded) -> io::Result<Encoded> {
        let at = self.slot(n, frame.header.index, frame.data_bytes())?;
        let mut offset = at;
        for c in &frame.chunks {
            self.copy_in(offset, &c.data)?;
            offset += c.data.len() as u64;
        }
        Ok(self.placed(frame.header, at))
    }

    /// Writes the `n`th frame sent (`frame`, for session `session_id`, sent as `how` says)
    /// into its slot and returns the header to send for it: straight from its planes when
    /// its samples are the planes' memory ([`SharedRegion::write_in_place`]), else encoded
    /// and placed ([`SharedRegion::place`]). The region's bytes are the same either way.
    pub fn write(
        &self,
        n: u64,
        frame: &FrameData<'_>,
        session_id: &str,
        how: Encoding,
    ) -> io::Result<Encoded> {
        match self.write_in_place(n, frame, session_id, how) {
            Some(written) => written,
            None => self.place(n, encode(frame, session_id, how)),
        }
    }

    /// Writes the `n`th frame sent into its slot straight from its planes, with no encoded
    /// copy, when every channel's samples are the planes' own bytes ([`in_place`]: f32 and
    /// u32, uncompressed, on a little-endian host), and returns the header to send for it;
    /// None (nothing written) when they are not.
    pub fn write_in_place(
        &self,
        n: u64,
        frame: &FrameData<'_>,
        session_id: &str,
        how: Encoding,
    ) -> Option<io::Result<Encoded>> {
        let header = header(frame, session_id, how, raw_bytes(frame, how.sample));
        if !in_place(&header) {
            return None;
        }
        let len = header.channels.iter().map(|c| c.byte_length).sum();
        let write = || {
            let at = self.slot(n, frame.index, len)?;
            let floats = frame
                .channels
                .iter()
                .flat_map(|c| c.planes.iter())
                .map(|p| bytemuck::cast_slice(p));
            let ids = frame.object_id.map(bytemuck::cast_slice);
            let mut offset = at;
            for bytes in floats.chain(ids) {
                self.copy_in(offset, bytes)?;
                offset += bytes.len() as u64;
            }
            Ok(self.placed(header, at))
        };
        Some(write())
    }

    /// Reads a reply's colour (`ch` its header, of a `width x height` frame) from `offset`:
    /// f32 samples straight into the planes, f16 through `buf` (kept from one reply to the
    /// next, so it is neither cleared nor faulted in again).
    pub fn read_color(
        &self,
        offset: u64,
        ch: &ChannelHeader,
        (width, height): (u32, u32),
        buf: &mut Vec<u8>,
    ) -> Result<[Vec<f32>; 3], ReplyError> {
        let n = width as usize * height as usize;
        if ch.sample == SampleType::F32 as i32 && in_host_order(ch.sample, ch.compression) {
            // The header is the server's: its sizes are checked before anything is read.
            let plane_bytes = (n as u64).checked_mul(4);
            let total = plane_bytes.and_then(|b| b.checked_mul(3));
            if total != Some(ch.byte_length) {
                return Err(ReplyError::Header(format!(
                    "expected {} bytes (3 x {width}x{height} f32 samples), got {}",
                    total.map_or("more than 2^64".to_string(), |t| t.to_string()),
                    ch.byte_length
                )));
            }
            let plane_bytes = plane_bytes.unwrap_or(0);
            let plane = |k: u64| {
                let at = offset.checked_add(k * plane_bytes);
                at.ok_or_else(|| io::Error::other(format!("reply offset {offset} overflows")))
                    .and_then(|at| self.map.read_f32_vec(at, n).map_err(io::Error::other))
                    .map(|(samples, _)| samples)
            };
            return Ok([plane(0)?, plane(1)?, plane(2)?]);
        }
        let len = usize::try_from(ch.byte_length)
            .map_err(|_| ReplyError::Header(format!("{} bytes of colour", ch.byte_length)))?;
        buf.resize(len, 0);
        self.copy_out(offset, buf)?;
        decode_color(ch, &[&buf[..]], width, height)
    }

    fn copy_in(&self, offset: u64, src: &[u8]) -> io::Result<()> {
        self.map.write(offset, src).map_err(io::Error::other)
    }

    fn copy_out(&self, offset: u64, dst: &mut [u8]) -> io::Result<()> {
        self.map.read(offset, dst).map_err(io::Error::other)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::Channel;
    use crate::proto::Compression;

    /// A region of `bytes` zeros as the server makes it (returned, to read its bytes
    /// with [`all_of`]), opened by the client cut into `slots` slots of `frame_bytes`
    /// frames and `reply_bytes` replies.
    fn region(bytes: u64, frame_bytes: u64, reply_bytes: u64, slots: u64) -> (SharedRegion, Mapping) {
        let server = Mapping::create("test", bytes).unwrap();
        let region = Region {
            session_id: "s".into(),
            path: server.path().display().to_string(),
            bytes,
        };
        (
            SharedRegion::open(&region, frame_bytes, reply_bytes, slots).unwrap(),
            server,
        )
    }

    /// Every byte of a region, as the server sees it.
    fn all_of(m: &Mapping) -> Vec<u8> {
        let mut v = vec![0u8; m.len() as usize];
        m.read(0, &mut v).unwrap();
        v
    }

    /// An f32 frame (with and without object ids, full or sparse colour, odd sizes,
    /// arbitrary bit patterns NaNs included) is written into its slot straight from its
    /// planes ([`SharedRegion::write_in_place`] takes it), and the region then holds, byte
    /// for byte, what encoding it and placing the encoded bytes gives, with the same
    /// header; f16 and zstd frames are not taken in place (nothing written) and go through
    /// the encoder, to the same bytes; a frame larger than its slot is refused, unwritten.
    #[test]
    fn an_f32_frame_is_written_in_place_to_the_bytes_encoding_gives() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut bits = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u32
        };
        for (case, ((w, h), ids, shading)) in [
            ((7usize, 5usize), false, None),
            ((13, 3), true, None),
            ((1, 1), true, None),
            ((9, 11), true, Some((3u32, [1u32, 2u32]))),
        ]
        .into_iter()
        .enumerate()
        {
            let n = w * h;
            let (cw, ch) = match shading {
                Some((f, _)) => (w.div_ceil(f as usize), h.div_ceil(f as usize)),
                None => (w, h),
            };
            let mut plane = |len: usize| (0..len).map(|_| f32::from_bits(bits())).collect::<Vec<f32>>();
            let color = [plane(cw * ch), plane(cw * ch), plane(cw * ch)];
            let depth = [plane(n)];
            let motion = [plane(n), plane(n)];
            let object_id: Vec<u32> = (0..n).map(|_| bits()).collect();
            let color: Vec<&[f32]> = color.iter().map(|p| &p[..]).collect();
            let depth: Vec<&[f32]> = depth.iter().map(|p| &p[..]).collect();
            let motion: Vec<&[f32]> = motion.iter().map(|p| &p[..]).collect();
            let frame = FrameData {
                index: 40 + case as u64,
                reset: case == 2,
                jitter: [0.25, -0.125],
                channels: vec![
                    Channel {
                        name: "depth",
                        planes: &depth,
                    },
                    Channel {
                        name: "color",
                        planes: &color,
                    },
                    Channel {
                        name: "motion",
                        planes: &motion,
                    },
                ],
                object_id: ids.then_some(&object_id[..]),
                shading,
            };
            let f32_bytes: u64 = raw_bytes(&frame, SampleType::F32).map(|b| b as u64).sum();
            // Room to spare in each slot (zstd makes random bits longer), so a write past
            // the frame's bytes would show.
            let slot = 2 * f32_bytes + 64;
            for (sample, compression) in [
                (SampleType::F32, Compression::None),
                (SampleType::F16, Compression::None),
                (SampleType::F32, Compression::Zstd),
            ] {
                let how = Encoding {
                    sample,
                    compression,
                    max_chunk: 5,
                };
                let what = format!("{w}x{h}, ids {ids}, {sample:?} {compression:?}");
                let (direct, direct_server) = region(2 * slot, slot, 0, 2);
                let (encoded, encoded_server) = region(2 * slot, slot, 0, 2);
                // The second slot, so the offsets count.
                let want = encoded.place(1, encode(&frame, "s", how)).unwrap();
                let got = direct.write_in_place(1, &frame, "s", how);
                if how.in_place() {
                    let got = got.expect("an f32 frame is written in place").unwrap();
                    assert_eq!(got.header, want.header, "{what}");
                    assert!(got.chunks.is_empty(), "{what}");
                    assert!(in_place(&got.header), "{what}");
                } else {
                    assert!(got.is_none(), "{what}: not in place");
                    let untouched = all_of(&direct_server);
                    assert!(untouched.iter().all(|&b| b == 0), "{what}: written");
                    let got = direct.write(1, &frame, "s", how).unwrap();
                    assert_eq!(got.header, want.header, "{what}");
                }
                let (d, e) = (all_of(&direct_server), all_of(&encoded_server));
                assert!(d == e, "{what}: the region's bytes differ");
                if compression == Compression::None {
                    let len = want.header.channels.iter().map(|c| c.byte_length).sum::<u64>() as usize;
                    assert!(d[slot as usize..][..len].iter().any(|&b| b != 0), "{what}");
                }
                // Both ways of writing refuse a frame larger than its slot, naming it and
                // the sizes, before writing anything.
                let (small, small_server) = region(2 * slot, 4, 0, 2);
                for e in [
                    small.write(0, &frame, "s", how).unwrap_err(),
                    small.place(0, encode(&frame, "s", how)).unwrap_err(),
                ] {
                    assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{what}");
                    let len = want.header.channels.iter().map(|c| c.byte_length).sum::<u64>();
                    let msg = format!("frame {}: {len} bytes, a slot holds 4", frame.index);
                    assert_eq!(e.to_string(), msg, "{what}");
                }
                assert!(all_of(&small_server).iter().all(|&b| b == 0), "{what}");
            }
        }
    }

    /// A reply's f32 colour is read from the region straight into its planes (the staging
    /// buffer stays empty); an f16 one goes through the buffer and is widened; both give
    /// the samples written.
    #[test]
    fn a_reply_is_read_in_place_when_f32_and_through_the_buffer_when_f16() {
        let (w, h) = (5u32, 3u32);
        let n = (w * h) as usize;
        let want: Vec<f32> = (0..3 * n).map(|i| i as f32 * 0.25 - 2.0).collect();
        for sample in [SampleType::F32, SampleType::F16] {
            let mut bytes = vec![0u8; want.len() * crate::codec::sample_bytes(sample)];
            crate::codec::put_samples(&want, sample, &mut bytes);
            let offset = 8;
            let (r, server) = region((offset + bytes.len()) as u64, 0, bytes.len() as u64, 1);
            server.write(offset as u64, &bytes).unwrap();
            let ch = ChannelHeader {
                name: "color".into(),
                sample: sample as i32,
                compression: Compression::None as i32,
                byte_length: bytes.len() as u64,
            };
            let mut buf = Vec::new();
            let got = r.read_color(offset as u64, &ch, (w, h), &mut buf).unwrap();
            assert_eq!(got.concat(), want, "{sample:?}");
            let staged = if sample == SampleType::F32 { 0 } else { bytes.len() };
            assert_eq!(buf.len(), staged, "{sample:?}: bytes through the staging buffer");
            // A header whose length does not fit the size is refused, not read short.
            let short = ChannelHeader {
                byte_length: bytes.len() as u64 - 2,
                ..ch
            };
            assert!(r.read_color(offset as u64, &short, (w, h), &mut buf).is_err());
        }
    }

    /// A file the server did not seal is not mapped (it could shrink under the mapping),
    /// and one whose size is not what the server said is refused.
    #[test]
    fn only_a_sealed_region_of_the_size_given_is_opened() {
        let path = std::env::temp_dir().join(format!("afterimage-unsealed-{}", std::process::id()));
        std::fs::write(&path, vec![0u8; 64]).unwrap();
        let plain = Region {
            session_id: "s".into(),
            path: path.display().to_string(),
            bytes: 64,
        };
        let e = SharedRegion::open(&plain, 32, 0, 2).unwrap_err();
        std::fs::remove_file(&path).unwrap();
        assert!(e.to_string().contains("not a sealed"), "{e}");
        let server = Mapping::create("test", 64).unwrap();
        let wrong = Region {
            session_id: "s".into(),
            path: server.path().display().to_string(),
            bytes: 128,
        };
        let e = SharedRegion::open(&wrong, 32, 0, 2).unwrap_err();
        assert!(e.to_string().contains("is 64 bytes, the server said 128"), "{e}");
    }
}
