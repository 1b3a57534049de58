//! Ablation tables for `phlm` against `taa` on the scene catalogue (issue 21): renders each
//! scene once, runs every configuration on it and prints per-scene PSNR, tRMSE and the
//! PSNR difference to the first configuration, then the means.
//!
//! ```sh
//! cargo run --release --example phlm_ablate -- "taa;phlm;phlm model_fetch=nearest"
//! AFTERIMAGE_SCENES=noisy cargo run --release --example phlm_ablate -- "taa;phlm"
//! AFTERIMAGE_JITTER=none cargo run --release --example phlm_ablate -- "taa;phlm"
//! ```
//!
//! Settings as `tests/filters_scenes.rs`: 128x72, 32 frames, 8x8 reference samples, 8-phase
//! Halton jitter (`AFTERIMAGE_JITTER=none` for pixel centres). `AFTERIMAGE_SCENES`:
//! `catalogue` (default: the ten scenes of the catalogue, in its order), `noisy` (the four
//! scenes of issue 21 with `--noise`), or a comma-separated list (`name` or `name+noise`).
//! `AFTERIMAGE_NOISE_SIGMA=s` multiplies each input pixel's colour by `1 + s n` (n uniform,
//! unit variance, a new draw per pixel and frame) and leaves the reference clean: not a
//! rendering model but a probe of how well each filter averages strong per-pixel noise
//! (docs/phlm-ablations.md, table 11). `AFTERIMAGE_PER_FRAME=1` also prints each run's
//! per-frame PSNR (on standard error), to see where a filter converges or lags.
//! `AFTERIMAGE_SIZE=report` renders at the report's default size instead (256x144, 16x16
//! reference samples).

use afterimage::filters::create;
use afterimage::frame::Frame;
use afterimage::metrics::{Evaluator, SpaceChoice, Summary};
use afterimage::pipeline::params::parse_assignments;
use afterimage::scene::{Jitter, Scene, Settings, CATALOGUE};

const NOISY: [&str; 4] = [
    "static+noise",
    "dynamic-light+noise",
    "foliage+noise",
    "moving-sphere+noise",
];

fn render(spec: &str, jitter: Jitter) -> Vec<Frame> {
    let (name, noise) = match spec.strip_suffix("+noise") {
        Some(n) => (n, true),
        None => (spec, false),
    };
    let mut s = Settings {
        width: 128,
        height: 72,
        frames: 32,
        spp: 64,
        jitter,
        noise,
        seed: 1,
        shading: 1,
    };
    if std::env::var("AFTERIMAGE_SIZE").as_deref() == Ok("report") {
        // The report's default run: 256x144 with 16x16 reference samples.
        let d = Settings::default();
        (s.width, s.height, s.spp) = (d.width, d.height, d.spp);
    }
    let scene = Scene::new(name, s).expect("a catalogue scene");
    let sigma: f64 = std::env::var("AFTERIMAGE_NOISE_SIGMA").map_or(0.0, |v| {
        v.parse()
            .ok()
            .filter(|s: &f64| *s >= 0.0)
            .unwrap_or_else(|| panic!("AFTERIMAGE_NOISE_SIGMA={v:?}: expected a number >= 0"))
    });
    (0..s.frames)
        .map(|i| {
            let mut f = scene.frame(i);
            if sigma > 0.0 {
                // Each pixel's colour times `1 + sigma n`, n uniform with unit variance
                // (floored at 0), one draw per pixel and frame; the reference stays clean.
                let mut rng = afterimage::rng::SplitMix64::new(1000 + i);
                let [r, g, b] = f.color_mut();
                for k in 0..r.len() {
                    let n = (rng.next_f64() * 2.0 - 1.0) * 3f64.sqrt();
                    let m = (1.0 + sigma * n).max(0.0) as f32;
                    r[k] *= m;
                    g[k] *= m;
                    b[k] *= m;
                }
            }
            f
        })
        .collect()
}

/// The metrics and the mean fraction of pixels whose history was clipped per frame.
fn run(config: &[&str], frames: &[Frame]) -> (Summary, f64) {
    let mut f = create(config[0], &parse_assignments(&config[1..]).expect("key=value")).expect("a filter");
    let mut eval = Evaluator::new(SpaceChoice::Auto);
    let mut clipped = 0.0;
    for fr in frames {
        let out = f.process(fr).expect("a frame");
        let n = (out.color[0].width() * out.color[0].height()) as f64;
        clipped += out.record.pixels.history_clipped as f64 / n;
        eval.push(
            fr.meta.index,
            &out.color,
            fr.reference().expect("a reference"),
            fr.meta.reset,
        )
        .expect("metrics");
    }
    if std::env::var("AFTERIMAGE_PER_FRAME").is_ok() {
        let psnr: Vec<String> = eval.frames.iter().map(|m| format!("{:.1}", m.psnr)).collect();
        eprintln!("{}: {}", config.join(" "), psnr.join(" "));
    }
    (eval.summary().expect("frames"), clipped / frames.len() as f64)
}

fn main() {
    let arg = std::env::args().nth(1).unwrap_or_else(|| "taa;phlm".into());
    let configs: Vec<Vec<&str>> = arg.split(';').map(|c| c.split_whitespace().collect()).collect();
    let jitter = match std::env::var("AFTERIMAGE_JITTER").as_deref() {
        Ok("none") => Jitter::None,
        _ => Jitter::Halton(8),
    };
    let which = std::env::var("AFTERIMAGE_SCENES").unwrap_or_else(|_| "catalogue".into());
    let scenes: Vec<String> = match which.as_str() {
        "catalogue" => CATALOGUE.iter().map(|e| e.name.to_string()).collect(),
        "noisy" => NOISY.iter().map(|s| s.to_string()).collect(),
        list => list.split(',').map(str::to_string).collect(),
    };
    let names: Vec<String> = configs.iter().map(|c| c.join(" ")).collect();
    let mut totals = vec![(0.0, 0.0); configs.len()];
    let mut worst = vec![f64::INFINITY; configs.len()];
    println!("jitter {jitter:?}; delta = PSNR minus `{}`\n", names[0]);
    println!("| scene | config | PSNR dB | tRMSE | delta dB | clipped % |\n|---|---|---|---|---|---|");
    for scene in &scenes {
        let frames = render(scene, jitter);
        let mut base = f64::NAN;
        for (k, c) in configs.iter().enumerate() {
            let (s, clipped) = run(c, &frames);
            let t = s.trmse.unwrap_or(f64::NAN);
            if k == 0 {
                base = s.mean_psnr;
            }
            let d = s.mean_psnr - base;
            println!(
                "| {scene} | {} | {:.2} | {:.4} | {:+.2} | {:.1} |",
                names[k],
                s.mean_psnr,
                t,
                d,
                100.0 * clipped
            );
            totals[k].0 += s.mean_psnr;
            totals[k].1 += t;
            worst[k] = worst[k].min(d);
        }
    }
    let n = scenes.len() as f64;
    println!(
        "\n| mean over {} scenes | PSNR dB | tRMSE | delta dB | worst scene delta |\n|---|---|---|---|---|",
        scenes.len()
    );
    for (k, name) in names.iter().enumerate() {
        println!(
            "| {name} | {:.2} | {:.4} | {:+.2} | {:+.2} |",
            totals[k].0 / n,
            totals[k].1 / n,
            (totals[k].0 - totals[0].0) / n,
            worst[k]
        );
    }
}
