//! NeuS volume rendering along one ray, and its backward pass.
//!
//! With SDF values S₀ … Sₙ at depths t₀ < … < tₙ along the ray (paper eq. 3, NeuS's discrete
//! unbiased opacity), interval i ∈ [0, n) has
//! `αᵢ = max((Φ_s(Sᵢ) − Φ_s(Sᵢ₊₁)) / Φ_s(Sᵢ), 0)`, `Tᵢ = Π_{j<i} (1 − αⱼ)`, `wᵢ = αᵢ Tᵢ`,
//! and the ray renders `colour = Σ wᵢ cᵢ`, `depth = Σ wᵢ (tᵢ + tᵢ₊₁)/2`, `opacity = Σ wᵢ`.
//!
//! Numerics: `1 − Φ(b)/Φ(a) = 1 − exp(softplus(−a) − softplus(−b))` with a = sSᵢ, b = sSᵢ₊₁,
//! which neither overflows nor divides 0 by 0 for any s (tested to s = 1e6). The backward pass
//! uses `∂L/∂αᵢ = Tᵢ (gᵢ − Bᵢ₊₁)`, `Bᵢ = gᵢ αᵢ + (1 − αᵢ) Bᵢ₊₁` (gᵢ = ∂L/∂wᵢ), which has no
//! division by 1 − αᵢ, so opaque intervals (α = 1) are fine.
//!
//! Worked example: α = [0.4, 0.8, 0.1] gives w = [0.4, 0.48, 0.012].

use crate::module::sigmoid;
use crate::real::{Real, exp_nonpositive_f32};

/// `ln(1 + eˣ)` without overflow.
#[inline]
fn softplus<R: Real>(x: R) -> R {
    if x > R::ZERO { x + (-x).exp().ln_1p() } else { x.exp().ln_1p() }
}

/// What one ray renders, with the per-interval opacities and weights kept for the backward pass.
#[derive(Debug, Clone, PartialEq)]
pub struct RayRender<R> {
    /// αᵢ per interval.
    pub alphas: Vec<R>,
    /// wᵢ per interval.
    pub weights: Vec<R>,
    /// Σ wᵢ cᵢ.
    pub color: [R; 3],
    /// Σ wᵢ (tᵢ + tᵢ₊₁)/2.
    pub depth: R,
    /// Σ wᵢ.
    pub opacity: R,
}

/// −ln Φ_s(S) = softplus(−sS): what one SDF value S contributes to the α of each interval it
/// ends, computed once per value (each value ends two intervals).
#[inline]
fn neg_log_phi<R: Real>(s: R, value: R) -> R {
    softplus(-(s * value))
}

/// The ratio r = Φ(b)/Φ(a) = exp(ln Φ(b) − ln Φ(a)) of an interval from its two ends'
/// [`neg_log_phi`]: αᵢ = 1 − r, ∂α/∂a = r σ(−a), ∂α/∂b = −r σ(−b) (a = sSᵢ, b = sSᵢ₊₁); `None`
/// where Φ(b) ≥ Φ(a), α clamped to 0 with both derivatives. NaN stays NaN (not clamped).
#[inline]
fn phi_ratio<R: Real>(neg_log_phi_a: R, neg_log_phi_b: R) -> Option<R> {
    let log_ratio = neg_log_phi_a - neg_log_phi_b; // ln(Φ(b)/Φ(a))
    (!(log_ratio >= R::ZERO)).then(|| log_ratio.exp())
}

/// The opacities αᵢ of the intervals between `sdf`'s values at scale `s`, passed to `each` in
/// order with their index.
#[inline]
fn for_each_alpha<R: Real>(sdf: &[R], s: R, mut each: impl FnMut(usize, R)) {
    let Some((&first, rest)) = sdf.split_first() else { return };
    let mut a = neg_log_phi(s, first);
    for (i, &next) in rest.iter().enumerate() {
        let b = neg_log_phi(s, next);
        each(i, phi_ratio(a, b).map_or(R::ZERO, |r| R::ONE - r));
        a = b;
    }
}

/// The weights wᵢ of the n intervals between n + 1 SDF values at scale `s`, into `weights`
/// (cleared first; no allocation once it has grown).
pub fn weights_into<R: Real>(sdf: &[R], s: R, weights: &mut Vec<R>) {
    weights.clear();
    let mut transmittance = R::ONE;
    for_each_alpha(sdf, s, |_, a| {
        weights.push(a * transmittance);
        transmittance *= R::ONE - a;
    });
}

