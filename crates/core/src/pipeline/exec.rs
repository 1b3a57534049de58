//! Execution on the crate's own rayon pool, split by rows.

use rayon::prelude::*;
use std::cell::RefCell;
use std::ops::AddAssign;
use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

/// The first `n` entries of a per-task scratch buffer, grown (never shrunk) to hold them:
/// band kernels keep one such buffer per row kind across bands and frames.
pub fn sized<T: Clone + Default>(v: &mut Vec<T>, n: usize) -> &mut [T] {
    if v.len() < n {
        v.resize(n, T::default());
    }
    &mut v[..n]
}

/// A band's rows with a row of halo on each side, clamped to the image: what a 3x3 stencil
/// over the band reads. Band buffers hold them from row `start`, `width` samples a row.
#[derive(Clone, Copy, Debug)]
pub struct Halo {
    /// The first image row held.
    pub start: usize,
    /// One past the last.
    pub end: usize,
    width: usize,
    height: usize,
}

impl Halo {
    /// The halo of band `rows` of a `width` x `height` image.
    pub fn new(rows: &Range<usize>, width: usize, height: usize) -> Self {
        Halo {
            start: rows.start.saturating_sub(1),
            end: (rows.end + 1).min(height),
            width,
            height,
        }
    }

    /// Samples of a band buffer.
    pub fn samples(&self) -> usize {
        (self.end - self.start) * self.width
    }

    /// Where image row `r` lies in a band buffer.
    pub fn row(&self, r: usize) -> Range<usize> {
        let k = r - self.start;
        k * self.width..(k + 1) * self.width
    }

    /// The rows of row `y`'s 3x3 stencil (above, itself, below; clamped to the image) in a
    /// band buffer.
    pub fn stencil(&self, y: usize) -> [Range<usize>; 3] {
        [y.saturating_sub(1), y, (y + 1).min(self.height - 1)].map(|r| self.row(r))
    }
}

/// Environment variable that sets the number of filter threads (default: all cores).
pub const THREADS_ENV: &str = "AFTERIMAGE_THREADS";

static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
static REQUESTED_THREADS: OnceLock<usize> = OnceLock::new();

/// Asks for `threads` filter threads (0: one per core), overriding `AFTERIMAGE_THREADS`
/// (the command line's `-j`). Only before the pool's first use: afterwards, or after an
/// earlier request, the error carries the count that is in force.
pub fn set_threads(threads: usize) -> Result<(), usize> {
    if let Some(p) = POOL.get() {
        return Err(p.current_num_threads());
    }
    REQUESTED_THREADS
        .set(threads)
        .map_err(|_| *REQUESTED_THREADS.get().unwrap_or(&0))
}

/// The crate's rayon pool: every filter runs its rows here, never on the caller's threads
/// (an async server's workers stay free). Sized by [`set_threads`], else by
/// `AFTERIMAGE_THREADS`, else one thread per core.
pub fn pool() -> &'static rayon::ThreadPool {
    POOL.get_or_init(|| {
        let threads = REQUESTED_THREADS.get().copied().unwrap_or_else(|| {
            std::env::var(THREADS_ENV)
                .ok()
                .and_then(|v| v.parse::<usize>().ok())
                .filter(|&n| n > 0)
                .unwrap_or(0)
        });
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .thread_name(|i| format!("afterimage-filter-{i}"))
            // A panic in a spawned job that nobody caught would abort the process (rayon's
            // default); the server catches its jobs' panics itself, this is the backstop.
            .panic_handler(|panic| {
                tracing::error!(cause = %panic_text(panic.as_ref()), "a job on the filter pool panicked");
            })
            .build()
            .expect("a rayon pool with default settings builds")
    })
}

thread_local! {
    /// The cancel flag of the job this thread runs (see [`with_cancel`]).
    static CANCEL: RefCell<Option<Arc<AtomicBool>>> = const { RefCell::new(None) };
}

/// Runs `job` with `flag` as its cancel flag: long work inside it (a windowed filter's
/// flush, frame by frame) asks [`cancelled`] between steps and stops early once the flag is
/// set, because whoever wanted the result has gone.
pub fn with_cancel<T>(flag: Arc<AtomicBool>, job: impl FnOnce() -> T) -> T {
    let before = CANCEL.with(|c| c.replace(Some(flag)));
    let out = job();
    CANCEL.with(|c| *c.borrow_mut() = before);
    out
}

