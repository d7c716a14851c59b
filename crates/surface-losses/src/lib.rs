//! The surface losses of the paper (Sec. 4.5; docs/DECISIONS.md §6) and the extra ray points around the
//! sampled depth λ̃.
//!
//! Per ray, with sample depths t₀ < … < tₙ, SDF values S₀ … Sₙ and rendering weights w₀ … wₙ₋₁
//! (one per interval), each interval i is represented by its midpoint `t̄ᵢ = (tᵢ + tᵢ₊₁)/2` and
//! `S̄ᵢ = (Sᵢ + Sᵢ₊₁)/2` (weights belong to intervals in NeuS's discretisation):
//! - a ray whose λ̃ is inside the scene bound: intervals with `|t̄ᵢ − λ̃| ≤ k·σ(s)` (k = 3,
//!   σ = π/(√3 s), the logistic's standard deviation) are *near* and give `L_near = Σ |S̄ᵢ| wᵢ`;
//!   the others are *empty* and give `L_empty = Σ ((S̄ᵢ − ε) wᵢ)²`;
//! - a *background* ray (λ̃ outside the bound) gives `L_bg = Σ exp(−β|S̄ᵢ|) wᵢ` over all intervals;
//! - `L_surf = weight · (λ₁ L_near + λ₂ (L_empty + L_bg))`, averaged over the rays by the caller.
//!
//! ε and β are not given by the paper: we take ε = 0.01 and β = 10 (scene normalised to the unit
//! sphere: exp(−β|S|) is small beyond 0.3), both configurable.
//!
//! **What they buy (the ablation, BENCHMARKS.md):** at equal wall time (60 s; Spot, Bob and the
//! built-in scene with backdrops and masks; 3 seeds each), the surface losses at weight 1 did not
//! lower the Chamfer against weight 0 (L0): level on Spot and the built-in scene, 12 % higher on
//! Bob (0.0131 ± 0.0005 vs 0.0117 ± 0.0005); uniform extra points (RU) and log-variance ones
//! (`guide.extra=log`, 1.01× the default's mean Chamfer) were level too. The guided
//! rays carry the gain in runs this short; the losses stay on (weight 1) as the paper's method,
//! and `surface.weight=0` is one key away.
//!
//! Gradients with respect to S and w are exact (checked against finite differences in f64);
//! at the kinks of |·| (S̄ = 0) the subgradient 0 is used.
//!
//! Extra points ([`extra_depths`]): `n` depths ~ N(λ̃, σ²) with σ = π/(√3 s) (the paper), or
//! uniform along the ray (ablation RU), or σ = π/(√3 ln s) (ablation Log), one explicit uniform
//! number per point (the normal quantile, [`standard_normal_quantile`]), clamped to the ray's
//! [near, far]. The caller may add λ̃'s own uncertainty in quadrature (`depth_sigma`): the
//! trainer passes one λ bin of the camera grid, because late in a run the logistic's σ is a
//! tenth of a bin while λ̃ is about a bin from the surface (docs/DECISIONS.md §18: 0.90× the
//! paper's Chamfer at 5 minutes on three scenes, level at 2 minutes).
#![deny(missing_docs)]

use std::f64::consts::PI;

/// Invalid configuration.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SurfaceLossError {
    /// A parameter is out of its range.
    #[error("surface loss: {name} = {value} is out of range ({expected})")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: f64,
        /// What is allowed.
        expected: &'static str,
    },
}

/// How the extra ray points are drawn (the paper's default and two ablations).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExtraPoints {
    /// N(λ̃, π²/(3 s²)) (the paper).
    #[default]
    Gaussian,
    /// Uniform on [near, far] (ablation RU).
    Uniform,
    /// N(λ̃, π²/(3 ln(s)²)) (ablation Log).
    #[serde(rename = "log")]
    LogVariance,
}

/// Weights and constants of the surface losses. In a configuration file every key is optional
/// (the defaults below) and unknown keys are errors.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SurfaceLossConfig {
    /// Overall weight. Default 1, not the paper's 500: added to our backbone's losses, 500 erases
    /// the surface within 100 iterations on the built-in scene (an empty mesh) and 10 already
    /// costs accuracy, while 1 gains over 0 (measured; BENCHMARKS.md "The surface-loss weight").
    /// The paper's weight is tied to its loss scales and runs of 300 k iterations.
    pub weight: f64,
    /// λ₁, weight of L_near (paper: 0.5).
    pub lambda_near: f64,
    /// λ₂, weight of L_empty + L_bg (paper: 0.5).
    pub lambda_far: f64,
    /// ε of L_empty (ours: 0.01).
    pub epsilon: f64,
    /// β of L_bg (ours: 10).
    pub beta: f64,
    /// Half-width of the near band in logistic standard deviations (paper: 3).
    pub band_sigmas: f64,
}