/// [`weights_into`] for a render, where nothing is differentiated: in f32 the opacities of all
/// intervals first, vectorised (the polynomial softplus of [`Real::softplus_with_derivative`] and
/// [`exp_nonpositive_f32`], relative errors < 1e-6 against the standard library's, which
/// [`weights_into`] calls per value), then the transmittance's product in order; in f64
/// [`weights_into`] itself. Training (the loss's [`render_ray`], its up-sampling) keeps
/// [`weights_into`]'s arithmetic: renders change no bit of it.
pub fn render_weights_into<R: Real>(sdf: &[R], s: R, weights: &mut Vec<R>) {
    if sdf.len() < 2 {
        // No interval (a ray that crosses nothing a render evaluates).
        weights.clear();
        return;
    }
    let Some(values) = R::f32s(sdf) else {
        return weights_into(sdf, s, weights);
    };
    weights.clear();
    weights.resize(sdf.len().saturating_sub(1), R::ZERO);
    let alphas = R::f32s_mut(weights).expect("R is f32, as the values are");
    let s = s.to_f64() as f32;
    crate::kernels::dispatch(
        #[inline(always)]
        || fast_alphas(values, s, alphas),
    );
    let mut transmittance = 1.0f32;
    for w in alphas.iter_mut() {
        let alpha = *w;
        *w = alpha * transmittance;
        transmittance *= 1.0 - alpha;
    }
}

/// [`neg_log_phi`] in f32 by the polynomial softplus.
#[inline(always)]
fn fast_neg_log_phi(s: f32, value: f32) -> f32 {
    (-(s * value)).softplus_with_derivative(1.0).0
}

/// αᵢ = 1 − Φ(b)/Φ(a) of every interval between `sdf`'s values (0 where Φ(b) ≥ Φ(a), NaN where
/// a value is NaN, as in [`weights_into`]: a broken model must not render as a plausible one), by
/// polynomials and selects only, so that the loop vectorises; each value's softplus is computed
/// for both its intervals, with no buffer to store it (which of the two is faster was not
/// measured).
#[inline(always)]
fn fast_alphas(sdf: &[f32], s: f32, alphas: &mut [f32]) {
    for ((alpha, &a), &b) in alphas.iter_mut().zip(sdf).zip(&sdf[1..]) {
        let log_ratio = fast_neg_log_phi(s, a) - fast_neg_log_phi(s, b);
        // Selects, not `min`, which would drop a NaN log ratio (a NaN value's): it stays NaN.
        let ratio = exp_nonpositive_f32(if log_ratio > 0.0 { 0.0 } else { log_ratio });
        *alpha = if log_ratio >= 0.0 { 0.0 } else { 1.0 - ratio };
    }
}

/// Renders one ray: `sdf` and `t` have n + 1 values, `colors` n (one per interval).
pub fn render_ray<R: Real>(sdf: &[R], t: &[R], colors: &[[R; 3]], s: R) -> RayRender<R> {
    let n = colors.len();
    assert!(sdf.len() == n + 1 && t.len() == n + 1, "render_ray: need n + 1 SDF values and depths for n colours");
    let mut out = RayRender { alphas: vec![R::ZERO; n], weights: vec![R::ZERO; n], color: [R::ZERO; 3], depth: R::ZERO, opacity: R::ZERO };
    let mut transmittance = R::ONE;
    for_each_alpha(sdf, s, |i, a| {
        let w = a * transmittance;
        out.alphas[i] = a;
        out.weights[i] = w;
        for k in 0..3 {
            out.color[k] += w * colors[i][k];
        }
        out.depth += w * (t[i] + t[i + 1]) * R::of(0.5);
        out.opacity += w;
        transmittance *= R::ONE - a;
    });
    out
}

/// Gradients of a ray's loss.
#[derive(Debug, Clone, PartialEq)]
pub struct RayGradients<R> {
    /// ∂L/∂Sᵢ (n + 1 values).
    pub sdf: Vec<R>,
    /// ∂L/∂cᵢ (n values).
    pub colors: Vec<[R; 3]>,
    /// ∂L/∂s.
    pub s: R,
}