/// Whether the job running on this thread has been cancelled (never outside
/// [`with_cancel`]).
pub fn cancelled() -> bool {
    CANCEL.with(|c| c.borrow().as_ref().is_some_and(|f| f.load(Ordering::SeqCst)))
}

/// The message of a caught panic's payload (`panic!("...")` gives a `&str` or a `String`).
pub fn panic_text(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic".into())
}

/// Splits `N` planes of `width`-wide rows into one `[row; N]` per image row.
pub fn rows_mut<const N: usize>(planes: [&mut [f32]; N], width: usize) -> Vec<[&mut [f32]; N]> {
    let height = planes.first().map_or(0, |p| p.len() / width.max(1));
    let mut iters = planes.map(|p| p.chunks_mut(width.max(1)));
    (0..height)
        .map(|_| {
            iters
                .each_mut()
                .map(|it| it.next().expect("all planes have the same size"))
        })
        .collect()
}

/// Runs `f(y, rows)` for every row `y` of the `N` output planes on the crate's pool, in
/// parallel, and adds up what the calls return (per-row counters).
pub fn par_rows<const N: usize, C, F>(planes: [&mut [f32]; N], width: usize, f: F) -> C
where
    C: Default + AddAssign + Send,
    F: Fn(usize, [&mut [f32]; N]) -> C + Sync + Send,
{
    let rows = rows_mut(planes, width);
    pool().install(|| {
        rows.into_par_iter()
            .enumerate()
            .map(|(y, r)| f(y, r))
            .reduce(C::default, |mut a, b| {
                a += b;
                a
            })
    })
}

/// Runs `f(y, rows)` for every row `y` of the `N` output planes on the crate's pool.
pub fn for_rows<const N: usize, F>(planes: [&mut [f32]; N], width: usize, f: F)
where
    F: Fn(usize, [&mut [f32]; N]) + Sync + Send,
{
    let rows = rows_mut(planes, width);
    pool().install(|| rows.into_par_iter().enumerate().for_each(|(y, r)| f(y, r)));
}

/// Rows per band of a fused pass: the band's rows and their 3x3 halo stay in the core's
/// L1/L2 while every stage of the pass runs over them, and 1080 rows make 135 tasks, plenty
/// to balance two to sixteen threads.
pub const BAND_ROWS: usize = 8;

/// Runs `f(scratch, rows, band)` for every band of [`BAND_ROWS`] rows of the `N` output
/// planes (`band[k]` holds rows `rows` of plane `k`) in parallel on the crate's pool, and
/// adds up what the calls return. Each task has a `S::default()` scratch of its own (reused
/// across the bands it runs), for the band-local buffers of fused stages.
pub fn par_bands<const N: usize, S, C, F>(planes: [&mut [f32]; N], width: usize, height: usize, f: F) -> C
where
    S: Default + Send,
    C: Default + AddAssign + Send,
    F: Fn(&mut S, std::ops::Range<usize>, [&mut [f32]; N]) -> C + Sync + Send,
{
    par_bands_strided(planes, [width; N], height, f)
}

/// [`par_bands`] over planes of different row lengths: plane `k` has `strides[k]` samples
/// per image row (e.g. four times the width for interleaved 4-channel texels).
pub fn par_bands_strided<const N: usize, S, C, F>(
    planes: [&mut [f32]; N],
    strides: [usize; N],
    height: usize,
    f: F,
) -> C
where
    S: Default + Send,
    C: Default + AddAssign + Send,
    F: Fn(&mut S, std::ops::Range<usize>, [&mut [f32]; N]) -> C + Sync + Send,
{
    let mut k = 0;
    let mut iters = planes.map(|p| {
        let it = p.chunks_mut(BAND_ROWS * strides[k].max(1));
        k += 1;
        it
    });
    let bands: Vec<[&mut [f32]; N]> = (0..height.div_ceil(BAND_ROWS))
        .map(|_| {
            iters
                .each_mut()
                .map(|it| it.next().expect("all planes have the same size"))
        })
        .collect();
    pool().install(|| {
        bands
            .into_par_iter()
            .enumerate()
            .map_init(S::default, |s, (b, band)| {
                let y0 = b * BAND_ROWS;
                f(s, y0..(y0 + BAND_ROWS).min(height), band)
            })
            .reduce(C::default, |mut a, b| {
                a += b;
                a
            })
    })
}

