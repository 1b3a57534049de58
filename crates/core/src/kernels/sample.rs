//! Resampling of history planes at sub-pixel positions: bilinear and Catmull-Rom.

use super::lanes::{block, each, load_texels, mask_of_bits, Lanes, LANES};
use wide::{f32x4, f32x8, i32x8};

/// Bilinear sample of `N` planes at `(x, y)` (pixel units, centres at +0.5, edges extended).
#[inline(always)]
pub fn bilinear<const N: usize>(
    planes: [&[f32]; N],
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; N] {
    let (x0y0, t) = bilinear_footprint(x, y);
    let [x0, y0] = x0y0;
    if x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < width as f32 && y0 + 1.0 < height as f32 {
        // The 2x2 footprint is inside: no clamping.
        let a = y0 as usize * width + x0 as usize;
        let b = a + width;
        let mut out = [0.0; N];
        for (o, p) in out.iter_mut().zip(planes) {
            let (r0, r1) = (&p[a..a + 2], &p[b..b + 2]);
            *o = lerp2([r0[0], r0[1], r1[0], r1[1]], t);
        }
        return out;
    }
    let [i00, i10, i01, i11] = clamped_taps(x0y0, width, height);
    planes.map(|p| lerp2([p[i00], p[i10], p[i01], p[i11]], t))
}

/// The top-left tap of the bilinear 2x2 footprint of a sample at `(x, y)` (whole numbers
/// as f32, possibly outside, huge or NaN) and the fractions past it.
#[inline(always)]
fn bilinear_footprint(x: f32, y: f32) -> ([f32; 2], [f32; 2]) {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x0 = fx.floor();
    let y0 = fy.floor();
    ([x0, y0], [fx - x0, fy - y0])
}

/// The indices of the 2x2 footprint's taps (top left, top right, bottom left, bottom
/// right) whose top-left tap is `x0y0`, each clamped into the image.
#[inline(always)]
fn clamped_taps(x0y0: [f32; 2], width: usize, height: usize) -> [usize; 4] {
    let [x0, y0] = x0y0;
    let xa = clamp_index(x0, width);
    let xb = clamp_index(x0 + 1.0, width);
    let ya = clamp_index(y0, height) * width;
    let yb = clamp_index(y0 + 1.0, height) * width;
    [ya + xa, ya + xb, yb + xa, yb + xb]
}

/// Bilinear interpolation of taps `[p00, p10, p01, p11]` at fractions `t`: along x in
/// both rows, then between the rows.
#[inline(always)]
fn lerp2(p: [f32; 4], t: [f32; 2]) -> f32 {
    let [p00, p10, p01, p11] = p;
    let top = p00 + (p10 - p00) * t[0];
    let bottom = p01 + (p11 - p01) * t[0];
    top + (bottom - top) * t[1]
}

/// Index `i` (a whole number as f32, possibly out of range or huge) clamped into `0..n`.
#[inline(always)]
fn clamp_index(i: f32, n: usize) -> usize {
    // `as` saturates for huge values and maps NaN to 0, so this never panics.
    (i.max(0.0) as usize).min(n - 1)
}

/// Catmull-Rom weights of the four taps around a sample at fraction `t` past tap 1.
#[inline(always)]
fn catmull_rom_weights(t: f32) -> [f32; 4] {
    let t2 = t * t;
    let t3 = t2 * t;
    [
        -0.5 * t + t2 - 0.5 * t3,
        1.0 - 2.5 * t2 + 1.5 * t3,
        0.5 * t + 2.0 * t2 - 1.5 * t3,
        -0.5 * t2 + 0.5 * t3,
    ]
}

/// [`catmull_rom_weights`] of eight fractions.
#[inline(always)]
fn catmull_rom_weights_v(t: f32x8) -> [f32x8; 4] {
    let s = f32x8::splat;
    let t2 = t * t;
    let t3 = t2 * t;
    [
        s(-0.5) * t + t2 - s(0.5) * t3,
        s(1.0) - s(2.5) * t2 + s(1.5) * t3,
        s(0.5) * t + s(2.0) * t2 - s(1.5) * t3,
        s(-0.5) * t2 + s(0.5) * t3,
    ]
}

/// Where a Catmull-Rom sample at one position reads, and with what weights.
#[derive(Clone, Copy, Debug, Default)]
pub struct Footprint {
    /// Column and row of tap 1 (the texel left of and above the position), as whole
    /// numbers in f32: possibly negative, past the edge, huge or NaN.
    pub x1: f32,
    /// See `x1`.
    pub y1: f32,
    /// `x1` as an integer (saturating: exact wherever the footprint is inside the image).
    pub ix: i32,
    /// `y1` as an integer, likewise.
    pub iy: i32,
    /// The position's fraction past tap 1, horizontally and vertically.
    pub tx: f32,
    /// See `tx`.
    pub ty: f32,
    /// Horizontal weights of taps 0 to 3.
    pub wx: [f32; 4],
    /// Vertical weights of taps 0 to 3, divided by the sum of the twelve weights used.
    pub wy: [f32; 4],
}

impl Footprint {
    /// The footprint of a sample at `(x, y)` (pixel units, centres at +0.5).
    #[inline(always)]
    pub fn at(x: f32, y: f32) -> Self {
        let fx = x - 0.5;
        let fy = y - 0.5;
        let x1 = fx.floor();
        let y1 = fy.floor();
        let (tx, ty) = (fx - x1, fy - y1);
        let wx = catmull_rom_weights(tx);
        let wy = catmull_rom_weights(ty);
        // The twelve weights' sum, grouped by row: the outer rows take the middle two
        // columns, the inner rows all four.
        let middle = wx[1] + wx[2];
        let all = (wx[0] + wx[1]) + (wx[2] + wx[3]);
        let wsum = middle * (wy[0] + wy[3]) + all * (wy[1] + wy[2]);
        let wy = wy.map(|w| w / wsum);
        let (ix, iy) = (x1 as i32, y1 as i32);
        Footprint {
            x1,
            y1,
            ix,
            iy,
            tx,
            ty,
            wx,
            wy,
        }
    }

    /// Whether the whole 4x4 footprint lies inside a `width` x `height` image.
    #[inline(always)]
    fn inside(&self, width: usize, height: usize) -> bool {
        self.x1 >= 1.0 && self.y1 >= 1.0 && self.x1 + 2.0 < width as f32 && self.y1 + 2.0 < height as f32
    }

    /// The four tap columns (or rows, from `y1`) clamped into `0..n`.
    #[inline(always)]
    fn clamped(i1: f32, n: usize) -> [usize; 4] {
        [-1.0, 0.0, 1.0, 2.0].map(|d| clamp_index(i1 + d, n))
    }
}

/// The footprints of eight positions, one field per lane: [`Footprint::at`] lane by lane
/// (the same operations, so the same bits), in vector instructions.
#[derive(Clone, Copy, Debug, Default)]
pub struct FootprintLanes {
    x1: Lanes,
    y1: Lanes,
    ix: [i32; LANES],
    iy: [i32; LANES],
    tx: Lanes,
    ty: Lanes,
    wx: [Lanes; 4],
    wy: [Lanes; 4],
}

