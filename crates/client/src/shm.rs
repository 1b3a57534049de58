//! The shared memory transport, for a client on the server's machine: the server makes a
//! region (a file on its tmpfs, `OpenRegion`), the client writes each frame's bytes into
//! it and sends only the header with their offsets, and the server writes the reply's
//! colour back into it. The region is cut into one slot per frame that may be in flight,
//! each a frame's bytes followed by its reply's colour; a frame is written into its slot
//! only when the reply that used the slot before has been read.
//!
//! Positioned reads and writes (`pread`/`pwrite`), as the server: no mapping, no
//! `unsafe`.

use crate::frame::{decode_color, Encoded, ReplyError};
use crate::proto::{ChannelHeader, Compression, Region, SampleType, SharedMemory};
use std::fs::{File, OpenOptions};
use std::io;
use std::os::unix::fs::FileExt;

/// A session's region, opened by the client and cut into slots.
#[derive(Debug)]
pub struct SharedRegion {
    file: File,
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
        let file = OpenOptions::new().read(true).write(true).open(&region.path)?;
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
            file,
            slot_bytes,
            frame_bytes,
            slots,
        })
    }

    /// Frames it can hold at once.
    pub fn slots(&self) -> u64 {
        self.slots
    }

    /// Writes the `n`th frame sent into its slot and returns the header to send for it
    /// (no data chunks follow).
    pub fn place(&self, n: u64, frame: Encoded) -> io::Result<Encoded> {
        let at = (n % self.slots) * self.slot_bytes;
        let len: u64 = frame.data_bytes();
        if len > self.frame_bytes {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!(
                    "frame {}: {len} bytes, a slot holds {}",
                    frame.header.index, self.frame_bytes
                ),
            ));
        }
        let mut offset = at;
        for c in &frame.chunks {
            self.file.write_all_at(&c.data, offset)?;
            offset += c.data.len() as u64;
        }
        let mut header = frame.header;
        header.shared_memory = Some(SharedMemory {
            offset: at,
            reply_offset: at + self.frame_bytes,
        });
        Ok(Encoded {
            header,
            chunks: Vec::new(),
        })
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
        let raw_f32 = ch.sample == SampleType::F32 as i32 && ch.compression == Compression::None as i32;
        if raw_f32 && cfg!(target_endian = "little") {
            if ch.byte_length != (3 * n * 4) as u64 {
                return Err(ReplyError::Header(format!(
                    "expected {} bytes (3 x {width}x{height} f32 samples), got {}",
                    3 * n * 4,
                    ch.byte_length
                )));
            }
            let mut planes = [vec![0f32; n], vec![0f32; n], vec![0f32; n]];
            for (k, p) in (0u64..).zip(&mut planes) {
                self.file
                    .read_exact_at(bytemuck::cast_slice_mut(p), offset + k * (n * 4) as u64)?;
            }
            return Ok(planes);
        }
        let len = usize::try_from(ch.byte_length)
            .map_err(|_| ReplyError::Header(format!("{} bytes of colour", ch.byte_length)))?;
        buf.resize(len, 0);
        self.file.read_exact_at(buf, offset)?;
        decode_color(ch, &[&buf[..]], width, height)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reply's f32 colour is read from the region straight into its planes (the staging
    /// buffer stays empty); an f16 one goes through the buffer and is widened; both give
    /// the samples written.
    #[test]
    fn a_reply_is_read_in_place_when_f32_and_through_the_buffer_when_f16() {
        let (w, h) = (5u32, 3u32);
        let n = (w * h) as usize;
        let want: Vec<f32> = (0..3 * n).map(|i| i as f32 * 0.25 - 2.0).collect();
        let path = std::env::temp_dir().join(format!("afterimage-shm-test-{}", std::process::id()));
        for sample in [SampleType::F32, SampleType::F16] {
            let mut bytes = vec![0u8; want.len() * crate::codec::sample_bytes(sample)];
            crate::codec::put_samples(&want, sample, &mut bytes);
            let offset = 8;
            std::fs::write(&path, [vec![0u8; offset], bytes.clone()].concat()).unwrap();
            let region = Region {
                session_id: "s".into(),
                path: path.display().to_string(),
                bytes: (offset + bytes.len()) as u64,
            };
            let r = SharedRegion::open(&region, 0, bytes.len() as u64, 1).unwrap();
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
        let _ = std::fs::remove_file(&path);
    }
}
