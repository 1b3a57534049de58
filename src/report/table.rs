//! The report as text: a markdown table for people, a CSV for spreadsheets.

use super::{Cost, FilterSummary, Report, SceneReport, TimingRow, TimingSize};
use crate::pipeline::StageSummary;
use std::fmt::Write;

const MB: f64 = 1e6;

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// `name median` for a stage that ran every frame, `name median (ran k/n)` for one left
/// out on some, `name -` for one never run.
fn stages_text(stages: &[StageSummary]) -> String {
    stages
        .iter()
        .map(|s| match s.timing {
            None => format!("{} -", s.name),
            Some(t) if s.left_out == 0 => format!("{} {:.3}", s.name, t.median_ms),
            Some(t) => format!(
                "{} {:.3} (ran {}/{})",
                s.name,
                t.median_ms,
                s.ran,
                s.ran + s.left_out
            ),
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// `name=median/p95` per stage (`name=left_out` for one never run), `;`-separated.
fn stages_csv(stages: &[StageSummary]) -> String {
    stages
        .iter()
        .map(|s| match s.timing {
            None => format!("{}=left_out", s.name),
            Some(t) => format!("{}={:.4}/{:.4}", s.name, t.median_ms, t.p95_ms),
        })
        .collect::<Vec<_>>()
        .join(";")
}

fn cost_cells(c: &Cost) -> String {
    format!(
        "{:.3} | {:.3} | {:.1} | {:.3} | {:.1} | {:.1}",
        c.time.median_ms,
        c.time.p95_ms,
        c.bytes_per_frame as f64 / MB,
        c.floor_ms,
        c.floor_ratio,
        c.state_bytes_per_megapixel / MB
    )
}

/// The report as markdown: the settings, the all-scenes summary, the full-size timing,
/// then one block per scene.
pub fn markdown(r: &Report) -> String {
    let c = &r.config;
    let s = &c.render;
    let mut o = String::new();
    let _ = writeln!(o, "# afterimage report\n");
    if !c.scenes.is_empty() {
        let _ =
            write!(
            o,
            "{} scenes at {}x{}, {} frames each, {} reference samples per pixel, jitter {:?}, {}seed {}. ",
            c.scenes.len(),
            s.width,
            s.height,
            s.frames,
            s.spp,
            s.jitter,
            if s.noise { "noisy input (one-sample soft shadows), " } else { "" },
            s.seed,
        );
    }
    let _ = writeln!(
        o,
        "Copy bandwidth {:.1} GB/s ({} threads, {} MiB buffers, median of {}). \
         ms/frame is the wall time of filtering one frame (one `push`; a windowed filter's gives the \
         frame T/2 back); the floor is the bytes a filter must move per frame over that bandwidth. PSNR and SSIM are means over frames against the \
         reference; tRMSE charges flicker and lag.\n",
        r.bandwidth.bytes_per_s / 1e9,
        r.bandwidth.threads,
        r.bandwidth.copy_bytes >> 20,
        r.bandwidth.copy.count
    );
    if !c.shots.is_empty() {
        let _ = writeln!(
            o,
            "{} shots read from disk, each at its own size and length against its own reference: {}.\n",
            c.shots.len(),
            c.shots
                .iter()
                .map(|s| format!("`{}` ({} against {})", s.name, s.input, s.reference))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    let _ = writeln!(o, "## All scenes (mean over {} scenes)\n", r.scenes.len());
    summary_table(&mut o, &r.summary);
    if let Some(t) = c.timing {
        timing_table(&mut o, &r.timing, t, "synthetic G-buffer with every channel");
    }
    scene_blocks(&mut o, &r.scenes);
    if let Some(u) = &r.upsampling {
        let _ = writeln!(
            o,
            "\n# Upsampling: one pixel of every {f}x{f} block shaded (Herzog et al. 2010)\n\n\
             The scenes rendered with sparse shading in the rotating order, no jitter, G-buffer and reference at full \
             resolution; `upsample` and its baselines reconstruct full resolution. The input row of each strip shows each \
             pixel its block's sample.\n",
            f = u.factor
        );
        let _ = writeln!(o, "## All scenes (mean over {} scenes)\n", u.scenes.len());
        summary_table(&mut o, &u.summary);
        if let Some(t) = c.timing {
            timing_table(
                &mut o,
                &u.timing,
                t,
                &format!(
                    "synthetic G-buffer, colour shaded at one pixel per {0}x{0} block",
                    u.factor
                ),
            );
        }
        scene_blocks(&mut o, &u.scenes);
    }
    o
}

fn summary_table(o: &mut String, summary: &[FilterSummary]) {
    let _ = writeln!(
        o,
        "| filter | PSNR dB | SSIM | tRMSE | ms/frame median | p95 | x floor | state MB/MP |"
    );
    let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---:|");
    for f in summary {
        let _ = writeln!(
            o,
            "| {} | {:.2} | {:.4} | {} | {:.3} | {:.3} | {:.1} | {:.1} |",
            f.filter,
            f.mean_psnr,
            f.mean_ssim,
            opt(f.mean_trmse, 4),
            f.time.median_ms,
            f.time.p95_ms,
            f.floor_ratio,
            f.state_bytes_per_megapixel / MB
        );
    }
}

fn timing_table(o: &mut String, rows: &[TimingRow], t: TimingSize, what: &str) {
    if rows.is_empty() {
        return;
    }
    let _ = writeln!(
        o,
        "\n## Timing at {}x{} ({what}, {} frames after one untimed)\n",
        t.width, t.height, t.frames
    );
    let _ = writeln!(
        o,
        "| filter | backend | ms/frame median | p95 | MB moved/frame | floor ms | x floor | state MB/MP | frames/s | stages (median ms) |"
    );
    let _ = writeln!(o, "|---|---|---:|---:|---:|---:|---:|---:|---:|---|");
    for row in rows {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {:.1} | {} |",
            row.filter,
            backend_label(row.backend, row.upload),
            cost_cells(&row.cost),
            1e3 / row.cost.time.median_ms,
            stages_text(&row.cost.stages)
        );
    }
}

fn scene_blocks(o: &mut String, scenes: &[SceneReport]) {
    for sc in scenes {
        let _ = writeln!(
            o,
            "\n## {} ({:?} space, render {:.0} ms/frame)\n\n{}\n",
            sc.scene, sc.space, sc.render.median_ms, sc.description
        );
        let _ = writeln!(
            o,
            "| filter | PSNR dB | SSIM | tRMSE | ms/frame median | p95 | MB moved/frame | floor ms | x floor | state MB/MP | stages (median ms) |"
        );
        let _ = writeln!(o, "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|");
        for cell in &sc.cells {
            let _ = writeln!(
                o,
                "| {} | {:.2} | {:.4} | {} | {} | {} |",
                cell.filter,
                cell.mean_psnr,
                cell.mean_ssim,
                opt(cell.trmse, 4),
                cost_cells(&cell.cost),
                stages_text(&cell.cost.stages)
            );
        }
    }
}

const CSV_HEADER: [&str; 16] = [
    "section",
    "scene",
    "filter",
    "width",
    "height",
    "frames",
    "mean_psnr",
    "mean_ssim",
    "trmse",
    "ms_median",
    "ms_p95",
    "bytes_per_frame",
    "floor_ms",
    "floor_ratio",
    "state_bytes_per_megapixel",
    "stages",
];

/// The report as CSV: one row per filter and scene (`section` = `scene`), one per filter
/// over all scenes (`summary`, scene `all`), and one per filter in the timing section
/// (`timing`, scene `synthetic`). Empty cells where a figure does not apply. Written by the
/// `csv` crate, so a scene or filter name with a comma, quote or line break is quoted and
/// reads back as it was.
pub fn csv(r: &Report) -> String {
    let s = &r.config.render;
    let mut w = csv::Writer::from_writer(Vec::new());
    let mut row = |cells: &[String]| {
        w.write_record(cells)
            .expect("a CSV record of text into memory cannot fail")
    };
    row(&CSV_HEADER.map(String::from));
    let text = |v: &dyn std::fmt::Display| v.to_string();
    let some = |v: Option<f64>| v.map_or(String::new(), |t| t.to_string());
    let (width, height, frames) = (text(&s.width), text(&s.height), text(&s.frames));
    let sections = std::iter::once((&r.scenes, &r.summary, &r.timing, "all", "synthetic".to_string())).chain(
        r.upsampling.iter().map(|u| {
            (
                &u.scenes,
                &u.summary,
                &u.timing,
                "upsampling",
                format!("synthetic-shading-{0}x{0}", u.factor),
            )
        }),
    );
    for (scenes, summary, timing, all, synthetic) in sections {
        for sc in scenes {
            for c in &sc.cells {
                row(&[
                    "scene".into(),
                    sc.scene.clone(),
                    c.filter.clone(),
                    width.clone(),
                    height.clone(),
                    frames.clone(),
                    text(&c.mean_psnr),
                    text(&c.mean_ssim),
                    some(c.trmse),
                    text(&c.cost.time.median_ms),
                    text(&c.cost.time.p95_ms),
                    text(&c.cost.bytes_per_frame),
                    text(&c.cost.floor_ms),
                    text(&c.cost.floor_ratio),
                    text(&c.cost.state_bytes_per_megapixel),
                    stages_csv(&c.cost.stages),
                ]);
            }
        }
        for f in summary {
            row(&[
                "summary".into(),
                all.into(),
                f.filter.clone(),
                width.clone(),
                height.clone(),
                frames.clone(),
                text(&f.mean_psnr),
                text(&f.mean_ssim),
                some(f.mean_trmse),
                text(&f.time.median_ms),
                text(&f.time.p95_ms),
                String::new(),
                String::new(),
                text(&f.floor_ratio),
                text(&f.state_bytes_per_megapixel),
                String::new(),
            ]);
        }
        if let Some(t) = r.config.timing {
            for timing_row in timing {
                let c = &timing_row.cost;
                row(&[
                    "timing".into(),
                    synthetic.clone(),
                    timing_row.filter.clone(),
                    text(&t.width),
                    text(&t.height),
                    text(&t.frames),
                    String::new(),
                    String::new(),
                    String::new(),
                    text(&c.time.median_ms),
                    text(&c.time.p95_ms),
                    text(&c.bytes_per_frame),
                    text(&c.floor_ms),
                    text(&c.floor_ratio),
                    text(&c.state_bytes_per_megapixel),
                    stages_csv(&c.stages),
                ]);
            }
        }
    }
    let bytes = w.into_inner().expect("a flush into memory cannot fail");
    String::from_utf8(bytes).expect("every field is text")
}

/// The timing table's backend cell: `cpu`, `gpu`, or `gpu-f16` where the colour went up as
/// f16.
fn backend_label(
    backend: crate::backend::Backend,
    upload: Option<crate::backend::UploadPrecision>,
) -> String {
    match upload {
        Some(crate::backend::UploadPrecision::F16) => format!("{backend}-f16"),
        _ => backend.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_backend_cell_says_an_f16_upload() {
        use crate::backend::{Backend, UploadPrecision};
        assert_eq!(backend_label(Backend::Cpu, None), "cpu");
        assert_eq!(backend_label(Backend::Gpu, Some(UploadPrecision::F32)), "gpu");
        assert_eq!(backend_label(Backend::Gpu, Some(UploadPrecision::F16)), "gpu-f16");
    }

    /// A scene (a shot's `--input NAME=DIR`) or filter label holding a comma, quotes, or
    /// spaces at its ends reads back from the CSV as it was, in its column; the other
    /// cells stay plain. (The hand-written writer before it quoted, but nothing read its
    /// output back.)
    #[test]
    fn csv_rows_read_back_as_written() {
        use super::super::{Bandwidth, Cell, Config};
        use crate::metrics::{MetricSpace, Timing};
        let time = Timing {
            median_ms: 1.5,
            p95_ms: 2.5,
            count: 3,
        };
        let cost = Cost {
            time,
            stages: vec![],
            state_bytes_per_megapixel: 16e6,
            bytes_per_frame: 1000,
            floor_ms: 0.25,
            floor_ratio: 6.0,
        };
        let scene = "sh010, \"hero\" take 2 ";
        let filter = "taa:alpha=0.2,clip=false";
        let report = Report {
            config: Config::quick(),
            bandwidth: Bandwidth {
                bytes_per_s: 1e10,
                copy_bytes: 1,
                copy: time,
                threads: 1,
            },
            scenes: vec![SceneReport {
                scene: scene.into(),
                description: String::new(),
                space: MetricSpace::Linear,
                render: time,
                cells: vec![Cell {
                    filter: filter.into(),
                    mean_psnr: 40.25,
                    mean_ssim: 0.5,
                    trmse: None,
                    cost,
                    psnr_per_frame: vec![],
                }],
            }],
            summary: vec![],
            timing: vec![],
            upsampling: None,
            strips: vec![],
        };
        let text = csv(&report);
        let mut rows = ::csv::Reader::from_reader(text.as_bytes());
        assert_eq!(rows.headers().unwrap(), CSV_HEADER.as_slice());
        let rows: Vec<::csv::StringRecord> = rows.records().map(Result::unwrap).collect();
        assert_eq!(rows.len(), 1, "{text}");
        let cell = |name: &str| &rows[0][CSV_HEADER.iter().position(|h| *h == name).unwrap()];
        assert_eq!(cell("scene"), scene, "{text}");
        assert_eq!(cell("filter"), filter, "{text}");
        assert_eq!(
            (cell("section"), cell("mean_psnr"), cell("trmse")),
            ("scene", "40.25", "")
        );
        assert_eq!(cell("width"), report.config.render.width.to_string());
        // Quoted only where needed: the numbers are plain.
        assert!(text.contains(",40.25,0.5,,1.5,2.5,1000,"), "{text}");
    }
}
