//! The report as text: a markdown table for people, a CSV for spreadsheets.

use super::{Cell, Cost, FilterSummary, Report, SceneReport, TimingRow, TimingSize};
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

/// Quotes a CSV field when it holds a comma, quote or newline.
fn field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

const CSV_HEADER: &str = "section,scene,filter,width,height,frames,mean_psnr,mean_ssim,trmse,ms_median,ms_p95,bytes_per_frame,floor_ms,floor_ratio,state_bytes_per_megapixel,stages";

/// The report as CSV: one row per filter and scene (`section` = `scene`), one per filter
/// over all scenes (`summary`, scene `all`), and one per filter in the timing section
/// (`timing`, scene `synthetic`). Empty cells where a figure does not apply.
pub fn csv(r: &Report) -> String {
    let s = &r.config.render;
    let mut o = String::from(CSV_HEADER);
    o.push('\n');
    let cell_row = |o: &mut String, scene: &str, c: &Cell| {
        let _ = writeln!(
            o,
            "scene,{},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            field(scene),
            field(&c.filter),
            s.width,
            s.height,
            s.frames,
            c.mean_psnr,
            c.mean_ssim,
            c.trmse.map_or(String::new(), |t| t.to_string()),
            c.cost.time.median_ms,
            c.cost.time.p95_ms,
            c.cost.bytes_per_frame,
            c.cost.floor_ms,
            c.cost.floor_ratio,
            c.cost.state_bytes_per_megapixel,
            field(&stages_csv(&c.cost.stages))
        );
    };
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
                cell_row(&mut o, &sc.scene, c);
            }
        }
        for f in summary {
            let _ = writeln!(
                o,
                "summary,{all},{},{},{},{},{},{},{},{},{},,,{},{},",
                field(&f.filter),
                s.width,
                s.height,
                s.frames,
                f.mean_psnr,
                f.mean_ssim,
                f.mean_trmse.map_or(String::new(), |t| t.to_string()),
                f.time.median_ms,
                f.time.p95_ms,
                f.floor_ratio,
                f.state_bytes_per_megapixel
            );
        }
        if let Some(t) = r.config.timing {
            for row in timing {
                let c = &row.cost;
                let _ = writeln!(
                    o,
                    "timing,{synthetic},{},{},{},{},,,,{},{},{},{},{},{},{}",
                    field(&row.filter),
                    t.width,
                    t.height,
                    t.frames,
                    c.time.median_ms,
                    c.time.p95_ms,
                    c.bytes_per_frame,
                    c.floor_ms,
                    c.floor_ratio,
                    c.state_bytes_per_megapixel,
                    field(&stages_csv(&c.stages))
                );
            }
        }
    }
    o
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

    #[test]
    fn csv_fields_are_quoted_only_when_needed() {
        assert_eq!(field("taa"), "taa");
        assert_eq!(field("a,b"), "\"a,b\"");
        assert_eq!(field("say \"x\""), "\"say \"\"x\"\"\"");
        assert_eq!(CSV_HEADER.split(',').count(), 16);
    }
}