impl FootprintLanes {
    /// The footprints of positions `(x[l], y[l])`.
    #[inline(always)]
    pub fn at(x: &Lanes, y: &Lanes) -> Self {
        // In `f32x8` vectors: as a loop over lanes the integer conversions and the
        // weights stayed scalar. `floor` and `trunc_int` (NaN to 0, saturating) are what
        // `f32::floor` and `as i32` compute.
        let half = f32x8::splat(0.5);
        let fx = f32x8::from(*x) - half;
        let fy = f32x8::from(*y) - half;
        let (x1, y1) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - x1, fy - y1);
        let wx = catmull_rom_weights_v(tx);
        let wy = catmull_rom_weights_v(ty);
        let middle = wx[1] + wx[2];
        let all = (wx[0] + wx[1]) + (wx[2] + wx[3]);
        let wsum = middle * (wy[0] + wy[3]) + all * (wy[1] + wy[2]);
        FootprintLanes {
            x1: x1.to_array(),
            y1: y1.to_array(),
            ix: x1.trunc_int().to_array(),
            iy: y1.trunc_int().to_array(),
            tx: tx.to_array(),
            ty: ty.to_array(),
            wx: wx.map(|w| w.to_array()),
            wy: wy.map(|w| (w / wsum).to_array()),
        }
    }

    /// Lane `l`'s footprint.
    #[inline(always)]
    pub fn lane(&self, l: usize) -> Footprint {
        Footprint {
            x1: self.x1[l],
            y1: self.y1[l],
            ix: self.ix[l],
            iy: self.iy[l],
            tx: self.tx[l],
            ty: self.ty[l],
            wx: self.wx.map(|w| w[l]),
            wy: self.wy.map(|w| w[l]),
        }
    }

    /// The lanes whose whole 4x4 footprint lies inside a `width` x `height` image
    /// ([`Footprint::inside`]), as bits (lane `l` is bit `l`).
    #[inline(always)]
    pub fn inside_bits(&self, width: usize, height: usize) -> u32 {
        let (x1, y1) = (f32x8::from(self.x1), f32x8::from(self.y1));
        let (one, two) = (f32x8::splat(1.0), f32x8::splat(2.0));
        let inside = x1.simd_ge(one)
            & y1.simd_ge(one)
            & (x1 + two).simd_lt(f32x8::splat(width as f32))
            & (y1 + two).simd_lt(f32x8::splat(height as f32));
        inside.to_bitmask()
    }

    /// [`catmull_rom_texel`] of each lane's footprint for the lanes set in `on` (lane `l`
    /// is bit `l`), zero texels in the others, as lanes (channel by channel). Lane `l`'s
    /// weights come from one 8x8 transpose of the block's (`wx` in the low half of its
    /// vector, `wy` in the high half), and the index of its footprint's first texel from
    /// one vector multiply, so a lane inside the image loads one vector of weights and one
    /// index where it read ten fields of its own; the count's bilinear is computed for the
    /// eight lanes at once from their centre taps. The lanes on the border go through
    /// [`catmull_rom_texel`].
    #[inline(always)]
    pub fn texels(&self, tex: &[f32], width: usize, height: usize, on: u32) -> [Lanes; TEXEL] {
        let inside = self.inside_bits(width, height) & on;
        let mut out = [[0.0; TEXEL]; LANES];
        // The centre taps' counts of the lanes inside ([`centre_counts`]), by tap.
        let mut taps = [[0.0f32; LANES]; 4];
        let v = |a: &Lanes| f32x8::from(*a);
        let weights = self.weights();
        // The lanes inside, by their set bits; then the others on screen.
        let mut todo = inside;
        let mut one = |l: usize, width: usize, first: usize| {
            let rows = footprint_rows(tex, width, first);
            let w = weights[l].to_array();
            // The count channel of this sum is replaced below.
            out[l] = catmull_rom_rows(rows, [w[0], w[1], w[2], w[3]], [w[4], w[5], w[6], w[7]]);
            let c = centre_counts(&rows);
            for (t, c) in taps.iter_mut().zip(c) {
                t[l] = c;
            }
        };
        if tex.len() <= i32::MAX as usize {
            // Every texel index fits in an i32 and `width` in a u32: the index math below
            // cannot overflow, and the compiler drops its overflow checks.
            let first = self.first_texels(width);
            let w32 = width as u32 as usize;
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                one(l, w32, first[l] as usize);
            }
        } else {
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                one(
                    l,
                    width,
                    (self.iy[l] as usize - 1) * width + self.ix[l] as usize - 1,
                );
            }
        }
        let mut border = on & !inside;
        while border != 0 {
            let l = border.trailing_zeros() as usize;
            border &= border - 1;
            out[l] = catmull_rom_texel(tex, width, height, &self.lane(l));
        }
        let [a, b, c, d] = load_texels(&out);
        // The count of the lanes inside: [`catmull_rom_weighted`]'s bilinear, lane by lane.
        let (tx, ty) = (v(&self.tx), v(&self.ty));
        let [c11, c12, c21, c22] = [v(&taps[0]), v(&taps[1]), v(&taps[2]), v(&taps[3])];
        let top = c11 + (c12 - c11) * tx;
        let bottom = c21 + (c22 - c21) * tx;
        let count = top + (bottom - top) * ty;
        [a, b, c, mask_of_bits(inside).select(count, v(&d)).to_array()]
    }

    /// For the lanes set in `on` (lane `l` is bit `l`) of a plane of `T`-float texels:
    /// [`catmull_rom_span`] of the [`SPAN`] channels from float `span_at` of each texel into
    /// `out[l][span_at..]`, and [`bilinear_span`] at the same position of the `N` channels
    /// from float `rest_at` into `out[l][rest_at..]` (e.g. phlm's model: its coefficients
    /// by Catmull-Rom, its information matrix bilinear; floats in neither range are left as
    /// they were); the other lanes' texels are zeros.
    /// The same bits as those functions lane by lane. A lane whose 4x4 footprint lies
    /// inside takes its weights from one 8x8 transpose and its first texel from one vector
    /// multiply (as [`FootprintLanes::texels`]), and its bilinear taps are the footprint's
    /// inner four, at its fractions: nothing of the bilinear position is computed again.
    /// The lanes on the border go through those functions' clamped paths.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    pub fn span_and_bilinear<const T: usize, const N: usize>(
        &self,
        tex: &[f32],
        width: usize,
        height: usize,
        on: u32,
        span_at: usize,
        rest_at: usize,
        out: &mut [[f32; T]; LANES],
    ) {
        let inside = self.inside_bits(width, height) & on;
        let weights = self.weights();
        let mut write = |l: usize, span: [f32; SPAN], rest: [f32; N]| {
            out[l][span_at..span_at + SPAN].copy_from_slice(&span);
            out[l][rest_at..rest_at + N].copy_from_slice(&rest);
        };
        // As in [`FootprintLanes::texels`]: with every texel index in an i32 the index math
        // cannot overflow; the lanes inside then take the fast path.
        let fast = tex.len() <= i32::MAX as usize;
        if fast {
            let firsts = self.first_texels(width);
            let w32 = width as u32 as usize;
            let mut todo = inside;
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let w = weights[l].to_array();
                let (wx, wy) = ([w[0], w[1], w[2], w[3]], [w[4], w[5], w[6], w[7]]);
                let first = firsts[l] as usize;
                let span = span_inside(tex, T, span_at, w32, first, wx, wy);
                // Taps 1 and 2 of rows 1 and 2: the bilinear footprint's top left is one
                // row and one column past the Catmull-Rom one's.
                let t = [self.tx[l], self.ty[l]];
                let rest = bilinear_inside(tex, T, rest_at, w32, first + w32 + 1, t);
                write(l, span, rest);
            }
        }
        // The others on screen, one footprint at a time.
        let mut rest = if fast { on & !inside } else { on };
        while rest != 0 {
            let l = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            let f = self.lane(l);
            let span = catmull_rom_span_of(tex, T, span_at, width, height, &f);
            let bil = bilinear_at(tex, T, rest_at, width, height, [f.x1, f.y1], [f.tx, f.ty]);
            write(l, span, bil);
        }
        let mut off = !on & ((1 << LANES) - 1);
        while off != 0 {
            let l = off.trailing_zeros() as usize;
            off &= off - 1;
            out[l] = [0.0; T];
        }
    }

    /// Each lane's weights as one vector, `wx` in the low half and `wy` in the high (one
    /// 8x8 transpose of the block's).
    #[inline(always)]
    fn weights(&self) -> [f32x8; LANES] {
        let v = |a: &Lanes| f32x8::from(*a);
        let (wx, wy) = (&self.wx, &self.wy);
        f32x8::transpose([
            v(&wx[0]),
            v(&wx[1]),
            v(&wx[2]),
            v(&wx[3]),
            v(&wy[0]),
            v(&wy[1]),
            v(&wy[2]),
            v(&wy[3]),
        ])
    }

    /// Each lane's first footprint texel `(y1 - 1) width + x1 - 1` (row-major), exact for
    /// the lanes whose footprint lies inside the image (any value for the others), in
    /// `i32x8` arithmetic: call only when every texel index of the texture fits in an i32
    /// (inside, the index is below the texture's texel count).
    #[inline(always)]
    fn first_texels(&self, width: usize) -> [u32; LANES] {
        let (ix, iy, one) = (i32x8::from(self.ix), i32x8::from(self.iy), i32x8::splat(1));
        // The products of lanes outside the image wrap, and are not used.
        let first = ((iy - one) * i32x8::splat(width as i32) + (ix - one)).to_array();
        each(|l| first[l] as u32)
    }
}

