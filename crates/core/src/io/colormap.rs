//! A perceptual colour ramp for maps (SSIM, error) that a person looks at.

/// Control points of matplotlib's "inferno" ramp at 0, 1/4, 1/2, 3/4 and 1 (sRGB bytes).
const INFERNO: [[f32; 3]; 5] = [
    [0.0, 0.0, 4.0],
    [87.0, 16.0, 110.0],
    [188.0, 55.0, 84.0],
    [249.0, 142.0, 9.0],
    [252.0, 255.0, 164.0],
];

/// Maps `t` in [0, 1] (clamped; NaN gives black) to an sRGB colour, dark to bright.
pub fn inferno(t: f32) -> [u8; 3] {
    let t = if t.is_nan() { 0.0 } else { t.clamp(0.0, 1.0) } * 4.0;
    let i = (t.floor() as usize).min(3);
    let f = t - i as f32;
    let (a, b) = (INFERNO[i], INFERNO[i + 1]);
    [0, 1, 2].map(|c| (a[c] + (b[c] - a[c]) * f).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ends_and_monotone_brightness() {
        assert_eq!(inferno(0.0), [0, 0, 4]);
        assert_eq!(inferno(1.0), [252, 255, 164]);
        assert_eq!(inferno(f32::NAN), [0, 0, 4]);
        let lum = |c: [u8; 3]| c[0] as u32 * 2126 + c[1] as u32 * 7152 + c[2] as u32 * 722;
        let mut last = 0;
        for i in 0..=100 {
            let l = lum(inferno(i as f32 / 100.0));
            assert!(l + 2000 >= last, "brightness drops at {i}");
            last = l;
        }
    }
}