/// Backward pass of [`render_ray`] for `∂L/∂colour`, `∂L/∂depth`, `∂L/∂opacity` and, optionally,
/// direct `∂L/∂wᵢ` (surface losses use the weights).
#[allow(clippy::too_many_arguments)]
pub fn render_ray_backward<R: Real>(
    sdf: &[R],
    t: &[R],
    colors: &[[R; 3]],
    s: R,
    forward: &RayRender<R>,
    d_color: [R; 3],
    d_depth: R,
    d_opacity: R,
    d_weights: Option<&[R]>,
) -> RayGradients<R> {
    let n = colors.len();
    let mut grads = RayGradients { sdf: vec![R::ZERO; n + 1], colors: vec![[R::ZERO; 3]; n], s: R::ZERO };
    // gᵢ = ∂L/∂wᵢ.
    let g: Vec<R> = (0..n)
        .map(|i| {
            let mut gi = d_opacity + d_depth * (t[i] + t[i + 1]) * R::of(0.5);
            for k in 0..3 {
                gi += d_color[k] * colors[i][k];
            }
            if let Some(dw) = d_weights {
                gi += dw[i];
            }
            gi
        })
        .collect();
    for i in 0..n {
        for k in 0..3 {
            grads.colors[i][k] = forward.weights[i] * d_color[k];
        }
    }
    // Bᵢ from the back, Tᵢ from the front.
    let mut b_next = R::ZERO;
    let mut b = vec![R::ZERO; n + 1];
    for i in (0..n).rev() {
        b[i] = g[i] * forward.alphas[i] + (R::ONE - forward.alphas[i]) * b_next;
        b_next = b[i];
    }
    // Each value's −ln Φ and σ(−sS), once per value rather than once for each of its intervals.
    let per_value: Vec<(R, R)> = sdf.iter().map(|&v| (neg_log_phi(s, v), sigmoid(-(s * v)))).collect();
    let mut transmittance = R::ONE;
    for i in 0..n {
        let d_alpha = transmittance * (g[i] - b[i + 1]);
        let ((log_phi_a, sig_a), (log_phi_b, sig_b)) = (per_value[i], per_value[i + 1]);
        let (da, db) = phi_ratio(log_phi_a, log_phi_b).map_or((R::ZERO, R::ZERO), |r| (r * sig_a, -r * sig_b));
        grads.sdf[i] += d_alpha * da * s;
        grads.sdf[i + 1] += d_alpha * db * s;
        grads.s += d_alpha * (da * sdf[i] + db * sdf[i + 1]);
        transmittance *= R::ONE - forward.alphas[i];
    }
    grads
}

/// `k` depths at the quantiles `(j + ½)/k` of the piecewise-constant density over the intervals
/// of `depths` with masses `weights + 1e-5` (NeuS's padding, so that an empty ray still gets
/// samples spread along it), each placed linearly inside its interval. Sorted.
pub fn sample_intervals(depths: &[f32], weights: &[f32], k: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(k);
    sample_intervals_into(depths, weights, k, &mut Vec::new(), &mut out);
    out
}

/// [`sample_intervals`]' `k` depths appended to `out`, the cumulative masses in `cdf` (cleared
/// first): an up-sampling's rays share both, no allocation per ray once they have grown.
pub fn sample_intervals_into(depths: &[f32], weights: &[f32], k: usize, cdf: &mut Vec<f64>, out: &mut Vec<f32>) {
    let n = weights.len();
    debug_assert_eq!(depths.len(), n + 1);
    cdf.clear();
    cdf.push(0.0f64);
    for &w in weights {
        let w = if w.is_finite() { f64::from(w.max(0.0)) } else { 0.0 };
        cdf.push(cdf.last().copied().unwrap_or(0.0) + w + 1e-5);
    }
    let total = cdf[n];
    let mut i = 0;
    for j in 0..k {
        let target = (j as f64 + 0.5) / k as f64 * total;
        while i + 1 < n && cdf[i + 1] < target {
            i += 1;
        }
        let frac = ((target - cdf[i]) / (cdf[i + 1] - cdf[i])).clamp(0.0, 1.0) as f32;
        out.push(depths[i] + frac * (depths[i + 1] - depths[i]));
    }
}

/// The union of two sorted depth lists, sorted (on a tie `a`'s depth first): `merge_in_place`
/// into a copy of `a`.
pub fn merge_sorted(a: &[f32], b: &[f32]) -> Vec<f32> {
    let mut out = Vec::with_capacity(a.len() + b.len());
    out.extend_from_slice(a);
    merge_in_place(&mut out, b, None);
    out
}