/// One row's two partial sums of the Catmull-Rom kernel for value `v(i)` at column tap
/// `i`: the inner rows (`inner`) split their four taps into columns 0 and 2 (`lo`) and
/// columns 1 and 3 (`hi`); the outer rows keep their middle two, column 1 in `lo` and 2
/// in `hi`. This pairing is what two adjacent texels in one vector compute (see
/// [`catmull_rom_texel`]), so both functions give the same bits.
#[inline(always)]
fn catmull_rom_row(wx: &[f32; 4], inner: bool, v: impl Fn(usize) -> f32) -> (f32, f32) {
    if inner {
        (wx[0] * v(0) + wx[2] * v(2), wx[1] * v(1) + wx[3] * v(3))
    } else {
        (wx[1] * v(1), wx[2] * v(2))
    }
}

/// Catmull-Rom sample of `N` planes at `(x, y)`: the 4x4 bicubic kernel without its four
/// corner taps, renormalised. This is exactly what the "5-tap" GPU formulation computes
/// with bilinear fetches (Jimenez 2016, used by Karis 2014 and Bevy's TAA); on a CPU the 12
/// taps are read directly. Sharper than bilinear for history reprojection, but it
/// overshoots near edges: callers clip or clamp the result.
///
/// The taps are summed row by row in two halves ([`catmull_rom_row`]), each row scaled by
/// its normalised vertical weight, and the halves added last; [`catmull_rom_texel`] sums
/// in the same order with vectors.
#[inline]
pub fn catmull_rom<const N: usize>(
    planes: [&[f32]; N],
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; N] {
    let f = Footprint::at(x, y);
    let xs = Footprint::clamped(f.x1, width);
    let ys = Footprint::clamped(f.y1, height).map(|r| r * width);
    std::array::from_fn(|c| {
        let p = planes[c];
        let (mut lo, mut hi) = (0.0f32, 0.0f32);
        for (j, &row) in ys.iter().enumerate() {
            let (a, b) = catmull_rom_row(&f.wx, j == 1 || j == 2, |i| p[row + xs[i]]);
            if j == 0 {
                (lo, hi) = (f.wy[0] * a, f.wy[0] * b);
            } else {
                (lo, hi) = (lo + f.wy[j] * a, hi + f.wy[j] * b);
            }
        }
        lo + hi
    })
}

/// Channels of a [`catmull_rom_span`]: twelve (one vector of eight and one of four).
pub const SPAN: usize = 12;

/// [`catmull_rom`] of [`SPAN`] channels that lie side by side in a plane of texels of
/// `stride` floats (`tex[stride * (y * width + x) + first + c]` is channel `c`; e.g. phlm's
/// twelve model coefficients): the same taps, weights and order of sums, so the same bits
/// as [`catmull_rom`] on the channels taken apart as planes. Each tap's channels are one
/// `f32x8` and one `f32x4` load.
#[inline(always)]
pub fn catmull_rom_span(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; SPAN] {
    catmull_rom_span_of(tex, stride, first, width, height, &Footprint::at(x, y))
}

/// [`catmull_rom_span`] with footprint `f` (e.g. a lane of [`FootprintLanes`]).
#[inline(always)]
fn catmull_rom_span_of(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    height: usize,
    f: &Footprint,
) -> [f32; SPAN] {
    if f.inside(width, height) {
        // Inside, `ix` and `iy` are at least 1 and exact.
        let first_texel = (f.iy as usize - 1) * width + f.ix as usize - 1;
        return span_inside(tex, stride, first, width, first_texel, f.wx, f.wy);
    }
    let xs = Footprint::clamped(f.x1, width);
    let ys = Footprint::clamped(f.y1, height).map(|r| r * width);
    span_rows(|r, i| block(tex, (ys[r] + xs[i]) * stride + first), f.wx, f.wy)
}

/// [`catmull_rom_span_of`] of the footprint whose first (top-left) texel is `first_texel`,
/// inside the image, with column weights `wx` and normalised row weights `wy`.
#[inline(always)]
fn span_inside(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    first_texel: usize,
    wx: [f32; 4],
    wy: [f32; 4],
) -> [f32; SPAN] {
    let rs = width * stride;
    let base = first_texel * stride + first;
    let len = 3 * stride + SPAN;
    let win = &tex[base..base + 3 * rs + len];
    let rows: [&[f32]; 4] = std::array::from_fn(|r| &win[r * rs..r * rs + len]);
    span_rows(|r, i| block(rows[r], i * stride), wx, wy)
}

