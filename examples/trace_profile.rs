//! Runs `pixel_trace` on the bench's synthetic G-buffer (frames 0 and 1 alternating, as
//! `benches/filters.rs` does) for profiling: `trace_profile WIDTH HEIGHT WINDOW OUTPUTS`.
//! With `AFTERIMAGE_THREADS=1` under `valgrind --tool=callgrind` the instruction counts
//! are repeatable on a loaded machine.
use afterimage::filters::create;
use afterimage::report::synthetic_frame;

fn main() {
    let args: Vec<usize> = std::env::args()
        .skip(1)
        .map(|a| a.parse().expect("a number"))
        .collect();
    let [w, h, window, outputs] = args[..] else {
        panic!("usage: trace_profile WIDTH HEIGHT WINDOW OUTPUTS");
    };
    let frames = [synthetic_frame(w, h, 0), synthetic_frame(w, h, 1)];
    let mut params = serde_json::Map::new();
    params.insert("window".into(), window.into());
    let mut f = create("pixel_trace", &params).unwrap();
    // The window full: every output after this reads T + 1 frames.
    for i in 0..=2 * f.lookahead() {
        f.push(&frames[i % 2]).unwrap();
    }
    let mut sum = 0.0f64;
    let t = std::time::Instant::now();
    for i in 0..outputs {
        for o in f.push(&frames[(i + 1 + 2 * f.lookahead()) % 2]).unwrap() {
            sum += o.color[0].data().iter().map(|&v| v as f64).sum::<f64>();
            if i + 1 == outputs {
                for st in &o.record.stages {
                    println!("  {:<16} {:?} ms", st.name, st.ms);
                }
            }
            f.recycle(o.color);
        }
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "{w}x{h} T={window}: {:.3} s/frame (checksum {sum:.6})",
        s / outputs.max(1) as f64
    );
}
