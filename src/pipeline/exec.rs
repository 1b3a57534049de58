//! Execution on the crate's own rayon pool, split by rows.

use rayon::prelude::*;
use std::ops::AddAssign;
use std::sync::OnceLock;

/// Environment variable that sets the number of filter threads (default: all cores).
pub const THREADS_ENV: &str = "AFTERIMAGE_THREADS";

/// The crate's rayon pool: every filter runs its rows here, never on the caller's threads
/// (an async server's workers stay free). Sized by `AFTERIMAGE_THREADS`, else one thread
/// per core.
pub fn pool() -> &'static rayon::ThreadPool {
    static POOL: OnceLock<rayon::ThreadPool> = OnceLock::new();
    POOL.get_or_init(|| {
        let threads = std::env::var(THREADS_ENV)
            .ok()
            .and_then(|v| v.parse::<usize>().ok())
            .filter(|&n| n > 0)
            .unwrap_or(0);
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

#[cfg(test)]
mod tests {
    use super::*;

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