/// [`catmull_rom_span`]'s sums over a footprint with weights `wx`, `wy`, tap `i` of row `r`
/// read by `tap(r, i)` (one slice per footprint row, so that the taps' offsets in it, `i *
/// stride` with `stride` known where this is inlined, need no bounds checks of their own):
/// [`catmull_rom_row`]'s two partial sums for every channel at once, in its order.
#[inline(always)]
fn span_rows<'a>(tap: impl Fn(usize, usize) -> &'a [f32; SPAN], wx: [f32; 4], wy: [f32; 4]) -> [f32; SPAN] {
    /// Channels 0-7 and 8-11.
    #[derive(Clone, Copy)]
    struct V(f32x8, f32x4);
    let load = |v: &[f32; SPAN]| {
        V(
            f32x8::from(*block::<f32, 8>(v, 0)),
            f32x4::from(*block::<f32, 4>(v, 8)),
        )
    };
    let mul = |w: f32, a: V| V(f32x8::splat(w) * a.0, f32x4::splat(w) * a.1);
    let add = |a: V, b: V| V(a.0 + b.0, a.1 + b.1);
    // Row 0 (outer: columns 1 and 2).
    let (a, b) = (mul(wx[1], load(tap(0, 1))), mul(wx[2], load(tap(0, 2))));
    let (mut lo, mut hi) = (mul(wy[0], a), mul(wy[0], b));
    for j in 1..4 {
        let (a, b) = if j == 1 || j == 2 {
            (
                add(mul(wx[0], load(tap(j, 0))), mul(wx[2], load(tap(j, 2)))),
                add(mul(wx[1], load(tap(j, 1))), mul(wx[3], load(tap(j, 3)))),
            )
        } else {
            (mul(wx[1], load(tap(j, 1))), mul(wx[2], load(tap(j, 2))))
        };
        lo = add(lo, mul(wy[j], a));
        hi = add(hi, mul(wy[j], b));
    }
    let mut out = [0.0; SPAN];
    out[..8].copy_from_slice(&(lo.0 + hi.0).to_array());
    out[8..].copy_from_slice(&(lo.1 + hi.1).to_array());
    out
}

/// Channels of one texel of an interleaved history (e.g. Y, Co, Cg and a sample count).
pub const TEXEL: usize = 4;

/// Texel `i` of an interleaved plane.
#[inline(always)]
fn texel(tex: &[f32], i: usize) -> [f32; TEXEL] {
    *<&[f32; TEXEL]>::try_from(&tex[i * TEXEL..i * TEXEL + TEXEL]).expect("a texel")
}

/// [`catmull_rom`] of the first three channels and [`bilinear`] of the fourth, of a plane
/// of interleaved 4-channel texels (`tex[4 * (y * width + x) + c]`), with footprint `f`:
/// the same values, bit for bit, as the planar functions on the planes taken apart.
///
/// A footprint row's four texels are 16 floats; an 8-float vector holds two texels, so a
/// row is two multiplies and an add (inner rows: texels 0 and 1 against 2 and 3) or one
/// multiply (outer rows: texels 1 and 2), each row scaled by its vertical weight into one
/// 8-float sum, whose halves are added at the end.
#[inline(always)]
pub fn catmull_rom_texel(tex: &[f32], width: usize, height: usize, f: &Footprint) -> [f32; TEXEL] {
    if f.inside(width, height) {
        // Inside, `ix` and `iy` are at least 1 (so the casts are exact) and exact.
        return catmull_rom_inside(
            tex,
            width,
            [f.ix as usize, f.iy as usize],
            f.wx,
            f.wy,
            [f.tx, f.ty],
        );
    }
    let xs = Footprint::clamped(f.x1, width);
    let gathered = Footprint::clamped(f.y1, height).map(|y| {
        let mut r = [0.0; 4 * TEXEL];
        for (i, &x) in xs.iter().enumerate() {
            r[i * TEXEL..(i + 1) * TEXEL].copy_from_slice(&texel(tex, y * width + x));
        }
        r
    });
    let mut out = catmull_rom_rows(
        [&gathered[0], &gathered[1], &gathered[2], &gathered[3]],
        f.wx,
        f.wy,
    );
    // The count: bilinear, from bilinear's clamped taps.
    let taps = clamped_taps([f.x1, f.y1], width, height);
    out[TEXEL - 1] = lerp2(taps.map(|i| tex[i * TEXEL + TEXEL - 1]), [f.tx, f.ty]);
    out
}

/// [`catmull_rom_texel`] of a footprint inside the image ([`Footprint::inside`]), whose tap
/// 1 is texel `i1 = [column, row]`: no clamping, each row's four texels in one bounds check.
#[inline(always)]
fn catmull_rom_inside(
    tex: &[f32],
    width: usize,
    i1: [usize; 2],
    wx: [f32; 4],
    wy: [f32; 4],
    t: [f32; 2],
) -> [f32; TEXEL] {
    let first = (i1[1] - 1) * width + i1[0] - 1;
    let w = [wx[0], wx[1], wx[2], wx[3], wy[0], wy[1], wy[2], wy[3]];
    catmull_rom_weighted(tex, width, first, f32x8::from(w), t)
}

/// [`catmull_rom_inside`] from the index of the footprint's first (top-left) texel and the
/// weights in one vector, `wx` then `wy`.
#[inline(always)]
fn catmull_rom_weighted(tex: &[f32], width: usize, first: usize, w: f32x8, t: [f32; 2]) -> [f32; TEXEL] {
    let rows = footprint_rows(tex, width, first);
    let w = w.to_array();
    let mut out = catmull_rom_rows(rows, [w[0], w[1], w[2], w[3]], [w[4], w[5], w[6], w[7]]);
    // The count: bilinear over the four centre taps, which are bilinear's own taps inside
    // the image.
    out[TEXEL - 1] = lerp2(centre_counts(&rows), t);
    out
}

/// The four rows of four texels of a footprint inside the image whose first (top-left)
/// texel is `first`.
#[inline(always)]
fn footprint_rows(tex: &[f32], width: usize, first: usize) -> [&[f32; 4 * TEXEL]; 4] {
    let base = first * TEXEL;
    let stride = width * TEXEL;
    // One bounds check for the whole footprint; the rows inside it are then known to fit.
    let win = &tex[base..base + 3 * stride + 4 * TEXEL];
    [
        block(win, 0),
        block(win, stride),
        block(win, 2 * stride),
        block(win, 3 * stride),
    ]
}

/// The counts (last channel) of a footprint's centre taps: texels 1 and 2 of rows 1 and
/// 2, in the order `[c11, c12, c21, c22]`.
#[inline(always)]
fn centre_counts(rows: &[&[f32; 4 * TEXEL]; 4]) -> [f32; 4] {
    let k = TEXEL - 1;
    [
        rows[1][TEXEL + k],
        rows[1][2 * TEXEL + k],
        rows[2][TEXEL + k],
        rows[2][2 * TEXEL + k],
    ]
}

/// The Catmull-Rom sum of a footprint's four rows of four texels with column weights `wx`
/// and normalised row weights `wy`, every channel (the caller replaces the count).
#[inline(always)]
fn catmull_rom_rows(rows: [&[f32; 4 * TEXEL]; 4], wx: [f32; 4], wy: [f32; 4]) -> [f32; TEXEL] {
    // Column weights per lane: texels 0|1, 2|3 and 1|2 of a row.
    let half = |a: usize| -> f32x8 {
        let (p, q) = (wx[a], wx[a + 1]);
        f32x8::from([p, p, p, p, q, q, q, q])
    };
    let (w01, w23, w12) = (half(0), half(2), half(1));
    let load = |r: &[f32; 4 * TEXEL], at: usize| f32x8::from(*block::<f32, 8>(r, at));
    let inner = |r| w01 * load(r, 0) + w23 * load(r, 2 * TEXEL);
    let outer = |r| w12 * load(r, TEXEL);
    let mut acc = f32x8::splat(wy[0]) * outer(rows[0]);
    acc += f32x8::splat(wy[1]) * inner(rows[1]);
    acc += f32x8::splat(wy[2]) * inner(rows[2]);
    acc += f32x8::splat(wy[3]) * outer(rows[3]);
    let acc = acc.to_array();
    let lo = f32x4::from(*block::<f32, TEXEL>(&acc, 0));
    let hi = f32x4::from(*block::<f32, TEXEL>(&acc, TEXEL));
    (lo + hi).to_array()
}

