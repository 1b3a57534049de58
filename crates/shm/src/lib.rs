//! A shared memory region mapped into this process: the server makes one per session for
//! a client on the same machine (the shared memory transport, `docs/server.md`), and both
//! copy frames and replies in and out of their mappings.
//!
//! Why a mapping: a positioned read or write of a tmpfs file is a copy in the kernel, and
//! on the virtual machines we measured that copy runs at 1.2-1.3 GB/s where a copy between
//! two mappings runs at 7 GB/s (`docs/measurements.md`, "Serving"): 17 ms of a 720p
//! frame's 22 MB against 3 ms.
//!
//! Why it is safe to map memory another process holds:
//! - **It cannot shrink.** A mapped file that another process truncates faults (SIGBUS) on
//!   the next access and kills the process. The region is a memfd sealed against shrinking
//!   and growing, and the seals sealed, before anyone else can open it: a client's
//!   `ftruncate` fails, and [`Mapping::open`] refuses a file without those seals.
//! - **No reference to it ever exists.** Another process may write the bytes at any time,
//!   so they are only ever copied, between the mapping and this process's own memory
//!   ([`Mapping::read`], [`Mapping::read_f32`], [`Mapping::read_f32_vec`],
//!   [`Mapping::write`]), with bounds checked on every copy. A copy racing a writer gives
//!   torn bytes, which every reader checks as it checks any client's input; a counted
//!   read counts the values it copied (each sample is loaded once, then both stored and
//!   counted).
//!
//! Every other crate of afterimage forbids `unsafe`; this one keeps it to the mapping's
//! creation, its copies (and the counting copy they share with [`copy_f32`]) and its
//! unmapping.

#![deny(unsafe_op_in_unsafe_fn, missing_docs)]
#![warn(clippy::undocumented_unsafe_blocks)]

use rustix::fs::{fcntl_add_seals, fcntl_get_seals, fstat, memfd_create, MemfdFlags, Mode, SealFlags};
use rustix::mm::{mmap, munmap, MapFlags, ProtFlags};
use std::fs::OpenOptions;
use std::os::fd::{AsRawFd, OwnedFd};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;

/// The seals a region carries: its size is fixed, and so are its seals.
const SEALS: SealFlags = SealFlags::SHRINK.union(SealFlags::GROW).union(SealFlags::SEAL);

/// What went wrong making, opening or copying into a region.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A copy that does not lie within the region (the offsets are a client's).
    #[error("{len} bytes at {offset} do not lie within the {size}-byte region")]
    OutOfRange {
        /// Where the copy would start.
        offset: u64,
        /// Its length.
        len: usize,
        /// The region's size.
        size: u64,
    },
    /// A file that is not a sealed region (it could shrink under its mapping).
    #[error("{path}: not a sealed shared memory region (its seals are {seals:?}; expected at least shrink and grow)")]
    Unsealed {
        /// The file.
        path: PathBuf,
        /// The seals it has.
        seals: SealFlags,
    },
    /// A region of no bytes, or of more than this process can address.
    #[error("a region of {0} bytes (expected 1 to {max})", max = isize::MAX)]
    Size(u64),
    /// The system refused a call.
    #[error("{what}: {source}")]
    Io {
        /// The call, and its file.
        what: String,
        /// Why.
        source: std::io::Error,
    },
}

fn io(what: impl Into<String>) -> impl FnOnce(rustix::io::Errno) -> Error {
    let what = what.into();
    move |e| Error::Io {
        what,
        source: e.into(),
    }
}

/// A region mapped read-write into this process, and the file that holds it.
#[derive(Debug)]
pub struct Mapping {
    ptr: NonNull<u8>,
    len: usize,
    fd: OwnedFd,
}

// SAFETY: the mapping is plain memory owned by this value until it is dropped; the
// pointer is only used by the copies and `drop`, which copy through raw pointers and
// hold no reference across threads.
unsafe impl Send for Mapping {}
// SAFETY: as above; the copies take `&self` and only copy bytes, which another
// process may change at any time anyway.
unsafe impl Sync for Mapping {}