impl Default for SurfaceLossConfig {
    fn default() -> Self {
        SurfaceLossConfig { weight: 1.0, lambda_near: 0.5, lambda_far: 0.5, epsilon: 0.01, beta: 10.0, band_sigmas: 3.0 }
    }
}

impl SurfaceLossConfig {
    /// Checks the ranges: all weights ≥ 0 and finite, β ≥ 0, band > 0.
    pub fn validate(&self) -> Result<(), SurfaceLossError> {
        let check = |name, value: f64, ok: bool, expected| if ok { Ok(()) } else { Err(SurfaceLossError::OutOfRange { name, value, expected }) };
        check("weight", self.weight, self.weight.is_finite() && self.weight >= 0.0, "finite, ≥ 0")?;
        check("lambda_near", self.lambda_near, self.lambda_near.is_finite() && self.lambda_near >= 0.0, "finite, ≥ 0")?;
        check("lambda_far", self.lambda_far, self.lambda_far.is_finite() && self.lambda_far >= 0.0, "finite, ≥ 0")?;
        check("epsilon", self.epsilon, self.epsilon.is_finite(), "finite")?;
        check("beta", self.beta, self.beta.is_finite() && self.beta >= 0.0, "finite, ≥ 0")?;
        check("band_sigmas", self.band_sigmas, self.band_sigmas.is_finite() && self.band_sigmas > 0.0, "finite, > 0")
    }
}

/// The logistic's standard deviation π/(√3 s) at scale `s` (> 0).
pub fn logistic_std(s: f64) -> f64 {
    PI / (3.0f64.sqrt() * s)
}

/// What the losses need to know about one ray.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaySurface {
    /// λ̃ as a distance along the ray (same units as the sample depths).
    pub depth: f64,
    /// True when λ̃ lies outside the scene bound (or the ray had no guided depth): L_bg applies.
    pub background: bool,
}

/// The three terms of one ray, before weighting.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SurfaceTerms {
    /// L_near.
    pub near: f64,
    /// L_empty.
    pub empty: f64,
    /// L_bg.
    pub background: f64,
}

/// `L_surf` of one ray at scale `s`; adds ∂L/∂Sᵢ (n + 1 values) into `d_sdf` and ∂L/∂wᵢ (n) into
/// `d_weights`. Returns the weighted loss and its unweighted terms.
#[allow(clippy::too_many_arguments)]
pub fn ray_loss(
    config: &SurfaceLossConfig,
    ray: &RaySurface,
    s: f64,
    t: &[f64],
    sdf: &[f64],
    weights: &[f64],
    d_sdf: &mut [f64],
    d_weights: &mut [f64],
) -> (f64, SurfaceTerms) {
    let n = weights.len();
    assert!(t.len() == n + 1 && sdf.len() == n + 1 && d_sdf.len() == n + 1 && d_weights.len() == n, "ray_loss: inconsistent lengths");
    let band = config.band_sigmas * logistic_std(s);
    let mut terms = SurfaceTerms::default();
    let (w_near, w_far) = (config.weight * config.lambda_near, config.weight * config.lambda_far);
    for i in 0..n {
        let mid_t = 0.5 * (t[i] + t[i + 1]);
        let mid_s = 0.5 * (sdf[i] + sdf[i + 1]);
        let w = weights[i];
        let sign = if mid_s > 0.0 {
            1.0
        } else if mid_s < 0.0 {
            -1.0
        } else {
            0.0
        };
        // ∂/∂S̄ and ∂/∂w of this interval's weighted term.
        let (d_mid, d_w) = if ray.background {
            let e = (-config.beta * mid_s.abs()).exp();
            terms.background += e * w;
            (w_far * -config.beta * sign * e * w, w_far * e)
        } else if (mid_t - ray.depth).abs() <= band {
            terms.near += mid_s.abs() * w;
            (w_near * sign * w, w_near * mid_s.abs())
        } else {
            let r = (mid_s - config.epsilon) * w;
            terms.empty += r * r;
            (w_far * 2.0 * r * w, w_far * 2.0 * r * (mid_s - config.epsilon))
        };
        d_sdf[i] += 0.5 * d_mid;
        d_sdf[i + 1] += 0.5 * d_mid;
        d_weights[i] += d_w;
    }
    let loss = w_near * terms.near + w_far * (terms.empty + terms.background);
    (loss, terms)
}