/// [`catmull_rom_texel`] at one position `(x, y)`.
#[inline]
pub fn catmull_rom_texels(tex: &[f32], width: usize, height: usize, x: f32, y: f32) -> [f32; TEXEL] {
    catmull_rom_texel(tex, width, height, &Footprint::at(x, y))
}

/// [`bilinear`] of channel `c` of an interleaved 4-channel plane.
#[inline]
pub fn bilinear_texel_channel(tex: &[f32], width: usize, height: usize, x: f32, y: f32, c: usize) -> f32 {
    let (x0y0, t) = bilinear_footprint(x, y);
    lerp2(clamped_taps(x0y0, width, height).map(|i| tex[i * TEXEL + c]), t)
}

/// [`bilinear`] of every channel of a plane of interleaved `N`-channel texels (the same
/// bits as the planar function per channel).
#[inline(always)]
pub fn bilinear_texels<const N: usize>(tex: &[f32], width: usize, height: usize, x: f32, y: f32) -> [f32; N] {
    bilinear_span(tex, N, 0, width, height, x, y)
}

/// [`bilinear_texels`] of `N` channels that lie side by side in a plane of texels of
/// `stride` floats, from float `first` of each texel (`tex[stride * (y * width + x) +
/// first + c]` is channel `c`): the same bits as [`bilinear`] on those channels as planes.
#[inline(always)]
pub fn bilinear_span<const N: usize>(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; N] {
    let (x0y0, t) = bilinear_footprint(x, y);
    bilinear_at(tex, stride, first, width, height, x0y0, t)
}

/// [`bilinear_span`] from its top-left tap `x0y0` (whole numbers as f32, possibly outside,
/// huge or NaN) and fractions `t`.
#[inline(always)]
fn bilinear_at<const N: usize>(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    height: usize,
    x0y0: [f32; 2],
    t: [f32; 2],
) -> [f32; N] {
    let [x0, y0] = x0y0;
    if x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < width as f32 && y0 + 1.0 < height as f32 {
        // Inside, `x0` and `y0` are whole, at least 0 and exact.
        return bilinear_inside(tex, stride, first, width, y0 as usize * width + x0 as usize, t);
    }
    bilinear_clamped(tex, stride, first, width, height, x0y0, t)
}

/// [`bilinear_texels`] of a 2x2 footprint inside the image, whose top-left tap is texel
/// `top_left` (row-major): no clamping, each row's two texels in one bounds check.
#[inline(always)]
fn bilinear_inside<const N: usize>(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    top_left: usize,
    t: [f32; 2],
) -> [f32; N] {
    let a = top_left * stride + first;
    // One bounds check for both rows.
    let win = &tex[a..a + width * stride + stride + N];
    let (r0, r1) = (&win[..stride + N], &win[width * stride..]);
    let mut out = [0.0; N];
    // Eight, then four channels at a time in vectors (the same operations per channel),
    // the rest one by one.
    let eights = N / 8 * 8;
    let (tx8, ty8) = (f32x8::splat(t[0]), f32x8::splat(t[1]));
    let at8 = |r: &[f32], i: usize| f32x8::from(*block::<f32, 8>(r, i));
    for c in (0..eights).step_by(8) {
        let (p00, p10, p01, p11) = (at8(r0, c), at8(r0, stride + c), at8(r1, c), at8(r1, stride + c));
        let top = p00 + (p10 - p00) * tx8;
        let bottom = p01 + (p11 - p01) * tx8;
        out[c..c + 8].copy_from_slice(&(top + (bottom - top) * ty8).to_array());
    }
    let whole = eights + (N - eights) / 4 * 4;
    let (tx, ty) = (f32x4::splat(t[0]), f32x4::splat(t[1]));
    let at = |r: &[f32], i: usize| f32x4::from(*block::<f32, 4>(r, i));
    for c in (eights..whole).step_by(4) {
        let (p00, p10, p01, p11) = (at(r0, c), at(r0, stride + c), at(r1, c), at(r1, stride + c));
        let top = p00 + (p10 - p00) * tx;
        let bottom = p01 + (p11 - p01) * tx;
        out[c..c + 4].copy_from_slice(&(top + (bottom - top) * ty).to_array());
    }
    for c in whole..N {
        out[c] = lerp2([r0[c], r0[stride + c], r1[c], r1[stride + c]], t);
    }
    out
}

/// [`bilinear_texels`] from the top-left tap `x0y0` (whole numbers as f32, possibly
/// outside, huge or NaN), the taps clamped into the image.
#[inline(always)]
fn bilinear_clamped<const N: usize>(
    tex: &[f32],
    stride: usize,
    first: usize,
    width: usize,
    height: usize,
    x0y0: [f32; 2],
    t: [f32; 2],
) -> [f32; N] {
    let at = |i: usize| -> &[f32; N] { block(tex, i * stride + first) };
    let [p00, p10, p01, p11] = clamped_taps(x0y0, width, height).map(at);
    std::array::from_fn(|c| lerp2([p00[c], p10[c], p01[c], p11[c]], t))
}

/// The bilinear footprints of eight positions, one per lane: [`bilinear_texels`]'s
/// top-left taps, fractions and inside test, lane by lane (the same operations, so the
/// same bits), in vector instructions.
#[derive(Clone, Copy, Debug)]
pub struct BilinearLanes {
    x0: Lanes,
    y0: Lanes,
    ix: [i32; LANES],
    iy: [i32; LANES],
    tx: Lanes,
    ty: Lanes,
    /// Lanes whose 2x2 footprint lies inside the image (lane `l` is bit `l`).
    inside: u32,
}

impl BilinearLanes {
    /// The footprints of positions `(x[l], y[l])` in a `width` x `height` image.
    #[inline(always)]
    pub fn at(x: &Lanes, y: &Lanes, width: usize, height: usize) -> Self {
        let half = f32x8::splat(0.5);
        let fx = f32x8::from(*x) - half;
        let fy = f32x8::from(*y) - half;
        let (x0, y0) = (fx.floor(), fy.floor());
        let (zero, one) = (f32x8::splat(0.0), f32x8::splat(1.0));
        let inside = x0.simd_ge(zero)
            & y0.simd_ge(zero)
            & (x0 + one).simd_lt(f32x8::splat(width as f32))
            & (y0 + one).simd_lt(f32x8::splat(height as f32));
        BilinearLanes {
            x0: x0.to_array(),
            y0: y0.to_array(),
            ix: x0.trunc_int().to_array(),
            iy: y0.trunc_int().to_array(),
            tx: (fx - x0).to_array(),
            ty: (fy - y0).to_array(),
            inside: inside.to_bitmask(),
        }
    }

