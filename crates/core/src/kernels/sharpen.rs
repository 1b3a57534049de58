//! The cross-shaped sharpen `c + s (c - mean of the 4 cross neighbours)`.

/// Sharpens centre `c` against its four cross neighbours `n` with strength `s`:
/// `c + s * (c - (n0 + n1 + n2 + n3) / 4)`. Strength 4 is the kernel
/// `[0 -1 0; -1 5 -1; 0 -1 0]` (Oliveros 2018, eq. 3.1, after Xu 2016); strength 1 is the
/// normalised `[0 -0.25 0; -0.25 2 -0.25; 0 -0.25 0]` (Oliveros 2018, eq. 4.17).
#[inline(always)]
pub fn sharpen_cross(c: f32, n: [f32; 4], s: f32) -> f32 {
    c + s * (c - 0.25 * (n[0] + n[1] + n[2] + n[3]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use crate::tolerance::Tolerance;

    #[test]
    fn strengths_4_and_1_are_the_thesis_kernels() {
        let k31 = [[0.0, -1.0, 0.0], [-1.0, 5.0, -1.0], [0.0, -1.0, 0.0]];
        let k417 = [[0.0, -0.25, 0.0], [-0.25, 2.0, -0.25], [0.0, -0.25, 0.0]];
        let mut rng = SplitMix64::new(51);
        for _ in 0..1000 {
            let t: [[f64; 3]; 3] = std::array::from_fn(|_| std::array::from_fn(|_| rng.next_f64()));
            let conv = |k: [[f64; 3]; 3]| (0..9).map(|i| k[i / 3][i % 3] * t[i / 3][i % 3]).sum::<f64>();
            let n = [t[0][1], t[1][0], t[1][2], t[2][1]].map(|v| v as f32);
            let c = t[1][1] as f32;
            Tolerance::abs(1e-5)
                .check("3.1", sharpen_cross(c, n, 4.0) as f64, conv(k31))
                .unwrap();
            Tolerance::abs(1e-5)
                .check("4.17", sharpen_cross(c, n, 1.0) as f64, conv(k417))
                .unwrap();
        }
    }
}
