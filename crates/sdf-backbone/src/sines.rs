//! The sines of a positional encoding, `sin(2^l v)` and `cos(2^l v)` for l < L, in f64: each
//! value's own sine and cosine, then the double-angle formulas, off by ≈ 2^l · 10⁻¹⁶ before the
//! one rounding to the network's precision (as close as `sinf`/`cosf` of each, ≈ 3 · 10⁻⁸).
//!
//! [`double_angles`] takes one value (the standard library's `sin_cos`), [`double_angles_of_each`]
//! many in the layout of [`double_angles_of_all`], which a render's learned background uses for
//! its points (on the unit sphere, where the ray reaches the sample's radius): there each value's
//! own sine and cosine come from their Taylor series ([`sin_cos_near_zero`], |v| ≤ 1.0625; libm's
//! beyond) and every step runs across the values in vector lanes. Per value and frequency, libm's
//! `sin_cos` and the double angles had been 9 % of a render's CPU time without masks on the
//! built-in scene (scalar calls, 3 per background sample). Training keeps libm's: the series
//! differs in the last places of f64, which can move a value's rounding to f32.

/// Beyond this |v|, [`double_angles_of_all`] takes libm's `sin_cos` (the series' error grows as
/// v¹⁹/19!: 2.6 · 10⁻¹⁷ here).
const SERIES_BOUND: f64 = 1.0625;

/// sin and cos of `2^l v` for l < `frequencies`, in pairs (`out`: 2 × `frequencies` values, sin
/// then cos), from v's own by the double-angle formulas.
pub(crate) fn double_angles(v: f64, frequencies: usize, out: &mut [f64]) {
    let (mut sin, mut cos) = v.sin_cos();
    for pair in out.chunks_exact_mut(2).take(frequencies) {
        pair.copy_from_slice(&[sin, cos]);
        (sin, cos) = (2.0 * sin * cos, (cos - sin) * (cos + sin));
    }
}

/// sin v and cos v for |v| ≤ [`SERIES_BOUND`] by their Taylor series to v¹⁷ and v¹⁸ (Horner in
/// v²): within a few units in the last place of f64 there; polynomials only, so that a loop
/// over values vectorises.
#[inline(always)]
pub(crate) fn sin_cos_near_zero(v: f64) -> (f64, f64) {
    // 1/(2k+1)! and 1/(2k)!, alternating in sign, from the highest power down.
    const SIN: [f64; 9] = [
        1.0 / 355_687_428_096_000.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 39_916_800.0,
        1.0 / 362_880.0,
        -1.0 / 5_040.0,
        1.0 / 120.0,
        -1.0 / 6.0,
        1.0,
    ];
    const COS: [f64; 10] = [
        -1.0 / 6_402_373_705_728_000.0,
        1.0 / 20_922_789_888_000.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 479_001_600.0,
        -1.0 / 3_628_800.0,
        1.0 / 40_320.0,
        -1.0 / 720.0,
        1.0 / 24.0,
        -0.5,
        1.0,
    ];
    let x2 = v * v;
    let sin = SIN.iter().fold(0.0, |acc, &c| acc * x2 + c) * v;
    let cos = COS.iter().fold(0.0, |acc, &c| acc * x2 + c);
    (sin, cos)
}