    /// [`bilinear_texels`] of lane `l`'s position.
    #[inline(always)]
    pub fn texel<const N: usize>(&self, tex: &[f32], width: usize, height: usize, l: usize) -> [f32; N] {
        let t = [self.tx[l], self.ty[l]];
        if self.inside >> l & 1 != 0 {
            // Inside, the taps are at least 0 and exact.
            bilinear_inside(
                tex,
                N,
                0,
                width,
                self.iy[l] as usize * width + self.ix[l] as usize,
                t,
            )
        } else {
            bilinear_clamped(tex, N, 0, width, height, [self.x0[l], self.y0[l]], t)
        }
    }
}

impl BilinearLanes {
    /// [`bilinear_texels`] of the lanes set in `on` (lane `l` is bit `l`; zero texels in
    /// the others) of a plane of `N`-channel texels, `N` at most 4, each in four values
    /// (those past `N` unspecified). A lane inside the image reads its four taps as four
    /// 4-float vectors (past the texel for `N` < 4) and weights them in one vector each,
    /// where [`bilinear_inside`] went channel by channel; its index comes from one `i32x8`
    /// multiply for the block.
    #[inline(always)]
    pub fn texels4<const N: usize>(
        &self,
        tex: &[f32],
        width: usize,
        height: usize,
        on: u32,
    ) -> [[f32; 4]; LANES] {
        const { assert!(N >= 1 && N <= 4) };
        let pad = |t: [f32; N]| -> [f32; 4] {
            let mut o = [0.0; 4];
            o[..N].copy_from_slice(&t);
            o
        };
        let mut out = [[0.0; 4]; LANES];
        let inside = self.inside & on;
        let mut todo = inside;
        if tex.len() <= i32::MAX as usize {
            // Every index fits in an i32 and `width` in a u32: no overflow checks below.
            let (ix, iy) = (i32x8::from(self.ix), i32x8::from(self.iy));
            let first = (iy * i32x8::splat(width as i32) + ix).to_array();
            let row = width as u32 as usize * N;
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let a = first[l] as u32 as usize * N;
                let t = [self.tx[l], self.ty[l]];
                out[l] = match tex.get(a..a + row + N + 4) {
                    Some(win) => {
                        let at = |i: usize| f32x4::from(*block::<f32, 4>(win, i));
                        let (p00, p10, p01, p11) = (at(0), at(N), at(row), at(row + N));
                        let (tx, ty) = (f32x4::splat(t[0]), f32x4::splat(t[1]));
                        let top = p00 + (p10 - p00) * tx;
                        let bottom = p01 + (p11 - p01) * tx;
                        (top + (bottom - top) * ty).to_array()
                    }
                    // The last texels of the plane: no vector reads past them.
                    None => pad(self.texel::<N>(tex, width, height, l)),
                };
            }
        }
        // Lanes inside left from above (a plane too large for i32 indices), then the
        // lanes on the border.
        let mut rest = on & !(inside & !todo);
        while rest != 0 {
            let l = rest.trailing_zeros() as usize;
            rest &= rest - 1;
            out[l] = pad(self.texel::<N>(tex, width, height, l));
        }
        out
    }
}