impl Mapping {
    /// Makes a region of `bytes` zero bytes: a memfd named `name`, readable and writable by
    /// this user only, sealed at that size, and mapped with its pages in place (so neither
    /// side takes a page fault per frame).
    pub fn create(name: &str, bytes: u64) -> Result<Mapping, Error> {
        let len = size(bytes)?;
        let fd = memfd_create(name, MemfdFlags::CLOEXEC | MemfdFlags::ALLOW_SEALING)
            .map_err(io(format!("memfd_create({name})")))?;
        rustix::fs::fchmod(&fd, Mode::from_raw_mode(0o600)).map_err(io("fchmod 0600"))?;
        rustix::fs::ftruncate(&fd, bytes).map_err(io(format!("sizing the region to {bytes} bytes")))?;
        fcntl_add_seals(&fd, SEALS).map_err(io("sealing the region"))?;
        map(fd, len)
    }

    /// Opens and maps the region at `path` (another process's [`Mapping::path`]), after
    /// checking that it cannot shrink.
    pub fn open(path: &Path) -> Result<Mapping, Error> {
        let fd: OwnedFd = OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| Error::Io {
                what: format!("opening {}", path.display()),
                source: e,
            })?
            .into();
        let seals = fcntl_get_seals(&fd).unwrap_or(SealFlags::empty());
        if !seals.contains(SealFlags::SHRINK | SealFlags::GROW) {
            return Err(Error::Unsealed {
                path: path.into(),
                seals,
            });
        }
        let bytes = fstat(&fd)
            .map_err(io(format!("stat {}", path.display())))?
            .st_size;
        map(fd, size(u64::try_from(bytes).unwrap_or(0))?)
    }

    /// The path another process on this machine opens the region by: this process's
    /// descriptor under `/proc`, which only this user (and root) may open.
    pub fn path(&self) -> PathBuf {
        PathBuf::from(format!("/proc/{}/fd/{}", std::process::id(), self.fd.as_raw_fd()))
    }

    /// Its size in bytes.
    pub fn len(&self) -> u64 {
        self.len as u64
    }

    /// Whether it has no bytes (never: [`Mapping::create`] refuses that).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Where `len` bytes from `offset` start, when they lie within the region.
    fn at(&self, offset: u64, len: usize) -> Result<usize, Error> {
        usize::try_from(offset)
            .ok()
            .filter(|&at| at.checked_add(len).is_some_and(|end| end <= self.len))
            .ok_or(Error::OutOfRange {
                offset,
                len,
                size: self.len as u64,
            })
    }

    /// Copies the region's bytes from `offset` into `dst`.
    pub fn read(&self, offset: u64, dst: &mut [u8]) -> Result<(), Error> {
        let at = self.at(offset, dst.len())?;
        // SAFETY: `at..at + dst.len()` lies within the mapping (checked above), which lives
        // as long as `self`; `dst` is this process's own memory, never part of a mapping
        // (no reference into one is ever made), so the two do not overlap.
        unsafe { std::ptr::copy_nonoverlapping(self.ptr.as_ptr().add(at), dst.as_mut_ptr(), dst.len()) };
        Ok(())
    }

    /// Copies the region's f32 samples from `offset` (any byte, not only a sample's) into
    /// `dst`, and returns how many of them are NaN or infinite: counted in the same pass,
    /// which costs nothing next to the copy where a pass of its own would read them again.
    pub fn read_f32(&self, offset: u64, dst: &mut [f32]) -> Result<u64, Error> {
        let at = self.at(offset, std::mem::size_of_val(dst))?;
        // SAFETY: as in `read`; `dst` holds `size_of_val(dst)` bytes.
        let non_finite = unsafe {
            copy_counting(
                self.ptr.as_ptr().add(at),
                dst.as_mut_ptr().cast(),
                std::mem::size_of_val(dst),
            )
        };
        Ok(non_finite)
    }

    /// The region's `n` f32 samples from `offset` as a new vector, and how many of them are
    /// NaN or infinite: [`Mapping::read_f32`] into memory that is not zeroed first (a pass
    /// as long as the copy; every sample is written by it). Nothing is allocated for a
    /// range outside the region.
    pub fn read_f32_vec(&self, offset: u64, n: usize) -> Result<(Vec<f32>, u64), Error> {
        let len = n.checked_mul(4).ok_or(Error::OutOfRange {
            offset,
            len: usize::MAX,
            size: self.len as u64,
        })?;
        let at = self.at(offset, len)?;
        let mut samples = Vec::<f32>::with_capacity(n);
        // SAFETY: as in `read`, into the vector's `len` bytes of spare capacity.
        let non_finite =
            unsafe { copy_counting(self.ptr.as_ptr().add(at), samples.as_mut_ptr().cast(), len) };
        // SAFETY: the copy wrote all `n` samples.
        unsafe { samples.set_len(n) };
        Ok((samples, non_finite))
    }

    /// Copies `src` into the region at `offset`.
    pub fn write(&self, offset: u64, src: &[u8]) -> Result<(), Error> {
        let at = self.at(offset, src.len())?;
        // SAFETY: as in `read`, with the copy the other way.
        unsafe { std::ptr::copy_nonoverlapping(src.as_ptr(), self.ptr.as_ptr().add(at), src.len()) };
        Ok(())
    }
}

