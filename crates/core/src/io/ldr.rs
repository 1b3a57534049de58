//! PNG and JPEG: sRGB-encoded LDR input and previews, through the `image` crate.

use super::{IoError, OutputFormat};
use crate::frame::{Frame, Plane, Rgb};
use std::path::Path;

/// The sRGB electro-optical transfer function (IEC 61966-2-1): encoded value in [0, 1]
/// to linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// The inverse of [`srgb_to_linear`], for linear values in [0, 1].
pub fn linear_to_srgb(v: f32) -> f32 {
    if v <= 0.003_130_8 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    }
}

fn image_error(path: &Path, format: &'static str, e: image::ImageError) -> IoError {
    match e {
        image::ImageError::IoError(source) => IoError::os(path, source),
        other => IoError::Format {
            path: path.to_path_buf(),
            format,
            reason: other.to_string(),
        },
    }
}

/// Reads a PNG or JPEG (8 or 16 bits, grey or colour, alpha ignored) as a colour-only
/// frame, decoding sRGB to linear.
pub fn read_ldr(path: &Path) -> Result<Frame, IoError> {
    let img = image::open(path).map_err(|e| image_error(path, "PNG/JPEG", e))?;
    let rgb = img.to_rgb32f();
    let (w, h) = (rgb.width() as usize, rgb.height() as usize);
    let mut planes: Rgb = [Plane::new(w, h), Plane::new(w, h), Plane::new(w, h)];
    for (i, px) in rgb.pixels().enumerate() {
        for (plane, &v) in planes.iter_mut().zip(&px.0) {
            plane.data_mut()[i] = srgb_to_linear(v);
        }
    }
    Frame::new(planes).map_err(|source| IoError::Frame {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes interleaved 8-bit sRGB pixels (`w * h * 3` bytes) as PNG, creating the
/// directory.
pub fn write_png_rgb8(path: &Path, width: usize, height: usize, pixels: Vec<u8>) -> Result<(), IoError> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|e| IoError::os(dir, e))?;
    }
    let buf = image::RgbImage::from_raw(width as u32, height as u32, pixels).ok_or_else(|| {
        IoError::Argument(format!(
            "{}: pixel buffer does not match {width}x{height}",
            path.display()
        ))
    })?;
    buf.save_with_format(path, image::ImageFormat::Png)
        .map_err(|e| image_error(path, "PNG", e))
}

/// Linear RGB as interleaved 8-bit sRGB (`w * h * 3` bytes), the way previews show it.
/// With `tonemap`, HDR values are first mapped by `c / (1 + c)` (the reversible tonemap
/// also used by the metrics); without it they are clamped to [0, 1]. Non-finite samples
/// become magenta so they show.
pub fn rgb_to_srgb8(rgb: &Rgb, tonemap: bool) -> Vec<u8> {
    let (w, h) = rgb[0].size();
    let mut bytes = Vec::with_capacity(w * h * 3);
    for i in 0..w * h {
        let px = [rgb[0].data()[i], rgb[1].data()[i], rgb[2].data()[i]];
        if px.iter().any(|v| !v.is_finite()) {
            bytes.extend_from_slice(&[255, 0, 255]);
            continue;
        }
        for v in px {
            let v = v.max(0.0);
            let v = if tonemap { v / (1.0 + v) } else { v.min(1.0) };
            bytes.push((linear_to_srgb(v) * 255.0 + 0.5) as u8);
        }
    }
    bytes
}

/// Linear RGB as an 8-bit sRGB PNG or JPEG (quality 95) in memory, clamped to [0, 1] (see
/// [`rgb_to_srgb8`]); `label` names it in errors. [`OutputFormat::Exr`] is not an 8-bit
/// format and is refused.
pub fn encode_ldr(rgb: &Rgb, format: OutputFormat, label: &Path) -> Result<Vec<u8>, IoError> {
    let (w, h) = rgb[0].size();
    let buf = image::RgbImage::from_raw(w as u32, h as u32, rgb_to_srgb8(rgb, false))
        .expect("rgb_to_srgb8 gives 3 bytes a pixel");
    let mut out = std::io::Cursor::new(Vec::new());
    let written = match format {
        OutputFormat::Png => buf.write_to(&mut out, image::ImageFormat::Png),
        OutputFormat::Jpeg => {
            buf.write_with_encoder(image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 95))
        }
        OutputFormat::Exr => {
            return Err(IoError::Argument(format!(
                "{}: EXR is not an 8-bit format",
                label.display()
            )))
        }
    };
    written.map_err(|e| image_error(label, "PNG/JPEG", e))?;
    Ok(out.into_inner())
}

/// Writes linear RGB as an 8-bit sRGB PNG preview (see [`rgb_to_srgb8`]).
pub fn write_png(path: &Path, rgb: &Rgb, tonemap: bool) -> Result<(), IoError> {
    let (w, h) = rgb[0].size();
    write_png_rgb8(path, w, h, rgb_to_srgb8(rgb, tonemap))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn srgb_round_trip_and_known_values() {
        let t = Tolerance::abs(1e-6);
        t.check("mid grey", srgb_to_linear(0.5) as f64, 0.214_041_14)
            .unwrap();
        for i in 0..=255 {
            let v = i as f32 / 255.0;
            t.check("round trip", linear_to_srgb(srgb_to_linear(v)) as f64, v as f64)
                .unwrap();
        }
    }
}