/// The texel of an interleaved `N`-channel plane nearest to `(x, y)` (the pixel holding
/// it, clamped into the image).
#[inline]
pub fn nearest_texel<const N: usize>(tex: &[f32], width: usize, height: usize, x: f32, y: f32) -> [f32; N] {
    let j = (y.max(0.0) as usize).min(height - 1) * width + (x.max(0.0) as usize).min(width - 1);
    *<&[f32; N]>::try_from(&tex[j * N..j * N + N]).expect("a texel")
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    /// f64 bilinear with clamped edges, written from the definition (the reference other
    /// kernels' tests sample with, too).
    pub(crate) fn bilinear_f64(p: &[f64], w: usize, h: usize, x: f64, y: f64) -> f64 {
        let at = |i: f64, j: f64| {
            let i = i.clamp(0.0, w as f64 - 1.0) as usize;
            let j = j.clamp(0.0, h as f64 - 1.0) as usize;
            p[j * w + i]
        };
        let (fx, fy) = (x - 0.5, y - 0.5);
        let (i, j) = (fx.floor(), fy.floor());
        let (tx, ty) = (fx - i, fy - j);
        at(i, j) * (1.0 - tx) * (1.0 - ty)
            + at(i + 1.0, j) * tx * (1.0 - ty)
            + at(i, j + 1.0) * (1.0 - tx) * ty
            + at(i + 1.0, j + 1.0) * tx * ty
    }

    /// The GPU 5-tap formulation (five bilinear fetches) in f64: an independent route to
    /// the same function as [`catmull_rom`].
    fn catmull_rom_5tap_f64(p: &[f64], w: usize, h: usize, x: f64, y: f64) -> f64 {
        let weights = |t: f64| {
            [
                t * (-0.5 + t * (1.0 - 0.5 * t)),
                1.0 + t * t * (-2.5 + 1.5 * t),
                t * (0.5 + t * (2.0 - 1.5 * t)),
                t * t * (-0.5 + 0.5 * t),
            ]
        };
        let pos1 = [(x - 0.5).floor() + 0.5, (y - 0.5).floor() + 0.5];
        let wx = weights(x - pos1[0]);
        let wy = weights(y - pos1[1]);
        let (w12x, w12y) = (wx[1] + wx[2], wy[1] + wy[2]);
        let p12 = [pos1[0] + wx[2] / w12x, pos1[1] + wy[2] / w12y];
        let (p0, p3) = ([pos1[0] - 1.0, pos1[1] - 1.0], [pos1[0] + 2.0, pos1[1] + 2.0]);
        let taps = [
            (p12[0], p0[1], w12x * wy[0]),
            (p0[0], p12[1], wx[0] * w12y),
            (p12[0], p12[1], w12x * w12y),
            (p3[0], p12[1], wx[3] * w12y),
            (p12[0], p3[1], w12x * wy[3]),
        ];
        let (mut acc, mut wsum) = (0.0, 0.0);
        for (tx, ty, wt) in taps {
            acc += wt * bilinear_f64(p, w, h, tx, ty);
            wsum += wt;
        }
        acc / wsum
    }

    fn random_plane(rng: &mut SplitMix64, w: usize, h: usize) -> Vec<f32> {
        (0..w * h).map(|_| rng.next_f64() as f32).collect()
    }

    #[test]
    fn catmull_rom_span_gives_the_planar_bits() {
        let mut rng = SplitMix64::new(41);
        for (w, h) in [(1, 1), (2, 1), (1, 3), (7, 5), (13, 9)] {
            const N: usize = SPAN;
            let (stride, first) = (N + 3, 2);
            let tex: Vec<f32> = (0..w * h * stride)
                .map(|_| (rng.next_f64() * 4.0 - 1.0) as f32)
                .collect();
            let planes: Vec<Vec<f32>> = (0..N)
                .map(|c| (0..w * h).map(|i| tex[i * stride + first + c]).collect())
                .collect();
            let planes: [&[f32]; N] = std::array::from_fn(|c| &planes[c][..]);
            for _ in 0..300 {
                // Inside, on the border and off the image.
                let x = (rng.next_f64() * (w + 4) as f64 - 2.0) as f32;
                let y = (rng.next_f64() * (h + 4) as f64 - 2.0) as f32;
                let want = catmull_rom(planes, w, h, x, y).map(f32::to_bits);
                let got = catmull_rom_span(&tex, stride, first, w, h, x, y).map(f32::to_bits);
                assert_eq!(got, want, "{w}x{h} at ({x}, {y})");
            }
        }
    }

    #[test]
    fn footprint_lanes_span_and_bilinear_give_each_lanes_span_and_bilinear() {
        const T: usize = SPAN + 13 + 2;
        const N: usize = 13;
        let mut rng = SplitMix64::new(43);
        for (w, h) in [(1, 1), (2, 1), (3, 2), (4, 4), (9, 7), (37, 5)] {
            let tex: Vec<f32> = (0..w * h * T)
                .map(|_| (rng.next_f64() * 4.0 - 1.0) as f32)
                .collect();
            for case in 0..150 {
                let mut r = |n: usize| -> Lanes { each(|_| (rng.next_f64() * (n + 6) as f64 - 3.0) as f32) };
                let (mut x, mut y) = (r(w), r(h));
                if case % 10 == 0 {
                    // Whole and half positions (taps exactly on texels), and wild ones.
                    x = each(|l| [0.5, 1.0, 2.5, -0.5, f32::NAN, 1e30, -1e30, w as f32][l]);
                    y = each(|l| [0.5, 1.5, 1.0, 3.0, 0.5, f32::INFINITY, 2.0, h as f32 - 0.5][l]);
                }
                let on = (rng.next_f64() * 256.0) as u32 & 0xff;
                // Stale values in every texel: the lanes off must come back zero.
                let mut got = [[7.0; T]; LANES];
                FootprintLanes::at(&x, &y).span_and_bilinear::<T, N>(&tex, w, h, on, 2, SPAN + 2, &mut got);
                for l in 0..LANES {
                    let mut want = [0.0; T];
                    if on >> l & 1 != 0 {
                        // The floats outside both ranges are left as they were.
                        want[..2].fill(7.0);
                        want[2..2 + SPAN].copy_from_slice(&catmull_rom_span(&tex, T, 2, w, h, x[l], y[l]));
                        want[SPAN + 2..].copy_from_slice(&bilinear_span::<N>(
                            &tex,
                            T,
                            SPAN + 2,
                            w,
                            h,
                            x[l],
                            y[l],
                        ));
                    }
                    assert_eq!(
                        got[l].map(f32::to_bits),
                        want.map(f32::to_bits),
                        "{w}x{h} lane {l} at ({}, {})",
                        x[l],
                        y[l]
                    );
                }
            }
        }
    }

    #[test]
    fn catmull_rom_matches_the_5_tap_bilinear_formulation() {
        let mut rng = SplitMix64::new(11);
        let (w, h) = (13, 9);
        let a = random_plane(&mut rng, w, h);
        let b: Vec<f32> = a.iter().map(|v| 1e4 * v * v).collect();
        let (a64, b64): (Vec<f64>, Vec<f64>) = (
            a.iter().map(|&v| v as f64).collect(),
            b.iter().map(|&v| v as f64).collect(),
        );
        for _ in 0..20_000 {
            // Positions inside, at the edges and far outside the image.
            let x = rng.range(-3.0, w as f64 + 3.0);
            let y = rng.range(-3.0, h as f64 + 3.0);
            let got = catmull_rom([&a, &b], w, h, x as f32, y as f32);
            // The position is rounded to f32 before both evaluations.
            let (xf, yf) = (x as f32 as f64, y as f32 as f64);
            Tolerance::new(2e-6, 1e-5)
                .check("plane a", got[0] as f64, catmull_rom_5tap_f64(&a64, w, h, xf, yf))
                .unwrap();
            Tolerance::new(2e-2, 1e-5)
                .check("plane b", got[1] as f64, catmull_rom_5tap_f64(&b64, w, h, xf, yf))
                .unwrap();
        }
    }

    #[test]
    fn resamplers_are_exact_at_pixel_centres_and_on_linear_ramps() {
        let (w, h) = (7, 5);
        let mut rng = SplitMix64::new(12);
        let p = random_plane(&mut rng, w, h);
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f32 + 0.5, y as f32 + 0.5);
                assert_eq!(catmull_rom([&p], w, h, fx, fy)[0], p[y * w + x]);
                assert_eq!(bilinear([&p], w, h, fx, fy)[0], p[y * w + x]);
            }
        }
        // Bilinear reproduces a linear ramp inside the image; Catmull-Rom without its
        // corner taps is renormalised, so it reproduces a constant exactly.
        let ramp: Vec<f32> = (0..w * h)
            .map(|i| (i % w) as f32 * 0.5 + (i / w) as f32 * 0.25)
            .collect();
        let flat = vec![0.375f32; w * h];
        for _ in 0..1000 {
            let x = rng.range(0.5, w as f64 - 0.5) as f32;
            let y = rng.range(0.5, h as f64 - 0.5) as f32;
            let expect = ((x - 0.5) * 0.5 + (y - 0.5) * 0.25) as f64;
            Tolerance::abs(1e-5)
                .check("bl", bilinear([&ramp], w, h, x, y)[0] as f64, expect)
                .unwrap();
            let x = rng.range(-2.0, w as f64 + 2.0) as f32;
            Tolerance::abs(1e-6)
                .check("cr", catmull_rom([&flat], w, h, x, y)[0] as f64, 0.375)
                .unwrap();
        }
    }

    #[test]
    fn bilinear_matches_f64_and_survives_wild_positions() {
        let mut rng = SplitMix64::new(13);
        let (w, h) = (6, 4);
        let p = random_plane(&mut rng, w, h);
        let p64: Vec<f64> = p.iter().map(|&v| v as f64).collect();
        for _ in 0..10_000 {
            let x = rng.range(-2.0, 8.0);
            let y = rng.range(-2.0, 6.0);
            let got = bilinear([&p], w, h, x as f32, y as f32)[0] as f64;
            let expect = bilinear_f64(&p64, w, h, x as f32 as f64, y as f32 as f64);
            Tolerance::abs(1e-6).check("bilinear", got, expect).unwrap();
        }
        for (x, y) in [(f32::NAN, 1.0), (f32::INFINITY, -f32::INFINITY), (1e30, -1e30)] {
            // No panic; the value is some clamped texel mix (NaN weights give NaN, which
            // callers never produce: they test positions before fetching).
            let _ = bilinear([&p], w, h, x, y);
            let _ = catmull_rom([&p], w, h, x, y);
        }
    }

    #[test]
    fn footprint_lanes_texels_give_each_lanes_scalar_texel() {
        let mut rng = SplitMix64::new(16);
        let wild = [f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30, -1e30, -0.0, 0.5];
        for (w, h) in [(1, 1), (1, 7), (2, 3), (5, 4), (13, 9), (37, 6)] {
            let tex: Vec<f32> = (0..w * h * TEXEL)
                .map(|i| (rng.next_f64() as f32 - 0.25) * [1.0, 1e4, 1e-4, 255.0][i % TEXEL])
                .collect();
            for k in 0..3000 {
                // Mostly inside, some on and past the border, exact centres, wild values.
                let pick = |rng: &mut SplitMix64, l: usize, n: usize| -> f32 {
                    match (k + l) % 11 {
                        0 => wild[(k + 3 * l) % wild.len()],
                        1 => ((k + l) % (n + 2)) as f32 - 0.5,
                        _ => rng.range(-2.0, n as f64 + 2.0) as f32,
                    }
                };
                let x: Lanes = each(|l| pick(&mut rng, l, w));
                let y: Lanes = each(|l| pick(&mut rng, l + 5, h));
                let on = (k as u32).wrapping_mul(0x9e37_79b9) >> 24 | if k % 3 == 0 { 0xff } else { 0 };
                let got = FootprintLanes::at(&x, &y).texels(&tex, w, h, on);
                for l in 0..LANES {
                    let got = [got[0][l], got[1][l], got[2][l], got[3][l]];
                    let want = if on >> l & 1 != 0 {
                        catmull_rom_texels(&tex, w, h, x[l], y[l])
                    } else {
                        [0.0; TEXEL]
                    };
                    let bits = |v: &[f32; TEXEL]| v.map(f32::to_bits);
                    assert_eq!(
                        bits(&got),
                        bits(&want),
                        "{w}x{h} lane {l} at ({}, {})",
                        x[l],
                        y[l]
                    );
                }
            }
        }
    }

    #[test]
    fn bilinear_lanes_texels4_give_each_lanes_scalar_texel() {
        fn case<const N: usize>(rng: &mut SplitMix64) {
            let wild = [f32::NAN, f32::INFINITY, -f32::INFINITY, 1e30, -1e30, -0.0, 0.5];
            for (w, h) in [(1, 1), (1, 7), (2, 3), (5, 4), (13, 9), (37, 6)] {
                let tex: Vec<f32> = (0..w * h * N).map(|_| rng.range(-1.0, 3.0) as f32).collect();
                for k in 0..2000 {
                    // Mostly inside, some on and past the border (the plane's last texels
                    // too), exact centres, wild values.
                    let pick = |rng: &mut SplitMix64, l: usize, n: usize| -> f32 {
                        match (k + l) % 11 {
                            0 => wild[(k + 3 * l) % wild.len()],
                            1 => ((k + l) % (n + 2)) as f32 - 0.5,
                            2 => n as f32 - rng.range(0.0, 1.5) as f32,
                            _ => rng.range(-2.0, n as f64 + 2.0) as f32,
                        }
                    };
                    let x: Lanes = each(|l| pick(rng, l, w));
                    let y: Lanes = each(|l| pick(rng, l + 5, h));
                    let on = (k as u32).wrapping_mul(0x9e37_79b9) >> 24 | if k % 3 == 0 { 0xff } else { 0 };
                    let got = BilinearLanes::at(&x, &y, w, h).texels4::<N>(&tex, w, h, on);
                    for l in 0..LANES {
                        let want = if on >> l & 1 != 0 {
                            bilinear_texels::<N>(&tex, w, h, x[l], y[l])
                        } else {
                            [0.0; N]
                        };
                        let (got, want) = (got[l][..N].to_vec(), want.to_vec());
                        let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
                        assert_eq!(
                            bits(got),
                            bits(want),
                            "N {N} {w}x{h} lane {l} at ({}, {})",
                            x[l],
                            y[l]
                        );
                    }
                }
            }
        }
        let mut rng = SplitMix64::new(17);
        case::<1>(&mut rng);
        case::<3>(&mut rng);
        case::<4>(&mut rng);
    }

    #[test]
    fn footprint_lanes_give_each_lanes_scalar_footprint() {
        let mut rng = SplitMix64::new(15);
        let wild = [
            f32::NAN,
            f32::INFINITY,
            -f32::INFINITY,
            1e30,
            -1e30,
            0.0,
            -0.0,
            0.5,
            16_777_217.0,
            f32::MIN_POSITIVE,
        ];
        for k in 0..2000 {
            let pick = |rng: &mut SplitMix64, l: usize| {
                if (k + l).is_multiple_of(7) {
                    wild[(k * 3 + l) % wild.len()]
                } else {
                    rng.range(-4.0, 1924.0) as f32
                }
            };
            let x: Lanes = each(|l| pick(&mut rng, l));
            let y: Lanes = each(|l| pick(&mut rng, l + 1));
            let lanes = FootprintLanes::at(&x, &y);
            for l in 0..LANES {
                let (got, want) = (lanes.lane(l), Footprint::at(x[l], y[l]));
                let bits = |f: &Footprint| {
                    let mut v = vec![f.x1, f.y1, f.tx, f.ty];
                    v.extend(f.wx.iter().chain(&f.wy));
                    let mut bits: Vec<u32> = v.into_iter().map(f32::to_bits).collect();
                    bits.extend([f.ix as u32, f.iy as u32]);
                    bits
                };
                assert_eq!(bits(&got), bits(&want), "lane {l} at ({}, {})", x[l], y[l]);
            }
        }
    }

    #[test]
    fn interleaved_resamplers_give_the_planar_bits() {
        let mut rng = SplitMix64::new(14);
        for (w, h) in [(1, 1), (2, 3), (5, 4), (13, 9)] {
            let planes: Vec<Vec<f32>> = (0..TEXEL)
                .map(|c| {
                    (0..w * h)
                        .map(|_| (rng.next_f64() as f32 - 0.25) * [1.0, 1e4, 1e-4, 255.0][c])
                        .collect()
                })
                .collect();
            let tex: Vec<f32> = (0..w * h)
                .flat_map(|i| (0..TEXEL).map(|c| planes[c][i]).collect::<Vec<_>>())
                .collect();
            let p = [&planes[0][..], &planes[1][..], &planes[2][..]];
            for k in 0..4000 {
                // Inside, on the border, outside, and on exact pixel centres and edges.
                let (x, y) = if k % 5 == 0 {
                    ((k % (w + 2)) as f32 - 0.5, (k / 7 % (h + 2)) as f32)
                } else {
                    (
                        rng.range(-2.0, w as f64 + 2.0) as f32,
                        rng.range(-2.0, h as f64 + 2.0) as f32,
                    )
                };
                let got = catmull_rom_texels(&tex, w, h, x, y);
                let want = catmull_rom(p, w, h, x, y);
                let count = bilinear([&planes[3][..]], w, h, x, y)[0];
                let bits = |v: &[f32]| v.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&got[..3]), bits(&want), "{w}x{h} at ({x}, {y})");
                assert_eq!(got[3].to_bits(), count.to_bits(), "{w}x{h} count at ({x}, {y})");
                let bl = bilinear_texels::<TEXEL>(&tex, w, h, x, y);
                let want4 = bilinear(
                    [&planes[0][..], &planes[1][..], &planes[2][..], &planes[3][..]],
                    w,
                    h,
                    x,
                    y,
                );
                assert_eq!(bits(&bl), bits(&want4), "{w}x{h} bilinear at ({x}, {y})");
                for c in 0..TEXEL {
                    assert_eq!(
                        bilinear_texel_channel(&tex, w, h, x, y, c).to_bits(),
                        want4[c].to_bits()
                    );
                }
            }
        }
    }
}