/// Copies `src` into `dst` with the loop [`Mapping::read_f32`] copies a region with, and
/// returns how many of the samples are NaN or infinite: what that read costs, measured
/// without a region (`afterimage stream --compare`'s copy floor).
///
/// # Panics
/// When the two lengths differ.
pub fn copy_f32(src: &[f32], dst: &mut [f32]) -> u64 {
    assert_eq!(
        src.len(),
        dst.len(),
        "copy_f32 between slices of different lengths"
    );
    // SAFETY: two slices of this process of `size_of_val(src)` bytes each; `dst` is the
    // only reference to its memory, so they do not overlap.
    unsafe {
        copy_counting(
            src.as_ptr().cast(),
            dst.as_mut_ptr().cast(),
            std::mem::size_of_val(src),
        )
    }
}

/// An f32's exponent bits: all set in NaNs and infinities, and in no other value.
const EXPONENT: u32 = 0x7f80_0000;

/// Bytes copied per step of [`copy_counting`]: one 256-bit vector.
const BLOCK: usize = 32;

/// Blocks whose count [`copy_counting`] keeps in u32 before adding it to the total (a
/// run's count, at most 8 a block, fits).
const RUN: usize = 1 << 16;

/// Copies `len` bytes (a whole number of f32 samples) from `src` to `dst` a 32-byte block
/// at a time, as loads and stores the compiler vectorises, and returns how many of the
/// samples are NaN or infinite, counted from the values as they pass through registers.
///
/// Why not `memcpy` and then a count: the count's pass reads the samples again, which costs
/// about as much as the copy (`cargo bench --bench wire`: `copy_then_count` against
/// `copy_f32`).
///
/// # Safety
/// `src..src + len` must be readable, `dst..dst + len` writable, and the two must not
/// overlap.
unsafe fn copy_counting(src: *const u8, dst: *mut u8, len: usize) -> u64 {
    debug_assert_eq!(
        len % 4,
        0,
        "copy_counting of {len} bytes, not a whole number of samples"
    );
    type Words = [u32; BLOCK / 4];
    let blocks = len / BLOCK;
    let mut non_finite = 0u64;
    // Counted in u32 lanes, summed into the u64 every run of blocks.
    let mut start = 0;
    while start < blocks {
        let end = blocks.min(start + RUN);
        let mut run = 0u32;
        for b in start..end {
            // SAFETY: block `b` lies within both ranges (`b < len / BLOCK`); unaligned
            // accesses, since a client chooses the region's offsets.
            let words = unsafe { src.add(b * BLOCK).cast::<Words>().read_unaligned() };
            // SAFETY: as above.
            unsafe { dst.add(b * BLOCK).cast::<Words>().write_unaligned(words) };
            run += words
                .iter()
                .map(|&w| u32::from(w & EXPONENT == EXPONENT))
                .sum::<u32>();
        }
        non_finite += u64::from(run);
        start = end;
    }
    let done = blocks * BLOCK;
    // SAFETY: the last `len - done` (< BLOCK) bytes of both ranges.
    unsafe { std::ptr::copy_nonoverlapping(src.add(done), dst.add(done), len - done) };
    // The samples of the last, partial block (`len` is a whole number of them).
    for w in (done..len).step_by(4) {
        // SAFETY: a word within `dst`'s range, just written.
        let word = unsafe { dst.add(w).cast::<u32>().read_unaligned() };
        non_finite += u64::from(word & EXPONENT == EXPONENT);
    }
    non_finite
}

