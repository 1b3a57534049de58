//! Whole-plane passes shared by the temporal filters, built on [`crate::kernels`] and run
//! on the crate's pool by rows.

use super::reconstruct::Reconstruction;
use crate::frame::ChannelKind;
use crate::frame::{Frame, Plane, Rgb};
use crate::kernels::lanes::{block, each, Lanes, IOTA, LANES};
use crate::kernels::{rgb_to_ycocg, sharpen_cross, tonemap, tonemap_inverse, ycocg_to_rgb};
use crate::pipeline::exec::for_rows;
use crate::pipeline::{
    bind_size, check_channels, check_needs, DoubleBuffer, FilterError, FilterKind, FilterState, Inputs,
    ModelHealth, Output, PixelCounts, Recorder, Scratch, Skip, StateError,
};
use std::borrow::Cow;
use wide::f32x8;

/// Empty planes of the given size.
pub fn planes<const N: usize>(width: usize, height: usize) -> [Plane<f32>; N] {
    std::array::from_fn(|_| Plane::new(width, height))
}

/// Mutable slices of `N` planes.
pub fn slices_mut<const N: usize>(p: &mut [Plane<f32>; N]) -> [&mut [f32]; N] {
    p.each_mut().map(|p| p.data_mut())
}

/// The colour in the working space: tonemapped `c / (1 + max c)` when `tonemap` is on,
/// else the colour itself (borrowed).
pub fn to_working<'a>(color: &'a Rgb, on: bool, scratch: &mut Scratch) -> Cow<'a, Rgb> {
    if !on {
        return Cow::Borrowed(color);
    }
    Cow::Owned(map_color(color, scratch, tonemap))
}

/// `f` applied to each pixel's colour, into reused planes.
fn map_color(rgb: &Rgb, scratch: &mut Scratch, f: impl Fn([f32; 3]) -> [f32; 3] + Sync) -> Rgb {
    let (w, h) = rgb[0].size();
    let src = rgb.each_ref().map(|p| p.data());
    let mut out: Rgb = scratch.planes(w, h);
    for_rows(slices_mut(&mut out), w, |y, [a, b, c]| {
        for x in 0..w {
            let i = y * w + x;
            [a[x], b[x], c[x]] = f([src[0][i], src[1][i], src[2][i]]);
        }
    });
    out
}

/// The colour converted to YCoCg planes (Malvar and Sullivan 2003; see
/// [`rgb_to_ycocg`]), in reused planes.
pub fn to_ycocg(rgb: &Rgb, scratch: &mut Scratch) -> Rgb {
    map_color(rgb, scratch, rgb_to_ycocg)
}

