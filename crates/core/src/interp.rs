//! Interpolation shared by the run driver (dense output of the fixed-step methods, events) and
//! the chaos kernels (flip times): the cubic Hermite interpolant of one step.

/// Cubic Hermite interpolation between `(y0, f0)` and `(y1, f1)` over a step `h`, at fraction `x`.
pub fn hermite(y0: &[f64], f0: &[f64], y1: &[f64], f1: &[f64], h: f64, x: f64, out: &mut [f64]) {
    let (x2, x3) = (x * x, x * x * x);
    let (h00, h10, h01, h11) = (2.0 * x3 - 3.0 * x2 + 1.0, x3 - 2.0 * x2 + x, -2.0 * x3 + 3.0 * x2, x3 - x2);
    for m in 0..out.len() {
        out[m] = h00 * y0[m] + h10 * h * f0[m] + h01 * y1[m] + h11 * h * f1[m];
    }
}

#[cfg(test)]
mod tests {
    use super::hermite;

    #[test]
    fn reproduces_a_cubic_to_round_off() {
        // y = 2 - x + 3 x^2 - 0.5 x^3 on [0.3, 1.1]: a cubic Hermite interpolant is exact for it.
        let y = |x: f64| 2.0 - x + 3.0 * x * x - 0.5 * x * x * x;
        let dy = |x: f64| -1.0 + 6.0 * x - 1.5 * x * x;
        let (a, b) = (0.3, 1.1);
        for i in 0..=20 {
            let s = i as f64 / 20.0;
            let mut out = [0.0];
            hermite(&[y(a)], &[dy(a)], &[y(b)], &[dy(b)], b - a, s, &mut out);
            let want = y(a + s * (b - a));
            assert!((out[0] - want).abs() <= 4.0 * f64::EPSILON * want.abs(), "x = {s}: {} vs {want}", out[0]);
        }
    }
}
