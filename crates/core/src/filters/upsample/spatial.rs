//! Joint-bilateral upsampling of sparse shading (Herzog et al. 2010, eq. 1-2,
//! after Yang et al.): a full-resolution pixel takes the weighted mean of the four shaded
//! samples around it, the weight being an image-space kernel times geometric terms on
//! normal and depth that the full-resolution G-buffer gives for both ends.

#[cfg(test)]
use crate::frame::Plane;
use crate::frame::Sampling;

/// Weights never fall below this: Herzog et al. 2010, sec. 3.1, "finite support, clamped to a small
/// epsilon to avoid zero weights", so that a pixel whose four samples all lie on other
/// surfaces still gets a value (their plain mean) rather than a division by zero. Small
/// enough that an epsilon-weighted sample moves a converged pixel by under 1e-3 of the
/// difference (four neighbours, a period of 16 frames: 4 x 16 x 1e-5 = 6.4e-4).
pub const WEIGHT_EPSILON: f32 = 1.0e-5;

/// The finite-support falloff of Herzog et al. 2010, sec. 3.1 (fig. 4, left): `(1 - x / sigma)^3`
/// for `x < sigma`, clamped below at [`WEIGHT_EPSILON`]. It is 1 at 0 and falls smoothly
/// to the clamp at `sigma`, a cheap stand-in for Yang et al.'s Gaussian.
#[inline(always)]
pub fn falloff(x: f32, sigma: f32) -> f32 {
    // Branch-free: `max` returns the other operand for a NaN distance, so NaN gets the clamp.
    let t = (1.0 - x * (1.0 / sigma)).max(0.0);
    (t * t * t).max(WEIGHT_EPSILON)
}

/// The full-resolution geometry the weights read, and the constants that scale it.
pub struct Geometry<'a> {
    /// Frame width.
    pub width: usize,
    /// Frame height.
    pub height: usize,
    /// Linear depth, when the frame has it.
    pub depth: Option<&'a [f32]>,
    /// Normals, when the frame has them.
    pub normal: Option<[&'a [f32]; 3]>,
    /// `1 / (depth_sigma x depth range)`: depth differences are measured relative to the
    /// frame's depth range (Herzog et al. 2010, sec. 3.1).
    pub inv_depth_scale: f32,
    /// Falloff width on `1 - n_i . n_j`.
    pub normal_sigma: f32,
    /// A pixel whose normal is zero (no surface: sky) weighs its samples by depth alone
    /// (normal term 1) instead of as a surface at right angles to every other.
    pub sky_depth_only: bool,
}

/// Up to nine shaded samples around a pixel: colour index, pixel index, offset index.
pub struct Near {
    /// How many.
    pub n: usize,
    /// Colour indices.
    pub k: [u32; 9],
    /// Full-resolution pixel indices.
    pub j: [u32; 9],
    /// Offset indices (see [`Sparse::dist`]).
    pub o: [u8; 9],
}

impl Geometry<'_> {
    /// The geometric weight between full-resolution pixels `i` and `j`: normal term times
    /// depth term (1 for a term whose channel is absent).
    #[inline(always)]
    pub fn weight(&self, i: usize, j: usize) -> f32 {
        let mut w = 1.0;
        if let Some(d) = self.depth {
            w *= falloff((d[i] - d[j]).abs() * self.inv_depth_scale, 1.0);
        }
        if let Some([nx, ny, nz]) = self.normal {
            if !(self.sky_depth_only && nx[i] == 0.0 && ny[i] == 0.0 && nz[i] == 0.0) {
                let dot = nx[i] * nx[j] + ny[i] * ny[j] + nz[i] * nz[j];
                w *= falloff((1.0 - dot).max(0.0), self.normal_sigma);
            }
        }
        w
    }
}

