//! Runs one filter over frames of the synthetic G-buffer, for profilers (`perf`, `valgrind
//! --tool=callgrind`), and prints the median time per frame:
//!
//! ```sh
//! cargo run --release --example profile_filter -- taa 1920 1080 20 [key=value ...]
//! AFTERIMAGE_THREADS=1 valgrind --tool=callgrind target/release/examples/profile_filter taa 480 270 4
//! ```
//!
//! Filters of sparse shading get the 2x2 sparse G-buffer.

use afterimage::filters::{create, info};
use afterimage::pipeline::params::parse_assignments;
use afterimage::report::{synthetic_frame, synthetic_sparse_frame};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().map_or("taa", String::as_str);
    let num = |i: usize, d: usize| args.get(i).and_then(|v| v.parse().ok()).unwrap_or(d);
    let (w, h, n) = (num(1, 1920), num(2, 1080), num(3, 20));
    let values = parse_assignments(&args[4.min(args.len())..]).expect("key=value");
    let sparse = info(name).expect("a filter name").sparse_input;
    let frames: Vec<_> = (0..2)
        .map(|i| {
            if sparse {
                synthetic_sparse_frame(w, h, i, 2)
            } else {
                synthetic_frame(w, h, i)
            }
        })
        .collect();
    let mut f = create(name, &values).expect("valid parameters");
    for i in 0..=f.lookahead() {
        f.push(&frames[i % 2]).expect("a frame");
    }
    let mut ms = Vec::new();
    let mut records = Vec::new();
    for i in 0..n {
        let t = Instant::now();
        for o in f.push(&frames[(i + 1) % 2]).expect("a frame") {
            records.push(o.record);
            f.recycle(o.color);
        }
        ms.push(t.elapsed().as_secs_f64() * 1e3);
    }
    ms.sort_by(f64::total_cmp);
    println!("{name} {w}x{h}: median {:.2} ms/frame over {n} frames", ms[n / 2]);
    for s in afterimage::pipeline::summarize_stages(&records) {
        match s.timing {
            Some(t) => println!("  {:<14} median {:.3} ms", s.name, t.median_ms),
            None => println!("  {:<14} left out", s.name),
        }
    }
}
