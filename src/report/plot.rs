//! The report as pictures (plotters, PNG and SVG): error against ms/frame with one marker
//! per filter, per-frame PSNR curves per scene (as in the PHLM paper's figures 3 and 4),
//! and per scene an image strip of one frame: input, each filter, reference, error maps.

use super::{Report, ReportError, Strip};
use crate::io::{inferno, rgb_to_srgb8, write_png_rgb8};
use crate::metrics::{luma, quantile, MetricSpace};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// Font family every label uses; DejaVu Sans is embedded (the `dejavu` crate), so plots
/// need no system fonts.
const FONT: &str = "sans-serif";

/// Distinct colours for up to ten filters (Tableau 10), then they repeat.
const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

fn register_font() -> Result<(), String> {
    static DONE: OnceLock<bool> = OnceLock::new();
    let ok = *DONE.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    ok.then_some(())
        .ok_or_else(|| "the embedded font does not parse".into())
}

/// Low and high ends of `values` (finite ones), widened by `pad` of their span, or
/// `fallback` when none is finite.
fn range(values: impl Iterator<Item = f64>, pad: f64, fallback: (f64, f64)) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return fallback;
    }
    let span = (hi - lo).max(1e-9 + hi.abs() * 1e-3);
    (lo - pad * span, hi + pad * span)
}

/// ms/frame each filter is plotted at: the full-size timing when it ran, else the
/// scenes' median.
fn times(r: &Report) -> (Vec<f64>, String) {
    match (r.config.timing, r.timing.len() == r.summary.len()) {
        (Some(t), true) => (
            r.timing.iter().map(|t| t.cost.time.median_ms).collect(),
            format!("ms/frame at {}x{} (log)", t.width, t.height),
        ),
        _ => (
            r.summary.iter().map(|s| s.time.median_ms).collect(),
            format!(
                "ms/frame at {}x{} (log)",
                r.config.render.width, r.config.render.height
            ),
        ),
    }
}

fn err<E: std::fmt::Display>(e: E) -> String {
    e.to_string()
}