/// The depth range a frame's depth differences are measured against: `far - near` when the
/// frame gives its planes, else the range of the finite depths of the pixels that show an
/// object (object id != 0 when ids are present, so a sky at 1e10 does not stretch it); 1
/// when there is no such pixel or the range is empty.
pub fn depth_range(depth: &[f32], ids: Option<&[u32]>, near_far: Option<[f32; 2]>) -> f32 {
    if let Some([n, f]) = near_far {
        if (f - n).is_finite() && f > n {
            return f - n;
        }
    }
    let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
    for (k, &d) in depth.iter().enumerate() {
        if d.is_finite() && ids.is_none_or(|ids| ids[k] != 0) {
            lo = lo.min(d);
            hi = hi.max(d);
        }
    }
    if hi > lo {
        hi - lo
    } else {
        1.0
    }
}

/// What the four shaded samples around a pixel give.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Gathered {
    /// Sum of weight x colour.
    pub sum: [f32; 3],
    /// Sum of weights.
    pub weight: f32,
}

impl Gathered {
    /// The weighted mean (`None` when no sample had weight).
    pub fn mean(&self) -> Option<[f32; 3]> {
        (self.weight > 0.0).then(|| self.sum.map(|s| s / self.weight))
    }
}

/// Offsets within one block of a pixel, `(2 x 4 + 1)^2` for the largest factor.
const OFFSETS: usize = 81;

/// The sparse colour and where its samples lie.
pub struct Sparse<'a> {
    /// Colour planes at their own size.
    pub color: [&'a [f32]; 3],
    /// Their width.
    pub color_width: usize,
    /// Their height.
    pub color_height: usize,
    /// The pattern.
    pub sampling: Sampling,
    /// Samples to leave out (repaired from NaN or negative input), indexed like `color`.
    pub invalid: Option<&'a [bool]>,
    /// Per offset `(dx, dy)` in `[-factor, factor]^2` (index `(dy + f)(2f + 1) + dx + f`):
    /// the distance in block diagonals.
    dist: [f32; OFFSETS],
    /// The same offsets' squared distance in pixels.
    dist2: [f32; OFFSETS],
}