/// Names the stages of a fused pass: `$name`s become the indices 0, 1, ... into its stage
/// list `$stages` (and its [`StageClock`]), one name for each of its stages, checked at
/// compile time, so an index cannot skip or repeat.
macro_rules! stage_indices {
    ($stages:ident: $($name:ident),+ $(,)?) => {
        $crate::pipeline::exec::stage_indices!(@next 0usize; $($name),+);
        const _: () = assert!([$(stringify!($name)),+].len() == $stages.len());
    };
    (@next $k:expr; $name:ident $(, $rest:ident)*) => {
        const $name: usize = $k;
        $crate::pipeline::exec::stage_indices!(@next $k + 1; $($rest),*);
    };
    (@next $k:expr;) => {};
}
pub(crate) use stage_indices;

/// CPU time per stage of a fused pass, added up over the threads that ran its bands: a
/// band times each of its stages with [`StageClock::time`], and the record then shares the
/// pass's wall time among the stages in proportion ([`super::Recorder::fused`]).
#[derive(Debug)]
pub struct StageClock<const N: usize> {
    nanos: [std::sync::atomic::AtomicU64; N],
}

impl<const N: usize> Default for StageClock<N> {
    fn default() -> Self {
        StageClock {
            nanos: std::array::from_fn(|_| std::sync::atomic::AtomicU64::new(0)),
        }
    }
}

impl<const N: usize> StageClock<N> {
    /// Runs `f` as part of stage `k` and adds its time.
    #[inline]
    pub fn time<T>(&self, k: usize, f: impl FnOnce() -> T) -> T {
        let t = std::time::Instant::now();
        let out = f();
        self.nanos[k].fetch_add(
            t.elapsed().as_nanos() as u64,
            std::sync::atomic::Ordering::Relaxed,
        );
        out
    }

    /// Each stage's share of the time measured, summing to 1 (equal shares when nothing
    /// was measured).
    pub fn shares(&self) -> [f64; N] {
        let ns = self
            .nanos
            .each_ref()
            .map(|a| a.load(std::sync::atomic::Ordering::Relaxed) as f64);
        let total: f64 = ns.iter().sum();
        if total > 0.0 {
            ns.map(|v| v / total)
        } else {
            [1.0 / N as f64; N]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bands_cover_every_row_once_with_their_scratch() {
        for (w, h) in [(1, 1), (3, 7), (5, BAND_ROWS), (4, 3 * BAND_ROWS + 1)] {
            let mut a = vec![0.0f32; w * h];
            let rows: usize = par_bands([&mut a], w, h, |s: &mut Vec<usize>, rows, [band]| {
                assert_eq!(band.len(), rows.len() * w);
                s.push(rows.start);
                for (k, y) in rows.clone().enumerate() {
                    for x in 0..w {
                        band[k * w + x] += (y * w + x) as f32 + 1.0;
                    }
                }
                rows.len()
            });
            assert_eq!(rows, h);
            for (i, v) in a.iter().enumerate() {
                assert_eq!(*v, i as f32 + 1.0, "{w}x{h} sample {i}");
            }
        }
        let clock = StageClock::<2>::default();
        clock.time(1, || std::thread::sleep(std::time::Duration::from_millis(2)));
        let s = clock.shares();
        assert!(s[1] > 0.99 && (s[0] + s[1] - 1.0).abs() < 1e-9, "{s:?}");
    }

    #[test]
    fn rows_cover_every_sample_once() {
        let (w, h) = (5, 4);
        let mut a = vec![0.0f32; w * h];
        let mut b = vec![0.0f32; w * h];
        let n: usize = par_rows([&mut a, &mut b], w, |y, [ra, rb]| {
            for (x, (va, vb)) in ra.iter_mut().zip(rb.iter_mut()).enumerate() {
                *va = (y * w + x) as f32;
                *vb += 1.0;
            }
            ra.len()
        });
        assert_eq!(n, w * h);
        assert!(a.iter().enumerate().all(|(i, &v)| v == i as f32));
        assert!(b.iter().all(|&v| v == 1.0));
    }
}