/// [`double_angles`] of every value of `values` (n of them) at once: `out[(2l + m) · n + i]` is
/// sin (m = 0) or cos (m = 1) of `2^l · values[i]`, l < `frequencies` (`out`: 2 × `frequencies`
/// × n values). Within a few units in the last place of f64 of [`double_angles`]'s, times 2^l
/// (the same double-angle steps from a first pair that may differ in its last place).
pub(crate) fn double_angles_of_all(values: &[f64], frequencies: usize, out: &mut [f64]) {
    let n = values.len();
    assert_eq!(out.len(), 2 * frequencies * n, "double_angles_of_all: 2 × {frequencies} × {n} values out");
    if frequencies == 0 || n == 0 {
        return;
    }
    crate::kernels::dispatch(
        #[inline(always)]
        || {
            let (first, mut rest) = out.split_at_mut(2 * n);
            let (sin, cos) = first.split_at_mut(n);
            for ((s, c), &v) in sin.iter_mut().zip(cos.iter_mut()).zip(values) {
                (*s, *c) = sin_cos_near_zero(v);
            }
            // The rare value off the series' range: libm's, as `double_angles` takes it.
            for (i, &v) in values.iter().enumerate() {
                if !(v.abs() <= SERIES_BOUND) {
                    (sin[i], cos[i]) = v.sin_cos();
                }
            }
            let (mut sin, mut cos) = (&*sin, &*cos);
            for _ in 1..frequencies {
                let (pair, tail) = rest.split_at_mut(2 * n);
                let (next_sin, next_cos) = pair.split_at_mut(n);
                for i in 0..n {
                    (next_sin[i], next_cos[i]) = (2.0 * sin[i] * cos[i], (cos[i] - sin[i]) * (cos[i] + sin[i]));
                }
                (sin, cos, rest) = (next_sin, next_cos, tail);
            }
        },
    );
}

/// [`double_angles_of_all`]'s layout from [`double_angles`] of each value (libm's `sin_cos`, the
/// doublings one value at a time): training's background, whose bits the series would change
/// (in a rare value's last place after the rounding to f32, and from there every later step).
pub(crate) fn double_angles_of_each(values: &[f64], frequencies: usize, out: &mut [f64]) {
    let n = values.len();
    assert_eq!(out.len(), 2 * frequencies * n, "double_angles_of_each: 2 × {frequencies} × {n} values out");
    let mut pairs = vec![0.0; 2 * frequencies];
    for (i, &v) in values.iter().enumerate() {
        double_angles(v, frequencies, &mut pairs);
        for (m, &p) in pairs.iter().enumerate() {
            out[m * n + i] = p;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The series against libm over its range (a few units in the last place), and the values
    /// of many at once against each alone: within 2^l · 10⁻¹⁵ at every frequency, the same
    /// values off the series' range (libm's there too), NaN kept.
    #[test]
    fn the_sines_of_many_values_are_each_values_own() {
        let mut worst = 0.0f64;
        for i in 0..=20_000 {
            let v = -SERIES_BOUND + 2.0 * SERIES_BOUND * f64::from(i) / 20_000.0;
            let ((s, c), (ls, lc)) = (sin_cos_near_zero(v), v.sin_cos());
            worst = worst.max((s - ls).abs()).max((c - lc).abs());
        }
        assert!(worst <= 4.0 * f64::EPSILON, "the series is off libm's by {worst:e}");
        let frequencies = 10;
        let mut values: Vec<f64> = (0..257).map(|i| (f64::from(i) * 0.618_034).sin() * 1.06).collect();
        values.extend([1.0, -1.0, 0.0, -0.0, 1.5, -3.0, 40.0, f64::NAN]);
        let n = values.len();
        let mut all = vec![0.0; 2 * frequencies * n];
        double_angles_of_all(&values, frequencies, &mut all);
        let mut each = vec![0.0; 2 * frequencies * n];
        double_angles_of_each(&values, frequencies, &mut each);
        let mut alone = vec![0.0; 2 * frequencies];
        for (i, &v) in values.iter().enumerate() {
            double_angles(v, frequencies, &mut alone);
            for l in 0..frequencies {
                for m in 0..2 {
                    let (got, want) = (all[(2 * l + m) * n + i], alone[2 * l + m]);
                    assert_eq!(each[(2 * l + m) * n + i].to_bits(), want.to_bits(), "{v}, frequency {l}: libm's, laid out");
                    if v.abs() > SERIES_BOUND || v.is_nan() {
                        assert_eq!(got.to_bits(), want.to_bits(), "{v}, frequency {l}: libm's off the series' range");
                    } else {
                        let bound = f64::from(1u32 << l) * 1e-15;
                        assert!((got - want).abs() <= bound, "{v}, frequency {l}: {got} against {want}");
                    }
                }
            }
        }
    }
}