impl<'a> Sparse<'a> {
    /// The sparse colour `color` (`color_width x color_height`) shaded with `sampling`.
    pub fn new(
        color: [&'a [f32]; 3],
        color_width: usize,
        color_height: usize,
        sampling: Sampling,
        invalid: Option<&'a [bool]>,
    ) -> Self {
        let f = sampling.factor as isize;
        let side = 2 * f + 1;
        let (mut dist, mut dist2) = ([0.0f32; OFFSETS], [0.0f32; OFFSETS]);
        for dy in -f..=f {
            for dx in -f..=f {
                let o = ((dy + f) * side + dx + f) as usize;
                dist2[o] = (dx * dx + dy * dy) as f32;
                dist[o] = (dist2[o] / (2.0 * (f * f) as f32)).sqrt();
            }
        }
        Sparse {
            color,
            color_width,
            color_height,
            sampling,
            invalid,
            dist,
            dist2,
        }
    }

    /// Distance of offset `o` (as passed by [`Sparse::for_each_near`]) in block diagonals.
    #[inline(always)]
    pub fn dist(&self, o: usize) -> f32 {
        self.dist[o]
    }

    /// Squared distance of offset `o` in pixels.
    #[inline(always)]
    pub fn dist2(&self, o: usize) -> f32 {
        self.dist2[o]
    }

    /// Index of the colour sample of lattice cell `(a, b)` and its full-resolution pixel,
    /// when it exists and was shaded inside the frame.
    #[inline(always)]
    pub fn sample(&self, a: isize, b: isize, width: usize, height: usize) -> Option<(usize, usize)> {
        if a < 0 || b < 0 || a as usize >= self.color_width || b as usize >= self.color_height {
            return None;
        }
        let (a, b) = (a as usize, b as usize);
        let k = b * self.color_width + a;
        if self.invalid.is_some_and(|v| v[k]) {
            return None;
        }
        let (x, y) = self.sampling.position(a, b, width, height)?;
        Some((k, y * width + x))
    }

    /// The colour index of pixel `(x, y)`'s own sample when it was shaded this frame.
    #[inline(always)]
    pub fn own(&self, x: usize, y: usize, width: usize, height: usize) -> Option<usize> {
        if !self.sampling.is_shaded(x, y) {
            return None;
        }
        let f = self.sampling.factor as usize;
        self.sample((x / f) as isize, (y / f) as isize, width, height)
            .map(|(k, _)| k)
    }

    /// The lattice cell at or before pixel coordinate `x` along an axis with phase `p`.
    #[inline(always)]
    pub fn cell(&self, x: usize, p: u32) -> isize {
        (x as isize - p as isize).div_euclid(self.sampling.factor as isize)
    }

    /// The shaded samples within `factor` pixels of `(x, y)` along both axes: the four
    /// around an unshaded pixel, and a shaded pixel's own sample with its eight lattice
    /// neighbours (so that the footprint is symmetric about every pixel; fewer at the
    /// borders, and none that are invalid).
    #[inline(always)]
    pub fn near(&self, x: usize, y: usize, width: usize, height: usize) -> Near {
        let fac = self.sampling.factor as isize;
        let side = 2 * fac + 1;
        let [px, py] = self.sampling.phase.map(|p| p as isize);
        let (x, y) = (x as isize, y as isize);
        let a0 = (x - px).div_euclid(fac);
        let b0 = (y - py).div_euclid(fac);
        let mut near = Near {
            n: 0,
            k: [0; 9],
            j: [0; 9],
            o: [0; 9],
        };
        for b in b0 - 1..=b0 + 1 {
            let sy = fac * b + py;
            let dy = sy - y;
            if b < 0 || b as usize >= self.color_height || sy as usize >= height || dy.abs() > fac {
                continue;
            }
            for a in a0 - 1..=a0 + 1 {
                let sx = fac * a + px;
                let dx = sx - x;
                if a < 0 || a as usize >= self.color_width || sx as usize >= width || dx.abs() > fac {
                    continue;
                }
                let k = b as usize * self.color_width + a as usize;
                if self.invalid.is_some_and(|v| v[k]) {
                    continue;
                }
                near.k[near.n] = k as u32;
                near.j[near.n] = (sy as usize * width + sx as usize) as u32;
                near.o[near.n] = ((dy + fac) * side + dx + fac) as u8;
                near.n += 1;
            }
        }
        near
    }

    /// Calls `f(colour index, pixel index, offset)` for each sample of [`Sparse::near`].
    #[inline(always)]
    pub fn for_each_near(
        &self,
        x: usize,
        y: usize,
        width: usize,
        height: usize,
        mut f: impl FnMut(usize, usize, usize),
    ) {
        let near = self.near(x, y, width, height);
        for s in 0..near.n {
            f(near.k[s] as usize, near.j[s] as usize, near.o[s] as usize);
        }
    }

    /// Joint-bilateral gather at pixel `(x, y)` (Herzog et al. 2010, eq. 1-2): weight = image-space
    /// falloff of the distance (in units of the block diagonal `factor x sqrt 2`, width
    /// `kernel_sigma`) times the geometric weight.
    #[inline(always)]
    pub fn gather(&self, geo: &Geometry, x: usize, y: usize, kernel_sigma: f32) -> Gathered {
        let (w, h) = (geo.width, geo.height);
        let i = y * w + x;
        let mut g = Gathered::default();
        let near = self.near(x, y, w, h);
        let [cr, cg, cb] = self.color;
        for s in 0..near.n {
            let (k, j) = (near.k[s] as usize, near.j[s] as usize);
            let wt = falloff(self.dist[near.o[s] as usize], kernel_sigma) * geo.weight(i, j);
            let v = [cr[k], cg[k], cb[k]];
            for c in 0..3 {
                g.sum[c] += wt * v[c];
            }
            g.weight += wt;
        }
        g
    }
}

/// Full-resolution planes of the spatial estimate alone (the `spatial` method, and the
/// hole filling of `temporal`).
#[cfg(test)]
pub fn upsample(sparse: &Sparse, geo: &Geometry, kernel_sigma: f32, out: &mut [Plane<f32>; 3]) {
    use crate::filters::passes::slices_mut;
    use crate::pipeline::exec::for_rows;
    let w = geo.width;
    for_rows(slices_mut(out), w, |y, [r, g, b]| {
        for x in 0..w {
            let c = sparse.gather(geo, x, y, kernel_sigma).mean().unwrap_or([0.0; 3]);
            (r[x], g[x], b[x]) = (c[0], c[1], c[2]);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::tolerance::Tolerance;

    #[test]
    fn falloff_is_one_at_zero_and_clamped_past_sigma() {
        assert_eq!(falloff(0.0, 0.5), 1.0);
        Tolerance::abs(1e-7)
            .check("half way", falloff(0.25, 0.5) as f64, 0.125)
            .unwrap();
        assert_eq!(falloff(0.5, 0.5), WEIGHT_EPSILON);
        assert_eq!(falloff(7.0, 0.5), WEIGHT_EPSILON);
        assert!(
            falloff(f32::NAN, 0.5) == WEIGHT_EPSILON,
            "NaN distance gets the clamp"
        );
    }

    /// The gather matches an f64 scalar evaluation of eq. 1-2 on random inputs.
    #[test]
    fn gather_matches_a_scalar_reference() {
        let mut rng = crate::rng::SplitMix64::new(5);
        let (w, h) = (9usize, 7usize);
        for factor in [2u32, 4] {
            for phase in [[0, 0], [1, factor - 1]] {
                let s = Sampling { factor, phase };
                let (cw, ch) = s.color_size(w, h);
                let color: Vec<Vec<f32>> = (0..3)
                    .map(|_| (0..cw * ch).map(|_| rng.next_f64() as f32 * 4.0).collect())
                    .collect();
                let depth: Vec<f32> = (0..w * h).map(|_| 1.0 + rng.next_f64() as f32 * 3.0).collect();
                let n: Vec<[f32; 3]> = (0..w * h)
                    .map(|_| {
                        let v = [rng.next_f64() - 0.5, rng.next_f64() - 0.5, 1.0];
                        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
                        v.map(|c| (c / l) as f32)
                    })
                    .collect();
                let nn: [Vec<f32>; 3] = std::array::from_fn(|c| n.iter().map(|v| v[c]).collect());
                let geo = Geometry {
                    width: w,
                    height: h,
                    depth: Some(&depth),
                    normal: Some([&nn[0], &nn[1], &nn[2]]),
                    inv_depth_scale: 1.0 / (0.1 * 3.0),
                    normal_sigma: 0.5,
                    sky_depth_only: false,
                };
                let sparse = Sparse::new([&color[0], &color[1], &color[2]], cw, ch, s, None);
                let g64 =
                    |x: f64, sigma: f64| ((1.0 - x / sigma).max(0.0).powi(3)).max(WEIGHT_EPSILON as f64);
                for y in 0..h {
                    for x in 0..w {
                        let i = y * w + x;
                        let (mut sum, mut wsum) = ([0.0f64; 3], 0.0f64);
                        for b in 0..ch {
                            for a in 0..cw {
                                let Some((sx, sy)) = s.position(a, b, w, h) else {
                                    continue;
                                };
                                // Within one block of the pixel along both axes.
                                let fac = factor as i64;
                                if (sx as i64 - x as i64).abs() > fac || (sy as i64 - y as i64).abs() > fac {
                                    continue;
                                }
                                let j = sy * w + sx;
                                let d = (((sx as f64 - x as f64).powi(2) + (sy as f64 - y as f64).powi(2))
                                    / (2.0 * (factor * factor) as f64))
                                    .sqrt();
                                let dot: f64 = (0..3).map(|c| n[i][c] as f64 * n[j][c] as f64).sum();
                                let wt = g64(d, 1.0)
                                    * g64((depth[i] as f64 - depth[j] as f64).abs() / 0.3, 1.0)
                                    * g64((1.0 - dot).max(0.0), 0.5);
                                for c in 0..3 {
                                    sum[c] += wt * color[c][b * cw + a] as f64;
                                }
                                wsum += wt;
                            }
                        }
                        let got = sparse.gather(&geo, x, y, 1.0);
                        let tol = Tolerance::new(1e-9, 1e-5);
                        tol.check("weight", got.weight as f64, wsum).unwrap();
                        for c in 0..3 {
                            tol.check("sum", got.sum[c] as f64, sum[c]).unwrap();
                        }
                    }
                }
            }
        }
    }
}