/// The sorted depths `new` merged into the sorted `depths` in place, on a tie the old depth first,
/// from the back: no allocation once `depths` has room (an up-sampling's rounds);
/// with `values`, each depth's value (`values`, and `new`'s in the pair's slice) follows it.
pub(crate) fn merge_in_place(depths: &mut Vec<f32>, new: &[f32], mut values: Option<(&mut Vec<f32>, &[f32])>) {
    let (mut i, mut j) = (depths.len(), new.len());
    depths.resize(i + j, 0.0);
    if let Some((values, _)) = values.as_mut() {
        values.resize(i + j, 0.0);
    }
    while j > 0 {
        let at = i + j - 1;
        // In order the old depth comes first while it is ≤ the new one: from the back, the new
        // one goes last unless the old one is not ≤ it (greater, or NaN).
        if i > 0 && !(depths[i - 1] <= new[j - 1]) {
            depths[at] = depths[i - 1];
            if let Some((values, _)) = values.as_mut() {
                values[at] = values[i - 1];
            }
            i -= 1;
        } else {
            depths[at] = new[j - 1];
            if let Some((values, new_values)) = values.as_mut() {
                values[at] = new_values[j - 1];
            }
            j -= 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both lists one after the other, sorted stably: on a tie the first list's depth first.
    fn stable_merge(a: &[f32], b: &[f32]) -> Vec<f32> {
        let mut all: Vec<f32> = a.iter().chain(b).copied().collect();
        all.sort_by(|x, y| x.partial_cmp(y).expect("finite depths"));
        all
    }

    #[test]
    fn merging_in_place_is_the_stable_merge_of_the_two_lists() {
        let (a, b) = ([0.0, 1.0, 1.0, 3.0], [1.0, 2.0, 4.0]);
        let (mut d, mut v) = (a.to_vec(), vec![10.0, 11.0, 12.0, 13.0]);
        merge_in_place(&mut d, &b, Some((&mut v, &[21.0, 22.0, 24.0])));
        assert_eq!(d, stable_merge(&a, &b));
        assert_eq!(v, vec![10.0, 11.0, 12.0, 21.0, 22.0, 13.0, 24.0]);
        // Without values; new depths all before, all after, none, into none.
        for (a, b) in [(&[2.0, 3.0][..], &[0.5, 1.0][..]), (&[0.0, 1.0], &[1.0, 5.0]), (&[1.0], &[]), (&[], &[1.0, 2.0])] {
            let mut d = a.to_vec();
            merge_in_place(&mut d, b, None);
            assert_eq!(d, stable_merge(a, b), "{a:?} {b:?}");
            assert_eq!(merge_sorted(a, b), d, "{a:?} {b:?}");
        }
        // A NaN depth goes last, as the loop in order (old first while ≤ the new) put it.
        let mut d = vec![f32::NAN];
        merge_in_place(&mut d, &[1.0], None);
        assert_eq!(d.iter().map(|v| v.is_nan()).collect::<Vec<_>>(), [false, true]);
    }

    #[test]
    fn up_sampling_puts_new_depths_where_the_weight_is() {
        // All weight in interval 2 of [0, 1, 2, 3, 4]: every new depth falls in [2, 3].
        let d = [0.0, 1.0, 2.0, 3.0, 4.0];
        let new = sample_intervals(&d, &[0.0, 0.0, 1.0, 0.0], 8);
        assert!(new.iter().all(|&t| (2.0..=3.0).contains(&t)), "{new:?}");
        assert!(new.windows(2).all(|w| w[0] <= w[1]));
        // No weight at all: spread evenly.
        let even = sample_intervals(&d, &[0.0; 4], 4);
        for (t, want) in even.iter().zip([0.5, 1.5, 2.5, 3.5]) {
            assert!((t - want).abs() < 1e-4, "{even:?}");
        }
        let m = merge_sorted(&d, &new);
        assert_eq!(m.len(), 13);
        assert!(m.windows(2).all(|w| w[0] <= w[1]));
    }

    /// A render's vectorised f32 weights against the exact f64 ones, beside the exact f32 ones
    /// (the standard library's functions), on rays through one or two surfaces, rising SDF
    /// (α = 0) and a ray that misses, from a soft scale to one far sharper than training reaches.
    #[test]
    fn render_weights_are_the_exact_weights_to_f32_precision() {
        let mut worst = (0.0f64, 0.0f64);
        for s in [1.0f32, 64.0, 700.0, 5000.0, 1e5] {
            for ray in 0..40 {
                let phase = ray as f32 * 0.173;
                let sdf: Vec<f32> = (0..=64)
                    .map(|i| {
                        let t = i as f32 / 64.0;
                        let first = 0.31 + 0.01 * phase - t; // a surface near a third of the way
                        let second = (t - 0.7 - 0.005 * phase).abs() - 0.05; // a thin shell behind it
                        if ray % 10 == 9 { 0.4 + 0.1 * (t * 9.0 + phase).sin() } else { first.max(-second) }
                    })
                    .collect();
                let sdf64: Vec<f64> = sdf.iter().map(|&v| f64::from(v)).collect();
                let (mut fast, mut exact, mut truth) = (Vec::new(), Vec::new(), Vec::new());
                render_weights_into(&sdf, s, &mut fast);
                weights_into(&sdf, s, &mut exact);
                weights_into(&sdf64, f64::from(s), &mut truth);
                assert_eq!(fast.len(), truth.len());
                for ((&f, &e), &t) in fast.iter().zip(&exact).zip(&truth) {
                    assert!((0.0..=1.0).contains(&f), "weight {f} at s = {s}");
                    worst.0 = worst.0.max((f64::from(f) - t).abs());
                    worst.1 = worst.1.max((f64::from(e) - t).abs());
                }
            }
        }
        assert!(worst.0 <= 1e-6, "the render's weights differ from the exact f64 ones by {:e} (the exact f32 ones by {:e})", worst.0, worst.1);
        // A NaN value poisons its intervals and those behind them, in both (a broken model must
        // not render, nor train, as a plausible one).
        let sdf = [0.5f32, 0.2, f32::NAN, -0.1, -0.3];
        let (mut fast, mut exact) = (Vec::new(), Vec::new());
        render_weights_into(&sdf, 64.0, &mut fast);
        weights_into(&sdf, 64.0, &mut exact);
        let nan = |w: &[f32]| w.iter().map(|v| v.is_nan()).collect::<Vec<_>>();
        assert_eq!(nan(&fast), [false, true, true, true]);
        assert_eq!(nan(&fast), nan(&exact));
    }

    /// Guards a render's rays with no interval (one that crosses no occupied cell has no depth):
    /// no weight, in f32 and f64, where the f32 path once sliced past the end.
    #[test]
    fn a_ray_without_an_interval_renders_no_weight() {
        let mut weights = vec![0.5f32];
        for sdf in [&[][..], &[0.3f32][..]] {
            render_weights_into(sdf, 64.0, &mut weights);
            assert!(weights.is_empty(), "{sdf:?}: {weights:?}");
        }
        let mut weights = vec![0.5f64];
        render_weights_into(&[0.3f64], 64.0, &mut weights);
        assert!(weights.is_empty());
    }

    /// Each value's softplus is computed once for its two intervals: every α must still be its
    /// own interval's alone, to the bit (f32, the precision renders run in) and against the
    /// closed form (Φ(a) − Φ(b))/Φ(a) clamped at 0 (f64), at a sharp and a soft scale, across a
    /// surface, a second surface behind it and intervals where the SDF rises (α = 0).
    #[test]
    fn each_alpha_is_its_own_intervals_alone() {
        let sdf: Vec<f32> = [0.9, 0.5, 0.2, 0.05, -0.01, -0.2, -0.1, 0.3, 0.02, -0.4, -0.4, 1.0].to_vec();
        let colors = vec![[0.0f32; 3]; sdf.len() - 1];
        let depths: Vec<f32> = (0..sdf.len()).map(|i| i as f32).collect();
        for s in [2.0f32, 300.0] {
            let rendered = render_ray(&sdf, &depths, &colors, s);
            let mut weights = Vec::new();
            weights_into(&sdf, s, &mut weights);
            assert_eq!(weights, rendered.weights, "weights_into and render_ray at s = {s}");
            for (i, pair) in sdf.windows(2).enumerate() {
                let log_ratio = softplus(-(s * pair[0])) - softplus(-(s * pair[1]));
                let alone = if log_ratio >= 0.0 { 0.0 } else { 1.0 - log_ratio.exp() };
                assert_eq!(rendered.alphas[i].to_bits(), alone.to_bits(), "interval {i} at s = {s}");
                let phi = |x: f32| 1.0 / (1.0 + (-f64::from(s) * f64::from(x)).exp());
                let closed = ((phi(pair[0]) - phi(pair[1])) / phi(pair[0])).max(0.0);
                assert!((f64::from(alone) - closed).abs() < 1e-5, "interval {i} at s = {s}: {alone} against {closed}");
            }
        }
    }
}
