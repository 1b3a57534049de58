//! The shared memory transport, for a client on the server's machine: the server makes a
//! region (a file on its tmpfs, `OpenRegion`), the client writes each frame's bytes into
//! it and sends only the header with their offsets, and the server writes the reply's
//! colour back into it. The region is cut into one slot per frame that may be in flight,
//! each a frame's bytes followed by its reply's colour; a frame is written into its slot
//! only when the reply that used the slot before has been read.
//!
//! Positioned reads and writes (`pread`/`pwrite`), as the server: no mapping, no
//! `unsafe`.

use crate::frame::Encoded;
use crate::proto::{Region, SharedMemory};
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

    /// Reads a reply's `len` bytes of colour from `offset` into `buf` (resized to `len`;
    /// a buffer kept from one reply to the next is neither cleared nor faulted in again).
    pub fn read_into(&self, offset: u64, len: u64, buf: &mut Vec<u8>) -> io::Result<()> {
        buf.resize(len as usize, 0);
        self.file.read_exact_at(buf, offset)
    }
}