fn draw_error_vs_time<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, r: &Report) -> Result<(), String> {
    root.fill(&WHITE).map_err(err)?;
    let (ms, x_desc) = times(r);
    let (lo, hi) = range(ms.iter().copied(), 0.0, (0.1, 10.0));
    let (x_lo, x_hi) = (lo.max(1e-4) / 2.0, hi.max(1e-4) * 2.5);
    let panels = root.split_evenly((1, 2));
    type Figure = fn(&super::FilterSummary) -> Option<f64>;
    let figures: [(&str, &str, Figure); 2] = [
        ("Mean PSNR over scenes (higher is better)", "PSNR dB", |s| {
            Some(s.mean_psnr)
        }),
        ("Mean tRMSE over scenes (lower is better)", "tRMSE", |s| {
            s.mean_trmse
        }),
    ];
    for (panel, (title, y_desc, get)) in panels.iter().zip(figures) {
        let ys: Vec<Option<f64>> = r.summary.iter().map(get).collect();
        let (y_lo, y_hi) = range(ys.iter().flatten().copied(), 0.15, (0.0, 1.0));
        let mut chart = ChartBuilder::on(panel)
            .caption(title, (FONT, 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d((x_lo..x_hi).log_scale(), y_lo..y_hi)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc(x_desc.as_str())
            .y_desc(y_desc)
            .label_style((FONT, 13))
            .draw()
            .map_err(err)?;
        for (i, (s, y)) in r.summary.iter().zip(&ys).enumerate() {
            let Some(y) = y.filter(|y| y.is_finite()) else {
                continue;
            };
            let c = color(i);
            chart
                .draw_series(std::iter::once(
                    EmptyElement::at((ms[i], y))
                        + Circle::new((0, 0), 6, c.filled())
                        + Text::new(s.filter.clone(), (9, -8), (FONT, 14).into_font().color(&c)),
                ))
                .map_err(err)?;
        }
    }
    root.present().map_err(err)
}

fn draw_psnr_curves<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, r: &Report) -> Result<(), String> {
    root.fill(&WHITE).map_err(err)?;
    let cols = 2;
    let rows = r.scenes.len().div_ceil(cols);
    let panels = root.split_evenly((rows.max(1), cols));
    for (panel, sc) in panels.iter().zip(&r.scenes) {
        let all = sc.cells.iter().flat_map(|c| c.psnr_per_frame.iter().copied());
        let (y_lo, y_hi) = range(all, 0.08, (0.0, 50.0));
        let n = sc.cells.first().map_or(1, |c| c.psnr_per_frame.len());
        let mut chart = ChartBuilder::on(panel)
            .caption(format!("{} ({:?})", sc.scene, sc.space), (FONT, 16))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(45)
            .build_cartesian_2d(0f64..(n.max(2) - 1) as f64, y_lo..y_hi)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("frame")
            .y_desc("PSNR dB")
            .label_style((FONT, 11))
            .draw()
            .map_err(err)?;
        for (i, cell) in sc.cells.iter().enumerate() {
            let c = color(i);
            let points = cell
                .psnr_per_frame
                .iter()
                .enumerate()
                .filter(|(_, p)| p.is_finite())
                .map(|(k, &p)| (k as f64, p));
            chart
                .draw_series(LineSeries::new(points, c.stroke_width(2)))
                .map_err(err)?
                .label(cell.filter.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 11))
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(err)?;
    }
    root.present().map_err(err)
}

/// Draws `draw` into `dir/name.png` and `dir/name.svg`.
macro_rules! png_and_svg {
    ($dir:expr, $name:expr, $size:expr, $draw:ident, $r:expr, $written:expr) => {{
        let (w, h): (u32, u32) = $size;
        let png = $dir.join(format!("{}.png", $name));
        let mut buf = vec![0u8; w as usize * h as usize * 3];
        $draw(
            BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area(),
            $r,
        )
        .map_err(|message| ReportError::Plot {
            path: png.clone(),
            message,
        })?;
        write_png_rgb8(&png, w as usize, h as usize, buf)?;
        $written.push(png);
        let svg = $dir.join(format!("{}.svg", $name));
        $draw(SVGBackend::new(&svg, (w, h)).into_drawing_area(), $r).map_err(|message| {
            ReportError::Plot {
                path: svg.clone(),
                message,
            }
        })?;
        $written.push(svg);
    }};
}

/// Writes `error_vs_time.{png,svg}`, `psnr_per_frame.{png,svg}` and one
/// `strip_<scene>.png` per scene into `dir`; returns the paths written.
pub fn write_plots(r: &Report, dir: &Path) -> Result<Vec<PathBuf>, ReportError> {
    std::fs::create_dir_all(dir).map_err(|e| crate::io::IoError::os(dir, e))?;
    register_font().map_err(|message| ReportError::Plot {
        path: dir.into(),
        message,
    })?;
    let mut written = Vec::new();
    png_and_svg!(dir, "error_vs_time", (1280, 540), draw_error_vs_time, r, written);
    let rows = r.scenes.len().div_ceil(2).max(1) as u32;
    png_and_svg!(
        dir,
        "psnr_per_frame",
        (1280, 280 * rows),
        draw_psnr_curves,
        r,
        written
    );
    for strip in &r.strips {
        let path = dir.join(format!("strip_{}.png", strip.scene));
        let (w, h, buf) = strip_image(strip).map_err(|message| ReportError::Plot {
            path: path.clone(),
            message,
        })?;
        write_png_rgb8(&path, w, h, buf)?;
        written.push(path);
    }
    Ok(written)
}

/// Height of the label band above each panel.
const LABEL_BAND: usize = 22;
/// Panels are magnified (nearest neighbour) to at least this width, so aliasing shows.
const MIN_PANEL_WIDTH: usize = 320;
/// The error maps' full scale is this quantile of the input's error, shared by every map
/// of the strip so they compare.
const ERROR_SCALE_QUANTILE: f64 = 0.99;

/// The strip as interleaved RGB8: top row input, each filter, reference; bottom row the
/// error |luma(x) - luma(reference)| of the input and each filter on one scale (inferno).
fn strip_image(s: &Strip) -> Result<(usize, usize, Vec<u8>), String> {
    let (w, h) = s.input[0].size();
    let zoom = MIN_PANEL_WIDTH.div_ceil(w).max(1);
    let (pw, ph) = (w * zoom, h * zoom);
    let cols = s.outputs.len() + 2;
    let (width, height) = (cols * pw, 2 * (ph + LABEL_BAND));
    let mut buf = vec![24u8; width * height * 3];
    let tonemap = s.space == MetricSpace::Tonemapped;
    let blit = |buf: &mut [u8], col: usize, row: usize, px: &[u8]| {
        let (x0, y0) = (col * pw, row * (ph + LABEL_BAND) + LABEL_BAND);
        for y in 0..ph {
            for x in 0..pw {
                let src = ((y / zoom) * w + x / zoom) * 3;
                let dst = ((y0 + y) * width + x0 + x) * 3;
                buf[dst..dst + 3].copy_from_slice(&px[src..src + 3]);
            }
        }
    };
    let ref_luma = luma(&s.reference, s.space);
    let error = |rgb: &crate::frame::Rgb| -> Vec<f64> {
        luma(rgb, s.space)
            .data()
            .iter()
            .zip(ref_luma.data())
            .map(|(a, b)| (a - b).abs())
            .collect()
    };
    let input_err = error(&s.input);
    let scale = quantile(&input_err, ERROR_SCALE_QUANTILE).max(1e-6);
    let heat = |e: &[f64]| -> Vec<u8> {
        e.iter()
            .flat_map(|&v| inferno(if v.is_finite() { (v / scale) as f32 } else { 1.0 }))
            .collect()
    };
    let mut labels = vec![(0, 0, format!("input, frame {}", s.frame))];
    blit(&mut buf, 0, 0, &rgb_to_srgb8(&s.input, tonemap));
    blit(&mut buf, 0, 1, &heat(&input_err));
    labels.push((0, 1, format!("|error| input, full scale {scale:.3}")));
    for (i, (label, rgb)) in s.outputs.iter().enumerate() {
        blit(&mut buf, i + 1, 0, &rgb_to_srgb8(rgb, tonemap));
        blit(&mut buf, i + 1, 1, &heat(&error(rgb)));
        labels.push((i + 1, 0, label.clone()));
        labels.push((i + 1, 1, format!("|error| {label}")));
    }
    blit(&mut buf, cols - 1, 0, &rgb_to_srgb8(&s.reference, tonemap));
    labels.push((cols - 1, 0, "reference".into()));
    labels.push((cols - 1, 1, format!("{} ({:?})", s.scene, s.space)));
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width as u32, height as u32)).into_drawing_area();
        let style = (FONT, 15).into_font().color(&WHITE);
        for (col, row, text) in labels {
            let pos = ((col * pw + 6) as i32, (row * (ph + LABEL_BAND) + 3) as i32);
            root.draw(&Text::new(text, pos, style.clone())).map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    Ok((width, height, buf))
}
