//! A synthetic G-buffer frame of any size, for timing filters where rendering a scene
//! would take longer than filtering it (1920x1080 in the report's timing section and in
//! `benches/filters.rs`).

use crate::frame::{ChannelKind, Frame, Plane, Sampling};

/// Textured colour with some HDR highlights, a depth ramp with object steps, object ids in
/// blocks, albedo, and a uniform sub-pixel pan of (-1.3, 0.7) px per frame, so every stage
/// of every filter runs. `index` moves the texture with the pan.
pub fn synthetic_frame(width: usize, height: usize, index: u64) -> Frame {
    let t = index as f32;
    let pat = |x: usize, y: usize, k: f32| {
        let (fx, fy) = (x as f32 + 1.3 * t, y as f32 - 0.7 * t);
        0.5 + 0.45 * ((fx * 0.21 + k).sin() * (fy * 0.17 - k).cos())
    };
    let color = [0.0, 1.0, 2.0].map(|k| {
        Plane::from_fn(width, height, |x, y| {
            pat(x, y, k) * if (x / 97 + y / 89) % 11 == 0 { 8.0 } else { 1.0 }
        })
    });
    let mut f = Frame::new(color).expect("three planes of one size");
    let albedo = [0.5, 1.5, 2.5].map(|k| Plane::from_fn(width, height, |x, y| pat(x, y, k)));
    f.set_f32(ChannelKind::Albedo, albedo.to_vec())
        .expect("same size");
    f.set_f32(
        ChannelKind::Depth,
        vec![Plane::from_fn(width, height, |x, y| {
            2.0 + y as f32 * 0.01 + ((x / 64) % 3) as f32
        })],
    )
    .expect("same size");
    f.set_f32(
        ChannelKind::Motion,
        vec![
            Plane::filled(width, height, -1.3f32),
            Plane::filled(width, height, 0.7f32),
        ],
    )
    .expect("same size");
    f.set_object_id(Plane::from_fn(width, height, |x, y| {
        (1 + x / 64 + 30 * (y / 64)) as u32
    }))
    .expect("same size");
    let normal = [0.3f32, -0.2, 0.93]
        .map(|k| Plane::from_fn(width, height, |x, y| k + 0.05 * ((x / 64 + y / 64) % 2) as f32));
    f.set_f32(ChannelKind::Normal, normal.to_vec())
        .expect("same size");
    f.meta.index = index;
    f
}

/// [`synthetic_frame`] with its colour shaded sparsely: one pixel per `factor x factor`
/// block in the rotating order of frame `index` (for timing the upsampling filters).
pub fn synthetic_sparse_frame(width: usize, height: usize, index: u64, factor: u32) -> Frame {
    let full = synthetic_frame(width, height, index);
    let s = Sampling::rotating(factor, index);
    let color = Frame::gather(full.color(), s).expect("a valid factor");
    let mut f = Frame::subsampled(color, width, height, s).expect("gathered at the pattern's size");
    for k in [
        ChannelKind::Albedo,
        ChannelKind::Depth,
        ChannelKind::Motion,
        ChannelKind::Normal,
    ] {
        let planes = full.planes(k).expect("set above").to_vec();
        f.set_f32(k, planes).expect("same size");
    }
    f.set_object_id(full.object_id().expect("set above").clone())
        .expect("same size");
    f.meta = full.meta;
    f
}