/// `bytes` as a mapping's length: at least one, at most what a pointer offset allows.
fn size(bytes: u64) -> Result<usize, Error> {
    usize::try_from(bytes)
        .ok()
        .filter(|&n| n > 0 && n <= isize::MAX as usize)
        .ok_or(Error::Size(bytes))
}

/// Maps all `len` bytes of `fd`, shared, read-write, pages populated.
fn map(fd: OwnedFd, len: usize) -> Result<Mapping, Error> {
    // SAFETY: a new mapping chosen by the kernel (null hint) overlaps nothing of ours; the
    // file is sealed against shrinking (checked by both callers), so no access within
    // `len` can fault for want of a page.
    let ptr = unsafe {
        mmap(
            std::ptr::null_mut(),
            len,
            ProtFlags::READ | ProtFlags::WRITE,
            MapFlags::SHARED | MapFlags::POPULATE,
            &fd,
            0,
        )
    }
    .map_err(io(format!("mapping {len} bytes")))?;
    let ptr = NonNull::new(ptr.cast::<u8>()).ok_or(Error::Size(len as u64))?;
    Ok(Mapping { ptr, len, fd })
}

impl Drop for Mapping {
    fn drop(&mut self) {
        // SAFETY: `ptr..ptr + len` is the mapping `map` made, and nothing refers to it.
        let _ = unsafe { munmap(self.ptr.as_ptr().cast(), self.len) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_written_through_one_mapping_are_read_through_another() {
        let a = Mapping::create("test", 10_000).unwrap();
        let b = Mapping::open(&a.path()).unwrap();
        assert_eq!((a.len(), b.len()), (10_000, 10_000));
        let src: Vec<u8> = (0..4097u32).map(|i| (i * 7 % 251) as u8).collect();
        a.write(5_000, &src).unwrap();
        let mut got = vec![0u8; src.len()];
        b.read(5_000, &mut got).unwrap();
        assert_eq!(got, src);
        // The last byte, and a read of nothing at the very end.
        b.write(9_999, &[42]).unwrap();
        let mut one = [0u8];
        a.read(9_999, &mut one).unwrap();
        assert_eq!(one, [42]);
        a.read(10_000, &mut []).unwrap();
        // A new region is zeros.
        let mut head = [1u8; 16];
        a.read(0, &mut head).unwrap();
        assert_eq!(head, [0; 16]);
    }

    /// The counting copy against `copy_nonoverlapping` and `is_finite`: every length up to a
    /// few blocks and odd ones past them, at offsets that are not a sample's, with NaNs,
    /// infinities, subnormals and both zeros on the blocks' edges; bit for bit.
    #[test]
    fn the_counting_copy_copies_and_counts_as_the_plain_ones_do() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let specials = [
            f32::NAN,
            -f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::from_bits(0x7f80_0001),
            f32::MIN_POSITIVE / 2.0,
            -0.0,
            0.0,
            f32::MAX,
        ];
        let region = Mapping::create("test", 1 << 20).unwrap();
        let lens = (0..200).chain([1021, 4099, 65_537, 200_003]);
        for (k, n) in lens.enumerate() {
            let samples: Vec<f32> = (0..n)
                .map(|i| match next() % 4 {
                    0 => specials[(next() % specials.len() as u64) as usize],
                    _ if i % 8 == 7 => specials[i % specials.len()],
                    _ => f32::from_bits(next() as u32),
                })
                .collect();
            let offset = (k * 13 % 61) as u64;
            let bytes: Vec<u8> = samples.iter().flat_map(|v| v.to_ne_bytes()).collect();
            region.write(offset, &bytes).unwrap();
            let mut got = vec![1.5f32; n];
            let bad = region.read_f32(offset, &mut got).unwrap();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&got), bits(&samples), "{n} samples at {offset}");
            let expected = samples.iter().filter(|v| !v.is_finite()).count() as u64;
            assert_eq!(bad, expected, "{n} samples at {offset}");
            let (fresh, bad) = region.read_f32_vec(offset, n).unwrap();
            assert_eq!(
                (bits(&fresh), bad),
                (bits(&samples), expected),
                "{n} new samples at {offset}"
            );
            // Between two slices, from any sample on.
            let from = k % 5;
            let mut copied = vec![0f32; n.saturating_sub(from)];
            let bad = copy_f32(&samples[from.min(n)..], &mut copied);
            assert_eq!(
                bits(&copied),
                bits(&samples[from.min(n)..]),
                "{n} samples from {from}"
            );
            let expected = samples[from.min(n)..].iter().filter(|v| !v.is_finite()).count() as u64;
            assert_eq!(bad, expected, "{n} samples from {from}");
            // The byte copy, to a length that is not a sample's.
            let cut = bytes.len().saturating_sub(k % 3);
            let mut raw = vec![7u8; cut];
            region.read(offset, &mut raw).unwrap();
            assert_eq!(raw, bytes[..cut], "{cut} bytes at {offset}");
        }
    }

    /// A copy of more than one run of blocks (the counts are summed run by run), with
    /// non-finite samples on both sides of each run's edge and last.
    #[test]
    fn a_count_across_runs_of_blocks_counts_them_all() {
        let per_run = RUN * BLOCK / 4;
        let n = 2 * per_run + 13;
        let mut samples: Vec<f32> = (0..n).map(|i| i as f32 * 0.25).collect();
        for i in [per_run - 1, per_run, 2 * per_run - 1, 2 * per_run, n - 1] {
            samples[i] = if i % 2 == 0 { f32::NAN } else { f32::NEG_INFINITY };
        }
        let mut copied = vec![0f32; n];
        assert_eq!(copy_f32(&samples, &mut copied), 5);
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&copied), bits(&samples));
    }

    #[test]
    fn copies_outside_the_region_are_refused() {
        let a = Mapping::create("test", 4096).unwrap();
        let mut buf = vec![0u8; 100];
        for offset in [4000, 4097, u64::MAX, u64::MAX - 50, 1 << 63] {
            let e = a.read(offset, &mut buf).unwrap_err();
            assert!(
                matches!(
                    e,
                    Error::OutOfRange {
                        size: 4096,
                        len: 100,
                        ..
                    }
                ),
                "{e}"
            );
            assert!(a.write(offset, &buf).is_err(), "write at {offset}");
        }
        assert!(a.read(3996, &mut buf).is_ok());
        for (offset, n) in [(0, 1025), (4092, 2), (0, usize::MAX), (0, usize::MAX / 4 + 1)] {
            let e = a.read_f32_vec(offset, n).unwrap_err();
            assert!(
                matches!(e, Error::OutOfRange { size: 4096, .. }),
                "{offset} {n}: {e}"
            );
        }
        assert_eq!(a.read_f32_vec(4092, 1).unwrap().0.len(), 1);
        assert!(matches!(Mapping::create("test", 0), Err(Error::Size(0))));
        assert!(matches!(Mapping::create("test", u64::MAX), Err(Error::Size(_))));
    }

    #[test]
    fn another_process_cannot_shrink_or_grow_it_and_only_this_user_opens_it() {
        use std::os::unix::fs::PermissionsExt;
        let a = Mapping::create("test", 8192).unwrap();
        let path = a.path();
        let file = OpenOptions::new().write(true).open(&path).unwrap();
        for len in [0, 100, 8191, 8193] {
            let e = file.set_len(len).unwrap_err();
            assert_eq!(
                e.kind(),
                std::io::ErrorKind::PermissionDenied,
                "set_len({len}): {e}"
            );
        }
        assert_eq!(file.metadata().unwrap().len(), 8192);
        // Nor can the seals be taken off.
        let seals = fcntl_get_seals(&file).unwrap();
        assert!(seals.contains(SEALS), "{seals:?}");
        let mode = std::fs::metadata(&path).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600);
        // Gone with its mapping.
        drop((file, a));
        assert!(!path.exists(), "{}", path.display());
    }

    #[test]
    fn a_file_that_could_shrink_is_not_mapped() {
        let dir = std::env::temp_dir().join(format!("afterimage-shm-unsealed-{}", std::process::id()));
        std::fs::write(&dir, vec![0u8; 4096]).unwrap();
        let e = Mapping::open(&dir).unwrap_err();
        std::fs::remove_file(&dir).unwrap();
        assert!(matches!(e, Error::Unsealed { .. }), "{e}");
        assert!(e.to_string().contains("not a sealed"), "{e}");
        let e = Mapping::open(Path::new("/proc/self/fd/999999")).unwrap_err();
        assert!(e.to_string().contains("opening /proc/self/fd/999999"), "{e}");
    }
}