/// The standard normal quantile Φ⁻¹(u) (Acklam's rational approximation, relative error
/// < 1.2e-9), for u in [0, 1); u = 0 is moved to the smallest positive f64 (z ≈ −38.5).
///
/// One uniform gives one variate, so any number of extra points is drawn the same way (a pair
/// transform such as Box–Muller needs a second uniform for an odd count).
pub fn standard_normal_quantile(u: f64) -> f64 {
    const A: [f64; 6] =
        [-3.969683028665376e1, 2.209460984245205e2, -2.759285104469687e2, 1.38357751867269e2, -3.066479806614716e1, 2.506628277459239];
    const B: [f64; 5] = [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] = [-7.784894002430293e-3, -3.223964580411365e-1, -2.400758277161838, -2.549732539343734, 4.374664141464968, 2.938163982698783];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let u = u.clamp(f64::MIN_POSITIVE, 1.0 - f64::EPSILON / 2.0);
    let tail =
        |q: f64| (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5]) / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0);
    if u < 0.02425 {
        tail((-2.0 * u.ln()).sqrt())
    } else if u > 1.0 - 0.02425 {
        -tail((-2.0 * (1.0 - u).ln()).sqrt())
    } else {
        let q = u - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// `uniforms.len()` extra depths for a ray with sampled depth `depth` (distance along the ray) at
/// scale `s`, drawn as `kind` says, clamped to `[near, far]`, sorted. Deterministic in the uniforms.
///
/// `depth_sigma` is the uncertainty of `depth` itself (0: exact, the paper). λ̃ comes from a grid
/// whose depth bins do not shrink as s grows: late in a run the logistic's σ (0.004 at s = 486)
/// is a tenth of a bin, and points drawn that tightly around a λ̃ that is off by a bin all miss
/// the surface. A Gaussian spread is then `√(σ² + depth_sigma²)`.
pub fn extra_depths(kind: ExtraPoints, depth: f64, s: f64, depth_sigma: f64, near: f64, far: f64, uniforms: &[f64]) -> Vec<f64> {
    let sigma = match kind {
        ExtraPoints::Gaussian => logistic_std(s.max(f64::MIN_POSITIVE)),
        // ln s ≤ 1 for s ≤ e would give a spread wider than the scene: floor it at 1.
        ExtraPoints::LogVariance => PI / (3.0f64.sqrt() * s.ln().max(1.0)),
        ExtraPoints::Uniform => 0.0,
    };
    let sigma = sigma.hypot(depth_sigma.max(0.0));
    let mut out: Vec<f64> = match kind {
        ExtraPoints::Uniform => uniforms.iter().map(|u| near + u * (far - near)).collect(),
        _ => uniforms.iter().map(|&u| (depth + sigma * standard_normal_quantile(u)).clamp(near, far)).collect(),
    };
    out.sort_by(f64::total_cmp);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Regression: with Box–Muller on pairs, an odd count padded the last pair with u₂ = ¼, whose
    /// cosine is 0, so the last extra point sat exactly at λ̃ whatever its uniform.
    #[test]
    fn odd_extra_point_count_does_not_put_the_last_point_exactly_at_the_depth() {
        for n in [1usize, 3, 5, 15] {
            let u: Vec<f64> = (0..n).map(|i| (i as f64 + 0.37) / n as f64).collect();
            let d = extra_depths(ExtraPoints::Gaussian, 2.0, 50.0, 0.0, 0.0, 4.0, &u);
            let at_depth = d.iter().filter(|&&t| t == 2.0).count();
            assert_eq!(at_depth, 0, "n = {n}: {d:?}");
        }
        // Each point follows N(λ̃, σ²) on its own: mean and variance over many odd batches.
        let s = 20.0;
        let sigma = logistic_std(s);
        let mut state = 1u64;
        let mut next = || {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let z: Vec<f64> = (0..20_000)
            .flat_map(|_| {
                let u = [next(), next(), next()];
                extra_depths(ExtraPoints::Gaussian, 0.0, s, 0.0, -10.0, 10.0, &u)
            })
            .map(|t| t / sigma)
            .collect();
        let mean = z.iter().sum::<f64>() / z.len() as f64;
        let var = z.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / z.len() as f64;
        assert!(mean.abs() < 0.02 && (var - 1.0).abs() < 0.03, "mean {mean}, variance {var}");
    }

    #[test]
    fn normal_quantile_matches_known_values() {
        for (u, z) in [(0.5, 0.0), (0.975, 1.959963984540054), (0.025, -1.959963984540054), (0.8413447460685429, 1.0), (1e-10, -6.361340902404056)] {
            assert!((standard_normal_quantile(u) - z).abs() < 1e-8 * z.abs().max(1.0), "Φ⁻¹({u})");
        }
        assert!(standard_normal_quantile(0.0).is_finite() && standard_normal_quantile(1.0).is_finite());
    }

    fn check_gradients(config: &SurfaceLossConfig, ray: &RaySurface, s: f64, t: &[f64], sdf: &[f64], w: &[f64]) -> f64 {
        let n = w.len();
        let (mut ds, mut dw) = (vec![0.0; n + 1], vec![0.0; n]);
        ray_loss(config, ray, s, t, sdf, w, &mut ds, &mut dw);
        let f = |sdf: &[f64], w: &[f64]| ray_loss(config, ray, s, t, sdf, w, &mut vec![0.0; n + 1], &mut vec![0.0; n]).0;
        let h = 1e-6;
        let rel = |a: f64, b: f64| (a - b).abs() / a.abs().max(b.abs()).max(1e-4);
        let mut worst = 0.0f64;
        for i in 0..=n {
            let (mut p, mut m) = (sdf.to_vec(), sdf.to_vec());
            p[i] += h;
            m[i] -= h;
            worst = worst.max(rel(ds[i], (f(&p, w) - f(&m, w)) / (2.0 * h)));
        }
        for i in 0..n {
            let (mut p, mut m) = (w.to_vec(), w.to_vec());
            p[i] += h;
            m[i] -= h;
            worst = worst.max(rel(dw[i], (f(sdf, &p) - f(sdf, &m)) / (2.0 * h)));
        }
        worst
    }

    #[test]
    fn gradients_match_finite_differences_for_near_empty_and_background_rays() {
        let config = SurfaceLossConfig::default();
        let t: Vec<f64> = (0..=12).map(|i| 1.0 + 0.1 * i as f64).collect();
        // SDF crossing zero near t = 1.6, kept away from the |·| kink at the midpoints.
        let sdf: Vec<f64> = t.iter().map(|&x| 1.63 - x + 0.013).collect();
        let w: Vec<f64> = (0..12).map(|i| 0.02 + 0.5 * (-((i as f64 - 6.0) / 2.0).powi(2)).exp()).collect();
        for background in [false, true] {
            for s in [5.0, 50.0] {
                let ray = RaySurface { depth: 1.62, background };
                let err = check_gradients(&config, &ray, s, &t, &sdf, &w);
                assert!(err <= 1e-6, "background {background}, s {s}: relative error {err:e}");
            }
        }
    }

    #[test]
    fn near_band_is_three_logistic_standard_deviations() {
        // One interval at distance 0.9 band from λ̃ is near; at 1.1 band it is empty.
        let config = SurfaceLossConfig { weight: 1.0, lambda_near: 1.0, lambda_far: 1.0, epsilon: 0.0, ..Default::default() };
        let s = 100.0;
        let band = 3.0 * logistic_std(s);
        for (offset, near) in [(0.9, true), (1.1, false)] {
            let mid = 2.0 + offset * band;
            let t = [mid - 1e-4, mid + 1e-4];
            let (_, terms) = ray_loss(&config, &RaySurface { depth: 2.0, background: false }, s, &t, &[0.5, 0.5], &[0.2], &mut [0.0; 2], &mut [0.0]);
            assert_eq!(terms.near > 0.0, near, "offset {offset}");
            assert_eq!(terms.empty > 0.0, !near, "offset {offset}");
            if near {
                assert!((terms.near - 0.1).abs() < 1e-12);
            } else {
                assert!((terms.empty - 0.01).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn background_loss_decays_with_the_distance_to_the_surface() {
        let config = SurfaceLossConfig::default();
        let ray = RaySurface { depth: 0.0, background: true };
        let bg = |sdf: f64| ray_loss(&config, &ray, 50.0, &[0.0, 1.0], &[sdf, sdf], &[0.5], &mut [0.0; 2], &mut [0.0]).1.background;
        assert!((bg(0.0) - 0.5).abs() < 1e-12);
        assert!(bg(0.1) < bg(0.01) && bg(0.5) < 0.01 * bg(0.0));
    }

    #[test]
    fn config_ranges_are_checked() {
        assert!(SurfaceLossConfig::default().validate().is_ok());
        let bad = SurfaceLossConfig { beta: -1.0, ..Default::default() };
        assert!(matches!(bad.validate(), Err(SurfaceLossError::OutOfRange { name: "beta", .. })));
        let bad = SurfaceLossConfig { weight: f64::NAN, ..Default::default() };
        assert!(bad.validate().is_err());
    }

    #[test]
    fn extra_points_follow_the_logistic_spread() {
        // 20 000 Gaussian extra points: mean λ̃, standard deviation π/(√3 s) within 2 %.
        let s = 64.0;
        let u: Vec<f64> = (0..20_000).map(|i| ((i as f64 * 0.618_033_988_749_895) % 1.0 + 0.5 / 20_000.0) % 1.0).collect();
        let d = extra_depths(ExtraPoints::Gaussian, 2.0, s, 0.0, 0.0, 4.0, &u);
        let mean = d.iter().sum::<f64>() / d.len() as f64;
        let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / d.len() as f64;
        assert!((mean - 2.0).abs() < 1e-3, "mean {mean}");
        assert!((var.sqrt() / logistic_std(s) - 1.0).abs() < 0.02, "std {} vs {}", var.sqrt(), logistic_std(s));
        // With λ̃'s own uncertainty: the two spreads add in quadrature.
        let g = extra_depths(ExtraPoints::Gaussian, 2.0, s, 0.05, 0.0, 4.0, &u);
        let std_g = (g.iter().map(|x| (x - 2.0).powi(2)).sum::<f64>() / g.len() as f64).sqrt();
        assert!((std_g / logistic_std(s).hypot(0.05) - 1.0).abs() < 0.02, "std {std_g}");
        // Log variant: wider (ln 64 ≈ 4.2 < 64).
        let l = extra_depths(ExtraPoints::LogVariance, 2.0, s, 0.0, 0.0, 4.0, &u[..2000]);
        let spread = |v: &[f64]| v[v.len() * 3 / 4] - v[v.len() / 4];
        assert!(spread(&l) > 5.0 * spread(&d[..2000].to_vec().tap_sort()));
        // Uniform variant covers [near, far].
        let r = extra_depths(ExtraPoints::Uniform, 2.0, s, 0.0, 1.0, 3.0, &u[..1000]);
        assert!(r[0] >= 1.0 && r[999] <= 3.0 && r[0] < 1.01 && r[999] > 2.99);
    }

    trait TapSort {
        fn tap_sort(self) -> Self;
    }
    impl TapSort for Vec<f64> {
        fn tap_sort(mut self) -> Self {
            self.sort_by(f64::total_cmp);
            self
        }
    }

    proptest! {
        #[test]
        fn extra_depths_stay_in_the_ray_and_are_sorted(
            depth in -1.0f64..5.0, log_s in -3.0f64..7.0, depth_sigma in 0.0f64..2.0, u in proptest::collection::vec(0.0f64..1.0, 0..40)
        ) {
            let s = 10f64.powf(log_s);
            for kind in [ExtraPoints::Gaussian, ExtraPoints::Uniform, ExtraPoints::LogVariance] {
                let d = extra_depths(kind, depth, s, depth_sigma, 0.5, 3.5, &u);
                prop_assert_eq!(d.len(), u.len());
                prop_assert!(d.iter().all(|x| x.is_finite() && (0.5..=3.5).contains(x)));
                prop_assert!(d.windows(2).all(|w| w[0] <= w[1]));
            }
        }

        #[test]
        fn losses_are_finite_and_non_negative_for_any_scale(
            log_s in -3.0f64..7.0, sdf in proptest::collection::vec(-2.0f64..2.0, 5), w in proptest::collection::vec(0.0f64..1.0, 4),
            background: bool
        ) {
            let s = 10f64.powf(log_s);
            let t = [0.5, 1.0, 1.5, 2.0, 2.5];
            let (mut ds, mut dw) = ([0.0; 5], [0.0; 4]);
            let (l, _) = ray_loss(&SurfaceLossConfig::default(), &RaySurface { depth: 1.4, background }, s, &t, &sdf, &w, &mut ds, &mut dw);
            prop_assert!(l.is_finite() && l >= 0.0);
            prop_assert!(ds.iter().chain(&dw).all(|g| g.is_finite()));
        }
    }
}
