//! The logistic density φ_s and its cell average, stable for any scale s and SDF value.
//!
//! NeuS's density is `φ_s(x) = s·e^{−sx} / (1 + e^{−sx})²` (the paper's eq. 1 drops the square;
//! the square is what makes φ_s the derivative of the sigmoid Φ_s and integrate to 1).
//!
//! **Point vs cell average.** The paper evaluates φ_s(S) at cell centres. For large s the
//! logistic shell (standard deviation π/(√3·s)) becomes thinner than a cell and point samples
//! alias: a cell whose centre misses the shell by half a cell gets e^{−s·a/2} of its due, so the
//! total mass collapses (s = 2000 on a 128³ grid: most surface cells get < 1e-6 of the peak).
//! [`cell_average_density`] instead averages φ_s over the range of SDF values a cell spans,
//! `[S − h, S + h]`: `(Φ_s(S + h) − Φ_s(S − h)) / 2h`. It tends to φ_s(S) as s·h → 0 and to the
//! surface area inside the cell (divided by its volume) as s → ∞, so the grid's total mass is
//! right at every s. We use `h = 0.75·cell` (a unit gradient crossing a cube spans between
//! 0.5 and 0.87 cells of SDF around the centre, depending on its direction).

/// How a cell's density is computed from the SDF at its centre.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum CellDensity {
    /// φ_s(S(centre)), as the paper does. Aliases when the shell is thinner than a cell.
    Point,
    /// φ_s averaged over the SDF range of the cell (see the module docs). Default.
    #[default]
    CellAverage,
}

/// The fraction of the SDF range a cell of side `a` spans on each side of its centre value, in
/// units of `a`, used by [`CellDensity::CellAverage`].
pub const CELL_HALF_SPAN: f32 = 0.75;

/// The sigmoid 1/(1 + e^{−x}) without overflow.
#[inline]
fn sigmoid(x: f64) -> f64 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// NeuS's logistic density φ_s(sdf), stable for any s > 0 and any finite sdf (0 for NaN).
#[inline]
pub fn logistic_density(s: f32, sdf: f32) -> f32 {
    let (s, x) = (s as f64, sdf as f64);
    // φ is even: use e = e^{−s|x|} ∈ (0, 1], so nothing overflows.
    let e = (-s * x.abs()).exp();
    let v = s * e / ((1.0 + e) * (1.0 + e));
    if v.is_finite() { v as f32 } else { 0.0 }
}

/// Φ_s(hi) − Φ_s(lo) for lo ≤ hi, without cancellation when both are far on one side.
#[inline]
pub fn logistic_cdf_difference(s: f32, lo: f32, hi: f32) -> f64 {
    let (s, lo, hi) = (s as f64, lo as f64, hi as f64);
    let d = if lo >= 0.0 {
        // Both above: 1 − Φ is small and precise.
        sigmoid(-s * lo) - sigmoid(-s * hi)
    } else {
        // Both below (Φ small and precise), or straddling 0 (no cancellation).
        sigmoid(s * hi) - sigmoid(s * lo)
    };
    d.max(0.0)
}

/// The average of φ_s over SDF values in `[sdf − half_span, sdf + half_span]` (0 for NaN).
#[inline]
pub fn cell_average_density(s: f32, sdf: f32, half_span: f32) -> f32 {
    if half_span <= 0.0 {
        return logistic_density(s, sdf);
    }
    // For s·h tiny the difference quotient loses digits: φ is then flat over the span.
    if (s as f64) * (half_span as f64) < 1e-4 {
        return logistic_density(s, sdf);
    }
    let v = logistic_cdf_difference(s, sdf - half_span, sdf + half_span) / (2.0 * half_span as f64);
    if v.is_finite() { v as f32 } else { 0.0 }
}

/// The density of a cell of side `cell` with centre SDF `sdf`.
#[inline]
pub fn cell_density(mode: CellDensity, s: f32, sdf: f32, cell: f32) -> f32 {
    match mode {
        CellDensity::Point => logistic_density(s, sdf),
        CellDensity::CellAverage => cell_average_density(s, sdf, CELL_HALF_SPAN * cell),
    }
}

/// The SDF distance beyond which the density (of either mode) is below `threshold`:
/// the smallest d ≥ 0 with 4·s·e^{−s·d} ≤ threshold, plus the cell half span.
pub fn negligible_distance(mode: CellDensity, s: f32, threshold: f64, cell: f32) -> f32 {
    let s64 = s as f64;
    let d = ((4.0 * s64 / threshold).ln() / s64).max(0.0);
    let span = match mode {
        CellDensity::Point => 0.0,
        CellDensity::CellAverage => (CELL_HALF_SPAN * cell) as f64,
    };
    (d + span) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logistic_density_is_finite_and_integrates_to_one_for_all_scales() {
        for s in [1e-3f32, 1.0, 20.0, 200.0, 2000.0, 1e5, 1e7] {
            for x in [-1e30f32, -10.0, -1e-3, 0.0, 1e-9, 5.0, 1e30, f32::MAX] {
                let v = logistic_density(s, x);
                assert!(v.is_finite() && v >= 0.0, "s {s} x {x}: {v}");
            }
            assert!((logistic_density(s, 0.0) - s / 4.0).abs() <= 1e-6 * s);
            // ∫ φ_s = 1: midpoint rule over ±40/s.
            let n = 20000;
            let w = 80.0 / s as f64;
            let sum: f64 = (0..n).map(|i| logistic_density(s, (-40.0 / s as f64 + (i as f64 + 0.5) * w / n as f64) as f32) as f64).sum();
            assert!((sum * w / n as f64 - 1.0).abs() < 1e-3, "s {s}: {}", sum * w / n as f64);
        }
        assert_eq!(logistic_density(10.0, f32::NAN), 0.0);
    }

    #[test]
    fn cell_average_matches_point_for_small_s_and_area_for_large_s() {
        let cell = 2.0f32 / 128.0;
        let h = CELL_HALF_SPAN * cell;
        // Small s: flat.
        let (p, c) = (logistic_density(1.0, 0.3), cell_average_density(1.0, 0.3, h));
        assert!((p - c).abs() / p < 1e-4);
        // Large s: 1/(2h) inside the span, 0 outside, whatever s.
        for s in [1e5f32, 1e7] {
            assert!((cell_average_density(s, 0.3 * h, h) - 1.0 / (2.0 * h)).abs() / (1.0 / (2.0 * h)) < 1e-3);
            assert_eq!(cell_average_density(s, 1.5 * h, h), 0.0);
        }
        // Far on one side (φ ≈ s·e^{−sx}): no cancellation; the closed-form average of s·e^{−sx}
        // over [x − h, x + h] is s·e^{−sx}·sinh(sh)/(sh).
        let (s, x) = (50.0f64, 0.5f64);
        let v = cell_average_density(s as f32, x as f32, h) as f64;
        let sh = s * h as f64;
        let expect = s * (-s * x).exp() * sh.sinh() / sh;
        assert!(v > 0.0 && (v - expect).abs() / expect < 1e-3, "{v} vs {expect}");
    }

    #[test]
    fn negligible_distance_bounds_the_density() {
        for s in [20.0f32, 200.0, 2000.0, 1e7] {
            for mode in [CellDensity::Point, CellDensity::CellAverage] {
                let d = negligible_distance(mode, s, 1e-6, 0.015);
                assert!(cell_density(mode, s, d, 0.015) as f64 <= 1e-6 * 1.0001, "{mode:?} s {s}");
            }
        }
    }
}
