//! A session's shared memory region: a file on a tmpfs (`/dev/shm` by default) that the
//! server creates and a client on the same machine opens, so that a frame's bytes and its
//! reply's colour are written in place and the stream carries only their offsets (the
//! idea of Triton's system shared memory extension).
//!
//! Both sides use positioned reads and writes (`pread`/`pwrite`), not a mapping: every
//! crate here forbids `unsafe`, and a mapping that a client truncates under the server
//! faults (SIGBUS) where a read of a truncated file is an error this module reports. The
//! cost is one memory copy each way, against the socket's several.

use super::{lock, random_hex, Reservation, SessionError};
use std::fs::{File, OpenOptions};
use std::os::unix::fs::{FileExt, OpenOptionsExt};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// A region: its file, its size, and the memory it holds against the budgets.
#[derive(Debug)]
pub struct Region {
    path: PathBuf,
    file: File,
    bytes: u64,
    /// The region's bytes on the tmpfs, and the staging buffers below.
    _hold: Reservation,
    /// Reused buffers for a frame's bytes read from the region and a reply's colour
    /// written to it (fresh multi-MiB buffers fault in page by page).
    inbound: Mutex<Vec<u8>>,
    outbound: Mutex<Vec<u8>>,
}

impl Region {
    /// Creates the file `dir/afterimage-<random>`, of `bytes` bytes, readable and writable
    /// by this user only. `create_new` refuses a path that exists, a link included, so
    /// nothing a client planted there is opened. The name leaves the session id out: anyone
    /// on the machine can list the directory, and an id is what opens a session.
    pub fn create(dir: &Path, bytes: u64, hold: Reservation) -> Result<Region, SessionError> {
        let io = |what: &str, path: &Path, e: std::io::Error| {
            SessionError::Internal(format!("shared memory: {what} {}: {e}", path.display()))
        };
        let random = random_hex(16)
            .map_err(|e| SessionError::Internal(format!("shared memory: no random name: {e}")))?;
        let name = format!("afterimage-{random}");
        let path = dir.join(name);
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create_new(true)
            .mode(0o600)
            .open(&path)
            .map_err(|e| io("cannot create", &path, e))?;
        if let Err(e) = file.set_len(bytes) {
            let _ = std::fs::remove_file(&path);
            return Err(io("cannot size", &path, e));
        }
        Ok(Region {
            path,
            file,
            bytes,
            _hold: hold,
            inbound: Mutex::new(Vec::new()),
            outbound: Mutex::new(Vec::new()),
        })
    }

    /// The file a client opens.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Its size in bytes.
    pub fn bytes(&self) -> u64 {
        self.bytes
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
            at.checked_add(len).filter(|&e| e <= self.bytes).ok_or_else(|| {
                bad(
                    field,
                    format!(
                        "frame {index}: {what} is {len} bytes from {at}, past the end of the {}-byte region",
                        self.bytes
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
    /// back with [`Region::recycle`]); a file a client truncated is an error that says so.
    pub fn read(&self, index: u64, offset: u64, len: usize) -> Result<Vec<u8>, SessionError> {
        let mut buf = std::mem::take(&mut *lock(&self.inbound));
        buf.resize(len, 0);
        self.read_into(index, offset, &mut buf)?;
        Ok(buf)
    }

    /// Fills `dst` with frame `index`'s bytes from `offset`: straight into a plane's
    /// memory where its samples need no conversion, which saves a copy of the frame.
    pub fn read_into(&self, index: u64, offset: u64, dst: &mut [u8]) -> Result<(), SessionError> {
        self.file
            .read_exact_at(dst, offset)
            .map_err(|e| self.io_error(index, "read", offset, dst.len(), e))
    }

    /// Writes `src` (a reply's plane, say) at `offset`.
    pub fn write_from(&self, index: u64, offset: u64, src: &[u8]) -> Result<(), SessionError> {
        self.file
            .write_all_at(src, offset)
            .map_err(|e| self.io_error(index, "write", offset, src.len(), e))
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

    fn io_error(&self, index: u64, what: &str, offset: u64, len: usize, e: std::io::Error) -> SessionError {
        let now = self.file.metadata().map(|m| m.len()).unwrap_or(0);
        if now < self.bytes {
            SessionError::invalid(
                "shared_memory",
                format!(
                    "frame {index}: cannot {what} {len} bytes at {offset}: the region {} is {now} bytes, it was made {} (truncated by the client?)",
                    self.path.display(),
                    self.bytes
                ),
            )
        } else {
            SessionError::Internal(format!(
                "shared memory: frame {index}: cannot {what} {len} bytes at {offset} of {}: {e}",
                self.path.display()
            ))
        }
    }
}

impl Drop for Region {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}
