//! Resampling of history planes at sub-pixel positions: bilinear and Catmull-Rom.

/// Bilinear sample of `N` planes at `(x, y)` (pixel units, centres at +0.5, edges extended).
#[inline]
pub fn bilinear<const N: usize>(
    planes: [&[f32]; N],
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; N] {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x0 = fx.floor();
    let y0 = fy.floor();
    let tx = fx - x0;
    let ty = fy - y0;
    if x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < width as f32 && y0 + 1.0 < height as f32 {
        // The 2x2 footprint is inside: no clamping.
        let a = y0 as usize * width + x0 as usize;
        let b = a + width;
        let mut out = [0.0; N];
        for (o, p) in out.iter_mut().zip(planes) {
            let (r0, r1) = (&p[a..a + 2], &p[b..b + 2]);
            let top = r0[0] + (r0[1] - r0[0]) * tx;
            let bottom = r1[0] + (r1[1] - r1[0]) * tx;
            *o = top + (bottom - top) * ty;
        }
        return out;
    }
    let xa = clamp_index(x0, width);
    let xb = clamp_index(x0 + 1.0, width);
    let ya = clamp_index(y0, height) * width;
    let yb = clamp_index(y0 + 1.0, height) * width;
    planes.map(|p| {
        let top = p[ya + xa] + (p[ya + xb] - p[ya + xa]) * tx;
        let bottom = p[yb + xa] + (p[yb + xb] - p[yb + xa]) * tx;
        top + (bottom - top) * ty
    })
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

/// Catmull-Rom sample of `N` planes at `(x, y)`: the 4x4 bicubic kernel without its four
/// corner taps, renormalised. This is exactly what the "5-tap" GPU formulation computes
/// with bilinear fetches (Jimenez 2016, used by Karis 2014 and Bevy's TAA); on a CPU the 12
/// taps are read directly. Sharper than bilinear for history reprojection, but it
/// overshoots near edges: callers clip or clamp the result.
#[inline]
pub fn catmull_rom<const N: usize>(
    planes: [&[f32]; N],
    width: usize,
    height: usize,
    x: f32,
    y: f32,
) -> [f32; N] {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x1 = fx.floor();
    let y1 = fy.floor();
    let wx = catmull_rom_weights(fx - x1);
    let wy = catmull_rom_weights(fy - y1);
    if x1 >= 1.0 && y1 >= 1.0 && x1 + 2.0 < width as f32 && y1 + 2.0 < height as f32 {
        // The whole 4x4 footprint is inside: no clamping, one base index.
        let base = (y1 as usize - 1) * width + x1 as usize - 1;
        let mut acc = [0.0f32; N];
        let mut wsum = 0.0f32;
        for (j, wyj) in wy.iter().enumerate() {
            let (lo, hi) = if j == 0 || j == 3 { (1, 3) } else { (0, 4) };
            let row = base + j * width;
            for (i, wxi) in wx.iter().enumerate().take(hi).skip(lo) {
                let wgt = wxi * wyj;
                wsum += wgt;
                for (a, p) in acc.iter_mut().zip(planes.iter()) {
                    *a += wgt * p[row + i];
                }
            }
        }
        return acc.map(|a| a / wsum);
    }
    let xs = [-1.0, 0.0, 1.0, 2.0].map(|d| clamp_index(x1 + d, width));
    let ys = [-1.0, 0.0, 1.0, 2.0].map(|d| clamp_index(y1 + d, height) * width);
    let mut acc = [0.0f32; N];
    let mut wsum = 0.0f32;
    for (j, &row) in ys.iter().enumerate() {
        // Corner taps are dropped: rows 0 and 3 use only the middle two columns.
        let cols = if j == 0 || j == 3 { 1..3 } else { 0..4 };
        for i in cols {
            let w = wx[i] * wy[j];
            wsum += w;
            for (a, p) in acc.iter_mut().zip(planes.iter()) {
                *a += w * p[row + xs[i]];
            }
        }
    }
    acc.map(|a| a / wsum)
}

/// Channels of one texel of an interleaved history (e.g. Y, Co, Cg and a sample count).
pub const TEXEL: usize = 4;

/// Texel `i` of an interleaved plane.
#[inline(always)]
fn texel(tex: &[f32], i: usize) -> [f32; TEXEL] {
    *<&[f32; TEXEL]>::try_from(&tex[i * TEXEL..i * TEXEL + TEXEL]).expect("a texel")
}

/// `acc + w * t` per channel (a multiply, then an add: the compiler keeps the two
/// roundings of the scalar code, so this is exactly four scalar steps, in one vector).
#[inline(always)]
fn accumulate(acc: [f32; TEXEL], w: f32, t: [f32; TEXEL]) -> [f32; TEXEL] {
    std::array::from_fn(|c| acc[c] + w * t[c])
}

/// [`catmull_rom`] of the first three channels and [`bilinear`] of the fourth, of a plane
/// of interleaved 4-channel texels (`tex[4 * (y * width + x) + c]`), at `(x, y)`: the
/// same values, bit for bit, as the planar functions on the planes taken apart, with one
/// vector load and one vector multiply-add per tap instead of four of each.
#[inline]
pub fn catmull_rom_texels(tex: &[f32], width: usize, height: usize, x: f32, y: f32) -> [f32; TEXEL] {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x1 = fx.floor();
    let y1 = fy.floor();
    let (tx, ty) = (fx - x1, fy - y1);
    let wx = catmull_rom_weights(tx);
    let wy = catmull_rom_weights(ty);
    if x1 >= 1.0 && y1 >= 1.0 && x1 + 2.0 < width as f32 && y1 + 2.0 < height as f32 {
        // The whole 4x4 footprint is inside: each row's four texels in one bounds check,
        // the taps in the planar function's order (rows 0..4, corners dropped).
        let base = (y1 as usize - 1) * width + x1 as usize - 1;
        let row = |j: usize| -> &[f32; 4 * TEXEL] {
            let at = (base + j * width) * TEXEL;
            tex[at..at + 4 * TEXEL].try_into().expect("four texels")
        };
        let tap =
            |r: &[f32; 4 * TEXEL], i: usize| -> [f32; TEXEL] { std::array::from_fn(|c| r[i * TEXEL + c]) };
        let (r0, r1, r2, r3) = (row(0), row(1), row(2), row(3));
        let mut acc = [0.0f32; TEXEL];
        let mut wsum = 0.0f32;
        let mut add = |w: f32, t: [f32; TEXEL]| {
            wsum += w;
            acc = accumulate(acc, w, t);
        };
        add(wx[1] * wy[0], tap(r0, 1));
        add(wx[2] * wy[0], tap(r0, 2));
        let (c11, c12) = (tap(r1, 1), tap(r1, 2));
        add(wx[0] * wy[1], tap(r1, 0));
        add(wx[1] * wy[1], c11);
        add(wx[2] * wy[1], c12);
        add(wx[3] * wy[1], tap(r1, 3));
        let (c21, c22) = (tap(r2, 1), tap(r2, 2));
        add(wx[0] * wy[2], tap(r2, 0));
        add(wx[1] * wy[2], c21);
        add(wx[2] * wy[2], c22);
        add(wx[3] * wy[2], tap(r2, 3));
        add(wx[1] * wy[3], tap(r3, 1));
        add(wx[2] * wy[3], tap(r3, 2));
        let mut out = acc.map(|a| a / wsum);
        // The count: bilinear over the four centre taps, which are bilinear's own taps here.
        let k = TEXEL - 1;
        let top = c11[k] + (c12[k] - c11[k]) * tx;
        let bottom = c21[k] + (c22[k] - c21[k]) * tx;
        out[k] = top + (bottom - top) * ty;
        return out;
    }
    let xs = [-1.0, 0.0, 1.0, 2.0].map(|d| clamp_index(x1 + d, width));
    let ys = [-1.0, 0.0, 1.0, 2.0].map(|d| clamp_index(y1 + d, height) * width);
    let mut acc = [0.0f32; TEXEL];
    let mut wsum = 0.0f32;
    for (j, &row) in ys.iter().enumerate() {
        let cols = if j == 0 || j == 3 { 1..3 } else { 0..4 };
        for i in cols {
            let wgt = wx[i] * wy[j];
            wsum += wgt;
            acc = accumulate(acc, wgt, texel(tex, row + xs[i]));
        }
    }
    let mut out = acc.map(|a| a / wsum);
    // At the border bilinear clamps its taps on its own.
    out[TEXEL - 1] = bilinear_texel_channel(tex, width, height, x, y, TEXEL - 1);
    out
}

/// [`bilinear`] of channel `c` of an interleaved 4-channel plane.
#[inline]
pub fn bilinear_texel_channel(tex: &[f32], width: usize, height: usize, x: f32, y: f32, c: usize) -> f32 {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x0 = fx.floor();
    let y0 = fy.floor();
    let tx = fx - x0;
    let ty = fy - y0;
    let xa = clamp_index(x0, width);
    let xb = clamp_index(x0 + 1.0, width);
    let ya = clamp_index(y0, height) * width;
    let yb = clamp_index(y0 + 1.0, height) * width;
    let p = |i: usize| tex[i * TEXEL + c];
    let top = p(ya + xa) + (p(ya + xb) - p(ya + xa)) * tx;
    let bottom = p(yb + xa) + (p(yb + xb) - p(yb + xa)) * tx;
    top + (bottom - top) * ty
}

/// [`bilinear`] of every channel of a plane of interleaved `N`-channel texels (the same
/// bits as the planar function per channel).
#[inline]
pub fn bilinear_texels<const N: usize>(tex: &[f32], width: usize, height: usize, x: f32, y: f32) -> [f32; N] {
    let fx = x - 0.5;
    let fy = y - 0.5;
    let x0 = fx.floor();
    let y0 = fy.floor();
    let tx = fx - x0;
    let ty = fy - y0;
    if x0 >= 0.0 && y0 >= 0.0 && x0 + 1.0 < width as f32 && y0 + 1.0 < height as f32 {
        // The 2x2 footprint is inside: no clamping, each row's two texels in one bounds
        // check.
        let a = (y0 as usize * width + x0 as usize) * N;
        let b = a + width * N;
        let (r0, r1) = (&tex[a..a + 2 * N], &tex[b..b + 2 * N]);
        let mut out = [0.0; N];
        for (c, o) in out.iter_mut().enumerate() {
            let top = r0[c] + (r0[N + c] - r0[c]) * tx;
            let bottom = r1[c] + (r1[N + c] - r1[c]) * tx;
            *o = top + (bottom - top) * ty;
        }
        return out;
    }
    let xa = clamp_index(x0, width);
    let xb = clamp_index(x0 + 1.0, width);
    let ya = clamp_index(y0, height) * width;
    let yb = clamp_index(y0 + 1.0, height) * width;
    let at = |i: usize| -> &[f32; N] { tex[i * N..i * N + N].try_into().expect("a texel") };
    let [p00, p10, p01, p11] = [ya + xa, ya + xb, yb + xa, yb + xb].map(at);
    std::array::from_fn(|c| {
        let top = p00[c] + (p10[c] - p00[c]) * tx;
        let bottom = p01[c] + (p11[c] - p01[c]) * tx;
        top + (bottom - top) * ty
    })
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
