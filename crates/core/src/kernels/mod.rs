//! Small pure per-pixel building blocks shared by the filters: colour transforms, history
//! resampling, neighbourhood statistics, clipping and edge operators.
//!
//! Each kernel is a plain function on `f32` with a float64 scalar reference in its tests
//! (random and adversarial inputs, compared through [`crate::tolerance::Tolerance`]).
//! Planes are row-major `&[f32]` of a stated width and height; positions are in pixels with
//! pixel `(i, j)` centred at `(i + 0.5, j + 0.5)`, and reads past an edge are clamped to it.

pub mod clip;
pub mod color;
pub mod lanes;
pub mod neighborhood;
pub mod reconstruct;
pub mod sample;
pub mod sharpen;
pub mod sobel;

pub use clip::{clamp_to_box, clip_toward_center, clip_toward_point};
pub use color::{
    luma, luma_v, rgb_to_ycocg, tonemap, tonemap_inverse, ycocg_to_rgb, LUMA_REC709, TONEMAP_MAX,
};
pub use neighborhood::{
    box_from_columns, column_stats, cross_and_box_stats, fmax, fmin, for_each_row_stats, gather3x3,
    variance_box, NeighborhoodStats, CROSS,
};
pub use sample::{
    bilinear, bilinear_span, bilinear_texel_channel, bilinear_texels, catmull_rom, catmull_rom_span,
    catmull_rom_texel, catmull_rom_texels, nearest_texel, BilinearLanes, Footprint, FootprintLanes, SPAN,
    TEXEL,
};
pub use sharpen::sharpen_cross;
pub use sobel::{sobel_magnitude, sobel_magnitude_v, sobel_plane};

/// Reads `plane[x, y]` with coordinates clamped into the `width` x `height` image.
#[inline(always)]
pub fn fetch_clamped(plane: &[f32], width: usize, height: usize, x: isize, y: isize) -> f32 {
    let xc = x.clamp(0, width as isize - 1) as usize;
    let yc = y.clamp(0, height as isize - 1) as usize;
    plane[yc * width + xc]
}