/// Back from the working space to linear colour (in place); a no-op when `tonemap` is off.
pub fn from_working(rgb: &mut Rgb, on: bool) {
    if !on {
        return;
    }
    let w = rgb[0].width();
    for_rows(slices_mut(rgb), w, |_, [r, g, b]| {
        for x in 0..w {
            let c = tonemap_inverse([r[x], g[x], b[x]]);
            (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
        }
    });
}

/// Velocity dilation: each pixel takes the motion of the nearest (smallest depth) pixel of
/// its 3x3 neighbourhood, so edges of moving foreground objects reproject with the object
/// (Karis 2014; Oliveros 2018, sec. 3.6.3).
pub fn dilate_motion(motion: &[Plane<f32>; 2], depth: &Plane<f32>, scratch: &mut Scratch) -> [Plane<f32>; 2] {
    let (w, h) = depth.size();
    let d = depth.data();
    let m = motion.each_ref().map(|p| p.data());
    let mut out = scratch.planes(w, h);
    for_rows(slices_mut(&mut out), w, |y, [mx, my]| {
        for x in 0..w {
            (mx[x], my[x]) = nearest_motion(d, m, w, h, x, y);
        }
    });
    out
}

/// [`dilate_motion`] by [`dilate_row`] (vector code), rows in parallel: the same planes.
pub fn dilate_motion_rows(
    motion: &[Plane<f32>; 2],
    depth: &Plane<f32>,
    scratch: &mut Scratch,
) -> [Plane<f32>; 2] {
    let (w, h) = depth.size();
    let d = depth.data();
    let m = motion.each_ref().map(|p| p.data());
    let mut out = scratch.planes(w, h);
    for_rows(slices_mut(&mut out), w, |y, [mx, my]| {
        dilate_row(d, m, w, h, y, mx, my)
    });
    out
}

/// [`to_working`] of one row: `c / (1 + max c)` ([`tonemap`]) of `src` into `dst` (as
/// many pixels as `dst` holds).
pub fn tonemap_row(src: [&[f32]; 3], dst: [&mut [f32]; 3]) {
    let [r, g, b] = src;
    let [a, c, d] = dst;
    let n = a.len();
    let (r, g, b, c, d) = (&r[..n], &g[..n], &b[..n], &mut c[..n], &mut d[..n]);
    for x in 0..n {
        let t = tonemap([r[x], g[x], b[x]]);
        (a[x], c[x], d[x]) = (t[0], t[1], t[2]);
    }
}

/// [`from_working`] of one row, in place ([`tonemap_inverse`]).
pub fn untonemap_row(rgb: [&mut [f32]; 3]) {
    let [r, g, b] = rgb;
    let n = r.len();
    let (g, b) = (&mut g[..n], &mut b[..n]);
    for x in 0..n {
        let c = tonemap_inverse([r[x], g[x], b[x]]);
        (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
    }
}

/// The motion of the nearest (smallest depth) pixel of `(x, y)`'s 3x3 neighbourhood,
/// rows top to bottom and columns left to right, the first of equal depths winning; the
/// centre starts as the best.
#[inline(always)]
fn nearest_motion(d: &[f32], m: [&[f32]; 2], w: usize, h: usize, x: usize, y: usize) -> (f32, f32) {
    let mut best = y * w + x;
    let mut best_d = d[best];
    for yy in y.saturating_sub(1)..(y + 2).min(h) {
        for xx in x.saturating_sub(1)..(x + 2).min(w) {
            let i = yy * w + xx;
            if d[i] < best_d {
                best_d = d[i];
                best = i;
            }
        }
    }
    (m[0][best], m[1][best])
}

/// [`dilate_motion`] of row `y` into `mx`, `my`: each pixel takes the motion of the nearest pixel of its 3x3
/// (Karis 2014). Pixels with all eight neighbours (not on the image's border) run in a
/// branch-free loop over the row; the border ones as `nearest_motion`.
pub fn dilate_row(d: &[f32], m: [&[f32]; 2], w: usize, h: usize, y: usize, mx: &mut [f32], my: &mut [f32]) {
    let border = |x: usize, mx: &mut [f32], my: &mut [f32]| {
        (mx[x], my[x]) = nearest_motion(d, m, w, h, x, y);
    };
    if y == 0 || y + 1 >= h || w < 3 {
        for x in 0..w {
            border(x, mx, my);
        }
        return;
    }
    border(0, mx, my);
    border(w - 1, mx, my);
    let n = w - 2;
    // Rows above, here and below, each starting at column 0: pixel x (1..w-1) reads
    // columns x-1, x, x+1 of each.
    let rows = [y - 1, y, y + 1].map(|r| r * w..r * w + w);
    let dr = rows.clone().map(|r| &d[r]);
    let xr = rows.clone().map(|r| &m[0][r]);
    let yr = rows.map(|r| &m[1][r]);
    let (mx, my) = (&mut mx[1..w - 1], &mut my[1..w - 1]);
    // Eight pixels at a time in vectors (the same compares and picks, lane by lane), then
    // the rest one by one.
    let whole = n / LANES * LANES;
    let load = |r: &[f32], at: usize| f32x8::from(*block::<f32, LANES>(r, at));
    for i in (0..whole).step_by(LANES) {
        let mut bd = load(dr[1], i + 1);
        let mut bx = load(xr[1], i + 1);
        let mut by = load(yr[1], i + 1);
        for r in 0..3 {
            for c in 0..3 {
                let dv = load(dr[r], i + c);
                let take = dv.simd_lt(bd);
                bd = take.select(dv, bd);
                bx = take.select(load(xr[r], i + c), bx);
                by = take.select(load(yr[r], i + c), by);
            }
        }
        mx[i..i + LANES].copy_from_slice(&bx.to_array());
        my[i..i + LANES].copy_from_slice(&by.to_array());
    }
    for i in whole..n {
        // Candidates in the reference's order; the centre (row 1, column i + 1) first.
        let mut bd = dr[1][i + 1];
        let mut bx = xr[1][i + 1];
        let mut by = yr[1][i + 1];
        for r in 0..3 {
            for c in 0..3 {
                let dv = dr[r][i + c];
                let take = dv < bd;
                bd = if take { dv } else { bd };
                bx = if take { xr[r][i + c] } else { bx };
                by = if take { yr[r][i + c] } else { by };
            }
        }
        mx[i] = bx;
        my[i] = by;
    }
}

/// Sharpens every channel with [`sharpen_cross`] of strength `s`, keeping values in
/// `[0, hi]` (`hi` the frame's [`output_ceiling`]).
pub fn sharpen(rgb: &Rgb, s: f32, hi: f32, scratch: &mut Scratch) -> Rgb {
    let (w, h) = rgb[0].size();
    let src = rgb.each_ref().map(|p| p.data());
    let mut out: Rgb = scratch.planes(w, h);
    for_rows(slices_mut(&mut out), w, |y, rows| {
        let up = y.saturating_sub(1) * w;
        let down = (y + 1).min(h - 1) * w;
        for (k, row) in rows.into_iter().enumerate() {
            let p = src[k];
            for x in 0..w {
                let i = y * w + x;
                let n = [
                    p[up + x],
                    p[y * w + x.saturating_sub(1)],
                    p[y * w + (x + 1).min(w - 1)],
                    p[down + x],
                ];
                row[x] = sharpen_cross(p[i], n, s).clamp(0.0, hi);
            }
        }
    });
    out
}

/// The largest output a filter gives in its working space for a frame with `facts`: with
/// HDR input (tonemapped), the tonemap of the frame's largest sample, `M / (1 + M)`, which
/// no channel of any tonemapped input pixel exceeds; unbounded otherwise. A sharpen, or a
/// model's prediction, may overshoot the range of the input, and near 1 the untonemap
/// turns a small overshoot into millions: no output is brighter than the frame's brightest
/// sample. The CPU kernels, their references and the GPU all take it from here.
pub fn output_ceiling(facts: &crate::pipeline::FrameFacts) -> f32 {
    if facts.hdr {
        (facts.max_color / (1.0 + facts.max_color)).min(crate::kernels::TONEMAP_MAX)
    } else {
        f32::MAX
    }
}

/// The state every temporal filter keeps: double-buffered history planes (the first three
/// hold colour in the working space), which space that is (tonemapped or linear), and the
/// reused temporaries.
#[derive(Debug)]
pub struct TemporalState {
    /// The history planes.
    pub buffer: DoubleBuffer,
    /// Reused temporaries.
    pub scratch: Scratch,
    /// Whether the colour history is tonemapped.
    tonemapped: bool,
    /// How the history moves between linear and tonemapped space.
    conversion: Conversion,
    /// The filter's own check of loaded planes (values in range), after every sample was
    /// found finite.
    check: Option<PlaneCheck>,
}

/// A filter's check of history planes loaded from a state file: `Err` names what is out
/// of range and where. Given the planes, their channels per pixel and whether their
/// colour is tonemapped.
pub type PlaneCheck = fn(&[Plane<f32>], &[usize], bool) -> Result<(), StateError>;

/// How a filter's history is converted between linear and tonemapped working space when a
/// stream switches between LDR and HDR frames.
#[derive(Clone, Copy, Debug)]
pub enum Conversion {
    /// The first three planes hold colour (YCoCg when `ycocg`, else RGB).
    Color {
        /// Whether the colour is stored as YCoCg.
        ycocg: bool,
    },
    /// A filter-specific conversion of all history planes, `to_tonemapped` as the flag.
    Custom(fn(&mut [Plane<f32>], bool)),
}

impl TemporalState {
    /// History of `planes` planes, colour in YCoCg when `ycocg`.
    pub fn new(planes: usize, ycocg: bool) -> Self {
        Self::with_conversion(planes, Conversion::Color { ycocg })
    }

    /// History of `planes` planes converted between spaces by `conversion`.
    pub fn with_conversion(planes: usize, conversion: Conversion) -> Self {
        Self::with_components(&vec![1; planes], conversion)
    }

    /// History of one plane per entry of `components`, each with that many channels per
    /// pixel, interleaved; converted between spaces by `conversion`.
    pub fn with_components(components: &[usize], conversion: Conversion) -> Self {
        TemporalState {
            buffer: DoubleBuffer::with_components(components),
            scratch: Scratch::default(),
            tonemapped: false,
            conversion,
            check: None,
        }
    }

    /// This history, with `check` run on planes loaded from a state file.
    pub fn checked_by(mut self, check: PlaneCheck) -> Self {
        self.check = Some(check);
        self
    }

    /// Sizes the history for `frame` and stores its colour in this frame's working space
    /// (tonemapped when `hdr`); returns whether there is history to use (none on the first
    /// frame, after a reset, and on a reset frame).
    pub fn begin(&mut self, frame: &Frame, hdr: bool) -> Result<bool, FilterError> {
        bind_size(&mut self.buffer, frame)?;
        let has_history = self.buffer.valid() && !frame.meta.reset;
        if has_history && self.tonemapped != hdr {
            match self.conversion {
                Conversion::Color { ycocg } => convert_history(&mut self.buffer.read_mut()[..3], hdr, ycocg),
                Conversion::Custom(f) => f(self.buffer.read_mut(), hdr),
            }
        }
        Ok(has_history)
    }

    /// The state to continue from (see [`crate::pipeline::state`]): the history planes and
    /// whether the colour in them is tonemapped.
    pub fn save(&self, filter: &'static str, params: serde_json::Value) -> FilterState {
        let mut st = FilterState::empty(filter, params);
        st.components = self.buffer.components().to_vec();
        if let Some(size) = self.buffer.history_size() {
            st.size = Some(size);
            st.planes = self.buffer.read().to_vec();
        }
        st.flags.insert("tonemapped".into(), self.tonemapped.into());
        st
    }

    /// Continues from `st`, a state [`Self::save`] gave for `filter` with `params`; on
    /// error nothing changes.
    pub fn load(
        &mut self,
        st: &FilterState,
        filter: &'static str,
        params: &serde_json::Value,
    ) -> Result<(), StateError> {
        st.check_for(filter, params)?;
        let tonemapped = st.flag("tonemapped", filter)?;
        // Untrusted planes (a client's upload, a checkpoint on shared storage): a filter
        // would spread a NaN or an out-of-range value into every frame after.
        st.check_finite()?;
        if let Some(check) = self.check {
            check(&st.planes, &st.components, tonemapped)?;
        }
        if st.components != self.buffer.components() {
            return Err(StateError::Mismatch {
                what: st.filter.clone(),
                filter,
                message: format!(
                    "its planes have {:?} channels, the filter's {:?}",
                    st.components,
                    self.buffer.components()
                ),
            });
        }
        match st.size {
            Some(size) => {
                self.buffer
                    .restore(size, st.planes.clone())
                    .map_err(|message| StateError::Mismatch {
                        what: st.filter.clone(),
                        filter,
                        message,
                    })?
            }
            None => self.buffer.reset(),
        }
        self.tonemapped = tonemapped;
        Ok(())
    }

    /// Whether the colour in the history is tonemapped.
    pub fn tonemapped(&self) -> bool {
        self.tonemapped
    }

    /// Says whether the colour in the history is tonemapped (for a state assembled
    /// elsewhere, e.g. downloaded from a GPU, before [`Self::save`]).
    pub fn set_tonemapped(&mut self, tonemapped: bool) {
        self.tonemapped = tonemapped;
    }

    /// After a frame: the written planes become the history; returns the bytes held.
    pub fn finish(&mut self, hdr: bool) -> usize {
        self.buffer.swap();
        self.tonemapped = hdr;
        self.buffer.bytes()
    }
}

/// A frame's inputs as the slices a fused pass reads: its size, colour, motion, depth and
/// the pixels the repair replaced.
#[derive(Clone, Copy)]
pub struct FrameSlices<'a> {
    /// Width in pixels.
    pub w: usize,
    /// Height in pixels.
    pub h: usize,
    /// The colour planes.
    pub color: [&'a [f32]; 3],
    /// The motion planes, where the frame has motion.
    pub motion: Option<[&'a [f32]; 2]>,
    /// The depth, where the frame has it.
    pub depth: Option<&'a [f32]>,
    /// The pixels the repair replaced, where there were any.
    pub invalid: Option<&'a [bool]>,
}

impl<'a> FrameSlices<'a> {
    /// The slices of `inp`, with `motion` (a pass's own, e.g. dilated) read in place of the
    /// frame's where given.
    pub fn of(inp: &'a Inputs, motion: Option<&'a [Plane<f32>; 2]>) -> Self {
        FrameSlices {
            w: inp.width,
            h: inp.height,
            color: inp.color_slices(),
            motion: motion
                .or(inp.motion.as_deref())
                .map(|m| m.each_ref().map(|p| p.data())),
            depth: inp.depth.as_deref().map(|d| d.data()),
            invalid: inp.invalid.as_deref(),
        }
    }
}

/// What a temporal filter's own stages work with for one frame (see
/// [`TemporalState::run`]).
pub struct FrameContext<'f, 's> {
    /// The channels the filter uses, repaired, with the planner's facts.
    pub inp: Inputs<'f>,
    /// The frame's record: the body times its stages here.
    pub rec: &'s mut Recorder,
    /// Whether the history holds a previous frame (not on the first frame, after a reset,
    /// or on a reset frame).
    pub has_history: bool,
    /// The history: the previous frame's planes, in this frame's working space.
    pub read: &'s [Plane<f32>],
    /// The planes this frame's history is written into.
    pub next: &'s mut [Plane<f32>],
    /// Reused temporaries (and the output planes callers hand back).
    pub scratch: &'s mut Scratch,
}

/// A [`FrameContext`] taken apart: its fields in their order.
pub type FrameParts<'f, 's> = (
    Inputs<'f>,
    &'s mut Recorder,
    bool,
    &'s [Plane<f32>],
    &'s mut [Plane<f32>],
    &'s mut Scratch,
);

impl<'f, 's> FrameContext<'f, 's> {
    /// The fields as a tuple, for a body that works with them all as locals.
    pub fn into_parts(self) -> FrameParts<'f, 's> {
        (
            self.inp,
            self.rec,
            self.has_history,
            self.read,
            self.next,
            self.scratch,
        )
    }
}

/// What a temporal filter's stages produce for one frame.
pub struct FrameResult {
    /// The output colour, linear.
    pub color: Rgb,
    /// What happened to the history.
    pub pixels: PixelCounts,
    /// Model health, for filters with per-pixel models.
    pub model: Option<ModelHealth>,
}

impl TemporalState {
    /// The frame every temporal filter `K` runs (the fused filters through
    /// [`history_filter`], and the references the tests hold them to): check that the
    /// frame has the channels `K` needs (and full-resolution colour unless its input may be
    /// sparse), repair and plan the channels it uses (stage `repair`), reconstruct the
    /// colour with `recon` (stage `reconstruct`), size the history and move it to this
    /// frame's working space, run `body` (the filter's own stages, from tonemap to
    /// untonemap), make what it wrote the history, and finish the record.
    pub fn run<K: FilterKind>(
        &mut self,
        recon: Reconstruction,
        frame: &Frame,
        body: impl FnOnce(FrameContext<'_, '_>) -> Result<FrameResult, FilterError>,
    ) -> Result<Output, FilterError> {
        let (filter, needs, uses) = (K::NAME, K::needs(), K::uses());
        if K::SPARSE_INPUT {
            check_channels(filter, needs, frame)?;
        } else {
            check_needs(filter, needs, frame)?;
        }
        let mut rec = Recorder::new();
        let inp = recon.prepare(frame, uses, &mut rec, &mut self.scratch)?;
        let hdr = inp.facts.hdr;
        let counts = inp.counts;
        let has_history = self.begin(frame, hdr)?;
        let (read, next) = self.buffer.split();
        let mut result = body(FrameContext {
            inp,
            rec: &mut rec,
            has_history,
            read,
            next,
            scratch: &mut self.scratch,
        })?;
        let sparse_colour = !frame.sampling().is_full();
        recon.sparse_output(&mut rec, &mut result.color, sparse_colour, &mut self.scratch);
        let bytes = self.finish(hdr);
        let mut record = rec.finish(filter, frame.meta.index, result.pixels, counts, bytes);
        record.model = result.model;
        Ok(Output {
            color: result.color,
            record,
        })
    }
}

/// A reference filter `$name` (tests only): the scalar statement of the filter `$kind`,
/// stage by stage over whole planes, that its fused kernel is tested against. Its frame
/// runs through [`TemporalState::run`] as the filter's does (with the parameters the
/// method `$params` gives, as in [`history_filter`], and the history `$history` makes of
/// the parameters `$p`), its own stages in the function `stages` of the module that
/// declares it (given the parameters, the frame and the context).
#[cfg(test)]
macro_rules! reference_filter {
    ($(#[$meta:meta])* $name:ident, $kind:ty, $params:ident, |$p:ident| $history:expr) => {
        $(#[$meta])*
        #[derive(Debug)]
        pub struct $name {
            params: <$kind as $crate::pipeline::FilterKind>::Params,
            hist: $crate::filters::passes::TemporalState,
        }

        impl $name {
            /// A fresh reference filter.
            pub fn new(params: <$kind as $crate::pipeline::FilterKind>::Params) -> Self {
                let $p = &params;
                let hist = $history;
                $name { params, hist }
            }

            /// Filters one frame.
            pub fn process(
                &mut self,
                frame: &$crate::frame::Frame,
            ) -> Result<$crate::pipeline::Output, $crate::pipeline::FilterError> {
                let p = self.params.$params();
                self.hist
                    .run::<$kind>(p.reconstruction(), frame, |ctx| stages(&p, frame, ctx))
            }
        }

        impl $crate::filters::check::Reference<$kind> for $name {
            fn with_params(params: <$kind as $crate::pipeline::FilterKind>::Params) -> Self {
                Self::new(params)
            }

            fn filter(&mut self, frame: &$crate::frame::Frame) -> $crate::pipeline::Output {
                self.process(frame).unwrap()
            }
        }
    };
}
#[cfg(test)]
pub(crate) use reference_filter;

/// The `tonemap` stage as the references write it, over whole planes: the colour in the
/// working space (tonemapped for HDR input), or the input's own where the stage is left out.
#[cfg(test)]
pub fn tonemap_stage<'a>(rec: &mut Recorder, inp: &'a Inputs, scratch: &mut Scratch) -> Cow<'a, Rgb> {
    rec.stage("tonemap", inp.facts.tonemap(), || {
        to_working(&inp.color, true, scratch)
    })
    .unwrap_or(Cow::Borrowed(&*inp.color))
}

/// Converts a history whose first plane holds texels `[Y, Co, Cg, count]` between linear
/// and tonemapped working space (as `convert_history` does for planar YCoCg).
pub fn convert_texel_history(planes: &mut [Plane<f32>], to_tonemapped: bool) {
    let w = planes[0].width();
    for_rows([planes[0].data_mut()], w, |_, [row]| {
        for t in row.chunks_exact_mut(4) {
            let rgb = ycocg_to_rgb([t[0], t[1], t[2]]).map(|v| v.max(0.0));
            let c = if to_tonemapped {
                tonemap(rgb)
            } else {
                tonemap_inverse(rgb)
            };
            [t[0], t[1], t[2]] = rgb_to_ycocg(c);
        }
    });
}

/// Converts colour history planes between linear and tonemapped working space.
fn convert_history(planes: &mut [Plane<f32>], to_tonemapped: bool, ycocg: bool) {
    let w = planes[0].width();
    let (a, rest) = planes.split_at_mut(1);
    let (b, c) = rest.split_at_mut(1);
    for_rows(
        [a[0].data_mut(), b[0].data_mut(), c[0].data_mut()],
        w,
        |_, [a, b, c]| {
            for x in 0..w {
                let v = [a[x], b[x], c[x]];
                let rgb = if ycocg {
                    ycocg_to_rgb(v).map(|v| v.max(0.0))
                } else {
                    v
                };
                let t = if to_tonemapped {
                    tonemap(rgb)
                } else {
                    tonemap_inverse(rgb)
                };
                [a[x], b[x], c[x]] = if ycocg { rgb_to_ycocg(t) } else { t };
            }
        },
    );
}

/// Where this frame's history comes from: whether reprojection runs (and why not), and the
/// motion it uses (dilated when the `dilate` stage ran).
pub struct Reprojection {
    /// Why the `reproject` stage is left out; `None` when it runs.
    pub skip: Option<Skip>,
    /// The dilated motion, when the `dilate` stage ran.
    pub dilated: Option<[Plane<f32>; 2]>,
}

/// Why reprojection is left out of a frame (None: it runs): it needs motion, history and
/// some motion in the frame. A missing channel is named first, on every frame it is
/// missing from (the first one included), so records and summaries say what the input lacks.
pub fn reproject_skip(inp: &Inputs, has_history: bool) -> Option<Skip> {
    inp.require(ChannelKind::Motion)
        .or_else(|| (!has_history).then_some(Skip::NoHistory))
        .or_else(|| inp.facts.reprojection())
}

/// Why velocity dilation is left out of a frame (None: it runs): it needs reprojection
/// (`reproject`, from [`reproject_skip`]), depth, and the filter's `dilation` on.
pub fn dilate_skip(inp: &Inputs, reproject: &Option<Skip>, dilation: bool) -> Option<Skip> {
    reproject
        .clone()
        .or_else(|| inp.require(ChannelKind::Depth))
        .or_else(|| (!dilation).then_some(Skip::Disabled { param: "dilation" }))
}

impl Reprojection {
    /// Plans reprojection for a frame and runs the `dilate` stage: reprojection needs
    /// history, motion and some motion; dilation also needs depth and `dilation` on.
    pub fn plan(
        rec: &mut Recorder,
        inp: &Inputs,
        has_history: bool,
        dilation: bool,
        scratch: &mut Scratch,
    ) -> Reprojection {
        let skip = reproject_skip(inp, has_history);
        let dilate_skip = dilate_skip(inp, &skip, dilation);
        let dilated = rec.stage("dilate", dilate_skip, || {
            dilate_motion(
                inp.motion.as_deref().expect("required"),
                inp.depth.as_deref().expect("required"),
                scratch,
            )
        });
        Reprojection { skip, dilated }
    }

    /// The motion planes to reproject with (call only when reprojection runs).
    pub fn motion<'a>(&'a self, inp: &'a Inputs) -> [&'a [f32]; 2] {
        let m = self
            .dilated
            .as_ref()
            .unwrap_or_else(|| inp.motion.as_deref().expect("reprojection needs motion"));
        m.each_ref().map(|p| p.data())
    }
}

/// Whether a previous position `(px, py)` (pixel units) lies on a `w` x `h` screen; false
/// for NaN.
#[inline(always)]
pub fn on_screen(px: f32, py: f32, w: usize, h: usize) -> bool {
    px >= 0.0 && px <= w as f32 && py >= 0.0 && py <= h as f32
}

/// The previous positions `p + motion` (pixel units) of row `y`'s block from column `x0`; a
/// row's last block repeats its last pixel in the lanes past the end.
#[inline(always)]
pub fn previous_positions(mx: &[f32], my: &[f32], x0: usize, y: usize) -> [Lanes; 2] {
    let w = mx.len();
    let row = y as f32 + 0.5;
    if x0 + LANES <= w {
        let (bx, by) = (block::<f32, LANES>(mx, x0), block::<f32, LANES>(my, x0));
        // `x0` is a multiple of 8, so `x0 as f32` is exact below 2^27 columns, and the
        // f32 sum `x0 + l` rounds like `(x0 + l) as f32`: the same numbers, by one vector
        // add.
        let x = f32x8::splat(x0 as f32) + f32x8::from(IOTA);
        let px = x + f32x8::splat(0.5) + f32x8::from(*bx);
        return [px.to_array(), (f32x8::splat(row) + f32x8::from(*by)).to_array()];
    }
    let at = |l: usize| (x0 + l).min(w - 1);
    [
        each(|l| at(l) as f32 + 0.5 + mx[at(l)]),
        each(|l| row + my[at(l)]),
    ]
}

/// [`on_screen`] of eight positions, as bits (lane `l` is bit `l`).
#[inline(always)]
pub fn on_screen_bits(px: &Lanes, py: &Lanes, w: usize, h: usize) -> u32 {
    let (x, y, zero) = (f32x8::from(*px), f32x8::from(*py), f32x8::splat(0.0));
    let on = x.simd_ge(zero)
        & x.simd_le(f32x8::splat(w as f32))
        & y.simd_ge(zero)
        & y.simd_le(f32x8::splat(h as f32));
    on.to_bitmask()
}
/// The [`Filter`](crate::pipeline::Filter) impl of a history filter (a type with
/// `params` and a [`TemporalState`] `hist`, and its [`FilterKind`](crate::pipeline::FilterKind)):
/// its frame goes through [`TemporalState::run`] with the filter's channels, sparse input
/// as its kind says and the reconstruction its `pixel_filter` and `filter_width` choose,
/// then `body` (given the parameters `p`, the `frame` and the `ctx`); reset, plane reuse,
/// size and the saved state are the history's. Adding a history filter means writing its
/// stages and one line of this.
macro_rules! history_filter {
    ($ty:ty, |$p:ident, $frame:ident, $ctx:ident| $body:expr) => {
        $crate::filters::passes::history_filter!($ty, clone, |$p, $frame, $ctx| $body);
    };
    // `$params` is the method of the parameters that gives the ones a frame runs with
    // (`clone`, or phlm's `effective`: its `variant` sets other parameters).
    ($ty:ty, $params:ident, |$p:ident, $frame:ident, $ctx:ident| $body:expr) => {
        impl $crate::pipeline::Filter for $ty {
            fn name(&self) -> &'static str {
                <Self as $crate::pipeline::FilterKind>::NAME
            }

            fn params(&self) -> serde_json::Value {
                serde_json::Value::Object($crate::pipeline::params::to_json(&self.params))
            }

            fn process(
                &mut self,
                $frame: &$crate::frame::Frame,
            ) -> Result<$crate::pipeline::Output, $crate::pipeline::FilterError> {
                let $p = &self.params.$params();
                self.hist
                    .run::<Self>($p.reconstruction(), $frame, |$ctx| $body)
            }

            fn reset(&mut self) {
                self.hist.buffer.reset();
            }

            fn recycle(&mut self, planes: $crate::frame::Rgb) {
                self.hist.scratch.recycle(planes);
            }

            fn state_bytes(&self) -> usize {
                self.hist.buffer.bytes()
            }

            fn save_state(&self) -> Result<$crate::pipeline::FilterState, $crate::pipeline::StateError> {
                use $crate::pipeline::FilterKind;
                Ok(self.hist.save(Self::NAME, self.params()))
            }

            fn load_state(
                &mut self,
                state: &$crate::pipeline::FilterState,
            ) -> Result<(), $crate::pipeline::StateError> {
                use $crate::pipeline::FilterKind;
                self.hist.load(state, Self::NAME, &self.params())
            }
        }
    };
}
pub(crate) use history_filter;

/// The `STAGES` of a history filter's [`FilterKind`](crate::pipeline::FilterKind) impl (an
/// item of it): `repair` and `reconstruct`, which [`TemporalState::run`] runs before the
/// filter's own stages, declared here once, then the filter's own `$stage`s.
macro_rules! temporal_stages {
    ($($stage:literal),* $(,)?) => {
        const STAGES: &'static [&'static str] = &[
            $crate::pipeline::input::REPAIR_STAGE,
            $crate::filters::reconstruct::STAGE,
            $($stage),*
        ];
    };
}
pub(crate) use temporal_stages;
