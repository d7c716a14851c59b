//! NeuS's hierarchical up-sampling, each depth's SDF evaluated once, and the trim of a render's
//! rays to the samples that carry weight.
//!
//! Up-sampling places `n_fine` depths in `rounds` rounds at the quantiles of the rendering
//! weights at scale `base_s · 2^round` (NeuS: 64 · 2^i). The SDF at a depth does not change
//! between rounds, so each depth is evaluated once and its value carried with it (rows of the
//! SDF network are independent: the values, and so the depths placed, are those of evaluating
//! every depth again each round).
//!
//! A render needs no gradient, and most of a ray's samples carry no weight: before the surface
//! α ≈ 0, behind it the transmittance ≈ 0, and a ray that misses the object carries none at
//! all. [`trim_to_weight`] keeps the contiguous run of intervals outside which the weights sum
//! to at most `negligible` on each side: within it α is exactly that of the whole ray (the
//! discrete NeuS opacity of an interval depends on its two ends only), the weights are the whole
//! ray's divided by the transmittance of the dropped front (≥ 1 − `negligible`), and the colour,
//! depth and opacity differ by at most about `2 · negligible`.

use crate::backbone::Backbone;
use crate::module::Module;
use crate::pipeline::RayInput;
use crate::render::{merge_in_place, render_weights_into, sample_intervals_into, weights_into};
use crate::scratch::Buf;

/// The SDF at points (rows × 3) into one value a row: [`Backbone::sdf_rows`].
trait SdfRows: Fn(&[f32], &mut [f32]) + Sync {}
impl<F: Fn(&[f32], &mut [f32]) + Sync> SdfRows for F {}

/// The SDF (`sdf`) at `depths[i]` along `rays[i]` for each ray of a chunk, in one forward pass
/// over all their points, the rays' values one after another (rows of the network are
/// independent: the values are those of evaluating each ray alone).
fn chunk_sdf(sdf: &impl SdfRows, rays: &[RayInput<f32>], depths: &[&[f32]]) -> Buf<f32> {
    let rows: usize = depths.iter().map(|d| d.len()).sum();
    let mut points = Vec::with_capacity(3 * rows);
    for (ray, depths) in rays.iter().zip(depths) {
        let (o, d) = (ray.origin, ray.direction);
        for &t in depths.iter() {
            points.extend_from_slice(&[o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]);
        }
    }
    let mut values = Buf::<f32>::to_overwrite(rows);
    sdf(&points, &mut values);
    values
}

/// [`chunk_sdf`]'s `values` (the rays' one after another) as one list per ray of `lists`, each
/// with room for `room` more values.
fn per_ray(values: &[f32], lists: &[&[f32]], room: usize) -> Vec<Vec<f32>> {
    let mut rest = values;
    lists
        .iter()
        .map(|depths| {
            let (own, tail) = rest.split_at(depths.len());
            rest = tail;
            let mut list = Vec::with_capacity(own.len() + room);
            list.extend_from_slice(own);
            list
        })
        .collect()
}

/// The SDF at `depths` along one ray, by `net`'s own [`Module::forward_first`].
#[cfg(test)]
fn ray_sdf<S: Module<f32> + Sync>(net: &S, params: &[f32], ray: &RayInput<f32>, depths: &[f32]) -> Vec<f32> {
    let sdf = |points: &[f32], out: &mut [f32]| net.forward_first(&params[..net.n_params()], points, out);
    chunk_sdf(&sdf, std::slice::from_ref(ray), &[depths]).to_vec()
}

/// What an up-sampling is for: training (weights by [`weights_into`], no values kept) or a
/// render (weights by [`render_weights_into`], the SDF at each final depth kept), trimmed by
/// [`Trim`] when given.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Purpose {
    Training,
    Render(Option<Trim>),
}

/// Up-samples a chunk of rays (one forward pass per round over all of them); for a render,
/// returns the SDF at each ray's final depths, no depth added to a ray once its values are
/// [`proven_faint`] (before any round) or [`resolved`] (before any round after the first), each
/// ray trimmed by [`trim_to_weight`] when `Purpose::Render` has a [`Trim`].
fn upsample_chunk(sdf_rows: &impl SdfRows, rays: &mut [RayInput<f32>], n_fine: usize, rounds: usize, base_s: f64, purpose: Purpose) -> Vec<Vec<f32>> {
    let _span = crate::profile::span(crate::profile::Stage::Upsample);
    let rounds = if n_fine == 0 { 0 } else { rounds };
    if rounds == 0 && purpose == Purpose::Training {
        return Vec::new();
    }
    let lists: Vec<&[f32]> = rays.iter().map(|r| r.depths.as_slice()).collect();
    // Each ray's values, and its depths, with room for every depth placed.
    let mut sdf = per_ray(&chunk_sdf(sdf_rows, rays, &lists), &lists, n_fine);
    for ray in rays.iter_mut() {
        ray.depths.reserve_exact(n_fine);
    }
    let mut faint = vec![false; rays.len()];
    let mut placed_before = 0;
    // Buffers every ray and round shares: the weights (the resolution rule's, then the
    // placement's), the placement's cumulative masses, and the depths placed (each ray's span).
    let (mut weights, mut cdf, mut new, mut spans) = (Vec::new(), Vec::new(), Vec::new(), Vec::with_capacity(rays.len()));
    for round in 0..rounds {
        let k = n_fine / rounds + usize::from(round < n_fine % rounds);
        if let Purpose::Render(Some(trim)) = purpose {
            // Each round's values prove more: its samples lie where the SDF is lowest. A ray is
            // judged resolved only once a round has placed samples where its weights are.
            let still = n_fine - placed_before;
            for ((faint, ray), sdf) in faint.iter_mut().zip(rays.iter()).zip(&sdf) {
                *faint = *faint
                    || proven_faint(&ray.depths, sdf, trim, ray.depths.len().saturating_sub(1) + still)
                    || (round >= 1 && trim.resolved.is_some_and(|most| resolved_with(sdf, trim.s, most, &mut weights)));
            }
        }
        placed_before += k;
        let s = (base_s * f64::from(1u32 << round.min(30))) as f32;
        new.clear();
        spans.clear();
        for ((ray, sdf), &faint) in rays.iter().zip(&sdf).zip(&faint) {
            let start = new.len();
            if !faint {
                match purpose {
                    Purpose::Training => weights_into(sdf, s, &mut weights),
                    Purpose::Render(_) => render_weights_into(sdf, s, &mut weights),
                }
                sample_intervals_into(&ray.depths, &weights, k, &mut cdf, &mut new);
            }
            spans.push(start..new.len());
        }
        if round + 1 == rounds && purpose == Purpose::Training {
            for (ray, span) in rays.iter_mut().zip(&spans) {
                merge_in_place(&mut ray.depths, &new[span.clone()], None);
            }
        } else {
            let lists: Vec<&[f32]> = spans.iter().map(|span| &new[span.clone()]).collect();
            let new_sdf = chunk_sdf(sdf_rows, rays, &lists);
            for ((ray, sdf), span) in rays.iter_mut().zip(sdf.iter_mut()).zip(&spans) {
                merge_in_place(&mut ray.depths, &new[span.clone()], Some((sdf, &new_sdf[span.clone()])));
            }
        }
    }
    let Purpose::Render(trim) = purpose else { return Vec::new() };
    if let Some(Trim { s, negligible, .. }) = trim {
        for (ray, sdf) in rays.iter_mut().zip(sdf.iter_mut()) {
            trim_to_weight(&mut ray.depths, sdf, s, negligible);
        }
    }
    sdf
}

/// Whether a render's ray (`depths` with the SDF `sdf` at each) is proven to carry at most
/// `trim.negligible` of weight in all, wherever `intervals` intervals between its first and last
/// depth are put: with the field's Lipschitz bound L (`trim.lipschitz`; without one, never),
/// the SDF is at least `m = min_i (f_i + f_{i+1} − L (t_{i+1} − t_i)) / 2` between them, and an
/// interval's NeuS opacity is at most `1 − Φ_s(f_end) ≤ e^{−s m}` (Φ_s the logistic at scale
/// s), so the weights sum to at most `n e^{−s m}` ≤ `negligible / 2` (half kept for the f32
/// rounding) when `m ≥ ln(2n / negligible) / s`. Such a ray's up-sampled samples would all be
/// trimmed away ([`trim_to_weight`] keeps its last interval), so a render need not place them.
/// A bound or a value that is not finite, a scale s that is not positive, or two values further
/// apart than the bound allows (the claim is broken there), prove nothing.
pub fn proven_faint(depths: &[f32], sdf: &[f32], trim: Trim, intervals: usize) -> bool {
    let Some(lipschitz) = trim.lipschitz.filter(|l| l.is_finite() && *l >= 0.0) else { return false };
    if !(trim.s > 0.0) || depths.len() < 2 || sdf.len() != depths.len() || !sdf.iter().all(|v| v.is_finite()) {
        return false;
    }
    let pairs = || depths.windows(2).zip(sdf.windows(2));
    if pairs().any(|(t, f)| (f[1] - f[0]).abs() > lipschitz * (t[1] - t[0])) {
        // A slope steeper than the bound: the claim is broken here.
        return false;
    }
    // Half the trim, for the f32 rounding of the weights and of their sum in the trim.
    let floor = (intervals as f32 / (0.5 * trim.negligible)).ln() / trim.s;
    let lowest = pairs().map(|(t, f)| 0.5 * (f[0] + f[1] - lipschitz * (t[1] - t[0]))).fold(f32::INFINITY, f32::min);
    lowest >= floor && floor.is_finite()
}

/// Whether a render's ray (the SDF `sdf` at its depths) is resolved at the model's scale `s`: no
/// interval carries more than `most` of weight ([`render_weights_into`]). Unlike
/// [`proven_faint`] this proves nothing about what lies between the samples: a render asks it
/// only after a round has placed samples by the weights (NeuS's up-sampling at a lower scale,
/// wider than the model's). Most rays it stops carry next to nothing in all (they graze or miss
/// the object), where a last round's samples changed no colour measurably (docs/DECISIONS.md
/// §55). A NaN weight is not resolved.
pub fn resolved(sdf: &[f32], s: f32, most: f32) -> bool {
    resolved_with(sdf, s, most, &mut Vec::new())
}

/// [`resolved`] with the weights in `weights` (an up-sampling's rays share one buffer).
fn resolved_with(sdf: &[f32], s: f32, most: f32, weights: &mut Vec<f32>) -> bool {
    render_weights_into(sdf, s, weights);
    weights.iter().all(|&w| w <= most)
}

/// How a render trims its rays ([`trim_to_weight`]): at the model's scale `s`, dropping at most
/// `negligible` of a ray's weight on each side; with the field's Lipschitz bound, a ray whose
/// coarse values prove it carries at most `negligible` in all is not up-sampled
/// ([`proven_faint`]); with `resolved`, a ray none of whose intervals carries more after a round
/// is up-sampled no further ([`resolved`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Trim {
    /// The model's logistic scale.
    pub s: f32,
    /// The weight a ray may drop on each side.
    pub negligible: f32,
    /// A bound on the SDF's Lipschitz constant (`None`: no ray is proven faint).
    pub lipschitz: Option<f32>,
    /// No more depths on a ray once no interval carries more than this weight ([`resolved`]).
    pub resolved: Option<f32>,
}

/// Rays per forward pass of the up-sampling.
const CHUNK: usize = 64;

/// On the presets' [`Backbone`] alone, so compiled here once ([`crate::compiled`]).
impl Backbone {
    /// The SDF network's value at points (rows × 3, one value a row out), as
    /// [`Module::forward_first`] computes it, to the bit, with its MLP's layers packed once for
    /// every call ([`crate::Mlp::packed_layers`]): an up-sampling calls it per chunk of rays and
    /// round, and packing per call was a pass over the weights each time.
    fn sdf_rows<'a>(&'a self, params: &'a [f32]) -> impl SdfRows + 'a {
        let (encoding, mlp) = (&self.sdf.a, &self.sdf.b);
        let (p_encoding, p_mlp) = params[..Module::<f32>::n_params(&self.sdf)].split_at(Module::<f32>::n_params(encoding));
        let packed = mlp.packed_layers(p_mlp);
        move |points: &[f32], out: &mut [f32]| {
            let mut features = Buf::<f32>::to_overwrite(out.len() * Module::<f32>::n_outputs(encoding));
            encoding.infer(p_encoding, points, &mut features);
            mlp.infer_packed(&packed, &features, out, 1);
        }
    }

    /// NeuS's hierarchical up-sampling: `rounds` rounds, each weighting the intervals of the
    /// ray's current depths as rendering would at scale `base_s · 2^round` and inserting
    /// `n_fine / rounds` depths at the weights' quantiles (midpoints, deterministic). Depths stay
    /// sorted. No gradient flows through the placement.
    pub fn upsample(&self, params: &[f32], rays: &mut [RayInput<f32>], n_fine: usize, rounds: usize, base_s: f64) {
        use rayon::prelude::*;
        let sdf = self.sdf_rows(params);
        rays.par_chunks_mut(CHUNK).for_each(|rays| {
            upsample_chunk(&sdf, rays, n_fine, rounds, base_s, Purpose::Training);
        });
    }

    /// [`Self::upsample`] for a render, each depth's SDF kept: each ray then trimmed by
    /// [`trim_to_weight`] when `trim` is given, chunk by chunk, no depth placed on a ray that `trim`'s Lipschitz bound proves faint
    /// ([`proven_faint`]). Returns the SDF at every ray's final depths, for [`Self::render`].
    pub fn upsample_for_render(
        &self,
        params: &[f32],
        rays: &mut [RayInput<f32>],
        n_fine: usize,
        rounds: usize,
        base_s: f64,
        trim: Option<Trim>,
    ) -> Vec<Vec<f32>> {
        use rayon::prelude::*;
        let sdf = self.sdf_rows(params);
        rays.par_chunks_mut(CHUNK).flat_map_iter(|rays| upsample_chunk(&sdf, rays, n_fine, rounds, base_s, Purpose::Render(trim))).collect()
    }

    /// The SDF at every depth of every ray (no up-sampling), in parallel chunks.
    pub fn sdf_along(&self, params: &[f32], rays: &[RayInput<f32>]) -> Vec<Vec<f32>> {
        use rayon::prelude::*;
        let sdf = self.sdf_rows(params);
        rays.par_chunks(CHUNK)
            .flat_map_iter(|rays| {
                let _span = crate::profile::span(crate::profile::Stage::Upsample);
                let lists: Vec<&[f32]> = rays.iter().map(|r| r.depths.as_slice()).collect();
                per_ray(&chunk_sdf(&sdf, rays, &lists), &lists, 0)
            })
            .collect()
    }
}

/// Rendering weights of the intervals between samples with SDF values `sdf` at scale `s`.
pub fn interval_weights(sdf: &[f32], s: f32) -> Vec<f32> {
    let mut weights = Vec::with_capacity(sdf.len().saturating_sub(1));
    weights_into(sdf, s, &mut weights);
    weights
}

/// Trims a render's ray (`depths` with the SDF `sdf` at each, rendered at scale `s`) to the
/// contiguous intervals outside which the weights ([`render_weights_into`]) sum to at most
/// `negligible` on each side (at least one interval: a ray that carries no weight keeps its
/// last), the values with their depths. Returns how many depths were dropped. See the module
/// docs for what this preserves.
pub fn trim_to_weight(depths: &mut Vec<f32>, sdf: &mut Vec<f32>, s: f32, negligible: f32) -> usize {
    let n = depths.len();
    if n < 3 || sdf.len() != n {
        return 0;
    }
    let mut weights = Vec::with_capacity(n - 1);
    render_weights_into(sdf, s, &mut weights);
    let mut first = 0;
    let mut before = 0.0f32;
    while first < weights.len() && before + weights[first] <= negligible {
        before += weights[first];
        first += 1;
    }
    if first == weights.len() {
        // No weight anywhere: one interval (the last) stands for the ray.
        depths.drain(..n - 2);
        sdf.drain(..n - 2);
        return n - 2;
    }
    let mut last = weights.len() - 1;
    let mut after = 0.0f32;
    while last > first && after + weights[last] <= negligible {
        after += weights[last];
        last -= 1;
    }
    // Intervals first..=last span depths first..=last + 1.
    for list in [&mut *depths, &mut *sdf] {
        list.truncate(last + 2);
        list.drain(..first);
    }
    n - depths.len()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::render::{merge_sorted, render_ray, sample_intervals};

    #[test]
    fn trimming_keeps_the_weights_and_colour_of_a_ray_through_a_surface() {
        // A plane at t = 1.3 along a ray sampled every 0.05 over [0, 3].
        let depths: Vec<f32> = (0..=60).map(|i| i as f32 * 0.05).collect();
        let sdf: Vec<f32> = depths.iter().map(|t| 1.3 - t).collect();
        let colors: Vec<[f32; 3]> = (0..60).map(|i| [i as f32 / 60.0, 0.5, 1.0]).collect();
        let s = 200.0;
        let whole = render_ray(&sdf, &depths, &colors, s);
        let (mut trimmed, mut trimmed_sdf) = (depths.clone(), sdf.clone());
        let dropped = trim_to_weight(&mut trimmed, &mut trimmed_sdf, s, 1e-4);
        assert!(dropped > 40, "only {dropped} of 61 depths dropped");
        let first = depths.iter().position(|&t| t == trimmed[0]).unwrap();
        let kept = trimmed.len();
        assert_eq!(trimmed_sdf, &sdf[first..first + kept], "the values follow their depths");
        let part = render_ray(&trimmed_sdf, &trimmed, &colors[first..first + kept - 1], s);
        for c in 0..3 {
            assert!((part.color[c] - whole.color[c]).abs() <= 2e-4, "colour {c}: {} vs {}", part.color[c], whole.color[c]);
        }
        assert!((part.opacity - whole.opacity).abs() <= 2e-4);
        assert_eq!(&part.alphas[..], &whole.alphas[first..first + kept - 1]);
        for (a, b) in part.weights.iter().zip(&whole.weights[first..first + kept - 1]) {
            assert!((a - b).abs() <= 1e-4 * b.max(1e-6), "weights {a} vs {b}");
        }
    }

    /// The guard of the one-evaluation-per-depth refactor: the depths placed are bit for bit
    /// those of evaluating every depth again each round (the earlier implementation), on a
    /// Neuralangelo backbone whose SDF is a perturbed sphere.
    #[test]
    fn upsampling_places_the_depths_of_evaluating_every_depth_each_round() {
        let (backbone, mut params) = crate::build(crate::Preset::NeuralangeloCpu, 0.5, 4);
        let mut rng = 0x2545_F491_4F6C_DD1Du64;
        for p in params.iter_mut() {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            *p += 1e-3 * ((rng >> 40) as f32 / (1u64 << 24) as f32 - 0.5);
        }
        let rays: Vec<RayInput<f32>> = (0..40)
            .map(|i| {
                let a = i as f32 * 0.37;
                let origin = [2.5 * a.cos(), 2.5 * a.sin(), 0.3];
                let n = (origin[0] * origin[0] + origin[1] * origin[1] + origin[2] * origin[2]).sqrt();
                let direction = [-origin[0] / n + 0.05 * (i % 5) as f32, -origin[1] / n, -origin[2] / n];
                let m = (direction[0] * direction[0] + direction[1] * direction[1] + direction[2] * direction[2]).sqrt();
                RayInput {
                    origin,
                    direction: direction.map(|d| d / m),
                    depths: (0..=32).map(|k| 1.5 + k as f32 * 2.0 / 32.0).collect(),
                    target: [0.0; 3],
                    mask: None,
                    weight: 1.0,
                }
            })
            .collect();
        let (n_fine, rounds, base_s) = (32, 2, 64.0);
        let mut new = rays.clone();
        backbone.upsample(&params, &mut new, n_fine, rounds, base_s);
        let mut kept = rays.clone();
        // The MLP packed once (a render's and training's path) against `forward_first` below.
        let sdf_rows = backbone.sdf_rows(&params);
        let values: Vec<Vec<f32>> =
            kept.chunks_mut(CHUNK).flat_map(|c| upsample_chunk(&sdf_rows, c, n_fine, rounds, base_s, Purpose::Render(None))).collect();
        // Training weighs by `weights_into`, a render by `render_weights_into`.
        let reference = |ray: &RayInput<f32>, weigh: fn(&[f32], f32, &mut Vec<f32>)| {
            let mut depths = ray.depths.clone();
            for round in 0..rounds {
                let k = n_fine / rounds;
                let s = (base_s * f64::from(1u32 << round)) as f32;
                let sdf = ray_sdf(&backbone.sdf, &params, ray, &depths);
                let mut weights = Vec::new();
                weigh(&sdf, s, &mut weights);
                depths = merge_sorted(&depths, &sample_intervals(&depths, &weights, k));
            }
            depths
        };
        for (ray, (a, (b, v))) in rays.iter().zip(new.iter().zip(kept.iter().zip(&values))) {
            assert_eq!(a.depths, reference(ray, weights_into));
            let depths = reference(ray, render_weights_into);
            assert_eq!(b.depths, depths);
            assert_eq!(*v, ray_sdf(&backbone.sdf, &params, ray, &depths));
        }
    }

    /// `count` parallel rays from 2.5 away along +y, the i-th aimed `spacing · i` above the
    /// centre of the presets' initial sphere (radius 0.5), each with `intervals` equal intervals
    /// over depths 1.5–3.5.
    fn rays_past_the_sphere(count: usize, spacing: f32, intervals: usize) -> Vec<RayInput<f32>> {
        (0..count)
            .map(|i| RayInput {
                origin: [0.0, -2.5, spacing * i as f32],
                direction: [0.0, 1.0, 0.0],
                depths: (0..=intervals).map(|k| 1.5 + k as f32 * 2.0 / intervals as f32).collect(),
                target: [0.0; 3],
                mask: None,
                weight: 1.0,
            })
            .collect()
    }

    fn trim(lipschitz: Option<f32>) -> Trim {
        Trim { s: 200.0, negligible: 1e-4, lipschitz, resolved: None }
    }

    #[test]
    fn a_ray_is_proven_faint_only_with_a_lipschitz_bound_finite_values_and_room_between_samples() {
        let depths: Vec<f32> = (0..=16).map(|i| 1.0 + 0.05 * i as f32).collect();
        let far = vec![0.3f32; 17];
        // m = 0.3 − 0.025 L against ln(2 · 48 / 10⁻⁴) / 200 = 0.069.
        assert!(proven_faint(&depths, &far, trim(Some(1.0)), 48));
        assert!(!proven_faint(&depths, &far, trim(None), 48), "no bound, no proof");
        assert!(!proven_faint(&depths, &far, trim(Some(f32::NAN)), 48), "a NaN bound proves nothing");
        assert!(!proven_faint(&depths, &far, Trim { s: -200.0, ..trim(Some(1.0)) }, 48), "nor a negative scale");
        assert!(!proven_faint(&depths, &far, trim(Some(10.0)), 48), "a steep field may dip between the samples");
        let mut nan = far.clone();
        nan[5] = f32::NAN;
        assert!(!proven_faint(&depths, &nan, trim(Some(1.0)), 48), "a NaN proves nothing");
        let mut steep = far.clone();
        steep[9] = 0.05;
        assert!(!proven_faint(&depths, &steep, trim(Some(1.0)), 48), "a slope steeper than the bound breaks the claim");
        let near: Vec<f32> = (0..17).map(|i| (0.05 + 0.05 * (i as f32 - 9.0).abs()).min(0.3)).collect();
        assert!(!proven_faint(&depths, &near, trim(Some(1.05)), 48), "a dip below the floor");
        assert!(proven_faint(&depths, &near.iter().map(|v| v + 0.05).collect::<Vec<_>>(), trim(Some(1.05)), 48), "the dip lifted");
        assert!(!proven_faint(&depths[..1], &far[..1], trim(Some(1.0)), 48), "one depth, no interval");
    }

    /// Soundness, as a property over random fields: wherever a proven ray's samples are put (any
    /// number up to the proof's), its weights sum to at most `negligible`. The fields are sums of
    /// sines along the ray with a known slope bound, offset so that many rays come near zero.
    #[test]
    fn a_proven_faint_ray_carries_at_most_the_negligible_weight_wherever_its_samples_lie() {
        let mut rng = 0x9E37_79B9_7F4A_7C15u64;
        let mut uniform = move || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            (rng >> 40) as f32 / (1u64 << 24) as f32
        };
        let (mut proven, intervals) = (0, 48);
        for _ in 0..400 {
            let waves: Vec<[f32; 3]> = (0..3).map(|_| [0.05 * uniform(), 5.0 + 60.0 * uniform(), 6.3 * uniform()]).collect();
            let offset = 0.02 + 0.2 * uniform();
            let field = |t: f32| offset + waves.iter().map(|[a, k, p]| a * (k * t + p).sin()).sum::<f32>();
            let lipschitz = waves.iter().map(|[a, k, _]| a * k).sum::<f32>() * 1.001;
            let coarse: Vec<f32> = (0..=16).map(|i| 1.0 + 0.03 * i as f32).collect();
            let values: Vec<f32> = coarse.iter().map(|&t| field(t)).collect();
            if !proven_faint(&coarse, &values, trim(Some(lipschitz)), intervals) {
                continue;
            }
            proven += 1;
            for placement in 0..20 {
                // The coarse depths and `intervals − 16` more, uniform or bunched where the
                // field is lowest.
                let mut depths = coarse.clone();
                let lowest = coarse.iter().copied().min_by(|a, b| field(*a).total_cmp(&field(*b))).unwrap_or(1.0);
                for _ in 0..intervals - 16 {
                    let t = if placement % 2 == 0 { 1.0 + 0.48 * uniform() } else { (lowest + 0.03 * (uniform() - 0.5)).clamp(1.0, 1.48) };
                    depths.push(t);
                }
                depths.sort_by(f32::total_cmp);
                let sdf: Vec<f32> = depths.iter().map(|&t| field(t)).collect();
                let mut weights = Vec::new();
                render_weights_into(&sdf, 200.0, &mut weights);
                let total: f32 = weights.iter().sum();
                assert!(total <= 1e-4, "proven faint, yet {total:e} of weight");
            }
        }
        assert!((20..380).contains(&proven), "{proven} of 400 rays proven: the fields do not test the proof");
    }

    /// A render up-sampled with the proof against one without (the presets' backbone, its
    /// geometric initialisation a sphere of radius 0.5): a ray with the same samples renders
    /// bit for bit the same, one proven by its coarse values keeps its last coarse interval, and
    /// every ray whose samples changed renders (colour, opacity) within the trim's bound of the
    /// full up-sampling.
    #[test]
    fn rays_proven_faint_render_as_the_full_upsampling_within_the_trim() {
        let (backbone, params) = crate::build(crate::Preset::NeuralangeloCpu, 0.5, 4);
        // Aimed at offsets from the sphere's centre of 0 to 0.94.
        let rays = rays_past_the_sphere(48, 0.02, 32);
        let (s, negligible, lipschitz) = (200.0, 1e-4, 1.5);
        let render = |trim: Trim| {
            let mut rays = rays.clone();
            let sdf = backbone.upsample_for_render(&params, &mut rays, 32, 2, 64.0, Some(trim));
            let outputs = backbone.render(&params, &rays, &sdf, negligible, std::num::NonZeroUsize::MIN);
            (rays, outputs)
        };
        let (full, full_out) = render(Trim { s, negligible, lipschitz: None, resolved: None });
        let (proof, proof_out) = render(Trim { s, negligible, lipschitz: Some(lipschitz), resolved: None });
        let mut proven = 0;
        for (r, ((a, b), (x, y))) in full.iter().zip(&proof).zip(full_out.iter().zip(&proof_out)).enumerate() {
            let coarse = &rays[r].depths;
            if proven_faint(
                coarse,
                &ray_sdf(&backbone.sdf, &params, &rays[r], coarse),
                Trim { s, negligible, lipschitz: Some(lipschitz), resolved: None },
                64,
            ) {
                proven += 1;
                assert_eq!(b.depths, coarse[31..], "ray {r}: a ray proven by its coarse values keeps its last coarse interval");
            }
            if a.depths == b.depths {
                assert_eq!((x.color, x.opacity), (y.color, y.opacity), "ray {r}: the same samples, the same render");
                continue;
            }
            assert!(x.opacity <= negligible && y.opacity <= negligible, "ray {r}: opacity {} and {}", x.opacity, y.opacity);
            for k in 0..3 {
                assert!((x.color[k] - y.color[k]).abs() <= 2.0 * negligible, "ray {r}, colour {k}: {} against {}", x.color[k], y.color[k]);
            }
        }
        // Rays that miss the sphere (radius 0.5) by more than ≈ 0.11 are proven.
        assert!((10..24).contains(&proven), "{proven} of 48 rays proven faint");
    }

    #[test]
    fn a_ray_is_resolved_only_when_no_interval_carries_more_than_the_bound() {
        // A plane at t = 1.3: sampled every 0.05 its weight sits in one interval, every 0.002 it
        // spreads over a dozen.
        let plane = |step: f32| (0..=(2.0 / step) as usize).map(|i| 1.3 - i as f32 * step).collect::<Vec<f32>>();
        assert!(!resolved(&plane(0.05), 200.0, 0.2), "one interval holds the surface's weight");
        assert!(resolved(&plane(0.002), 200.0, 0.2), "a dozen intervals share it");
        assert!(resolved(&[0.5, 0.4, 0.45, 0.6], 200.0, 0.02), "a ray that misses carries nothing");
        assert!(!resolved(&[0.5, f32::NAN, 0.45], 200.0, 0.02), "a NaN is not resolved");
    }

    /// A render's rays either take every round, or stop after the first where they were
    /// resolved: the presets' backbone (its initialisation a sphere of radius 0.5), rays from
    /// through its centre to past its rim, two rounds with the bound against none.
    #[test]
    fn a_resolved_ray_gets_no_depths_after_the_first_round() {
        let (backbone, params) = crate::build(crate::Preset::NeuralangeloCpu, 0.5, 4);
        let rays = rays_past_the_sphere(40, 0.015, 16);
        let (s, most) = (300.0, 0.2);
        let trim = |resolved| Trim { s, negligible: 0.0, lipschitz: None, resolved };
        let run = |n_fine, rounds, resolved| {
            let mut rays = rays.clone();
            let values = backbone.upsample_for_render(&params, &mut rays, n_fine, rounds, 64.0, Some(trim(resolved)));
            (rays, values)
        };
        let (all, _) = run(32, 2, None);
        let (stopped, _) = run(32, 2, Some(most));
        let (first, first_values) = run(16, 1, None);
        let mut counts = [0, 0];
        for r in 0..rays.len() {
            if resolved(&first_values[r], s, most) {
                assert_eq!(stopped[r].depths, first[r].depths, "ray {r}: resolved after the first round, it keeps that round's depths");
                counts[0] += 1;
            } else {
                assert_eq!(stopped[r].depths, all[r].depths, "ray {r}: not resolved, it takes every round");
                counts[1] += 1;
            }
        }
        assert!(counts[0] >= 5 && counts[1] >= 5, "{counts:?} rays resolved / not: the rays do not test the rule");
    }

    #[test]
    fn a_ray_that_misses_keeps_one_interval() {
        let mut depths: Vec<f32> = (0..=10).map(|i| i as f32).collect();
        let mut sdf: Vec<f32> = (0..=10).map(|i| 5.0 + i as f32).collect();
        assert_eq!(trim_to_weight(&mut depths, &mut sdf, 100.0, 1e-4), 9);
        assert_eq!(depths, vec![9.0, 10.0]);
        assert_eq!(sdf, vec![14.0, 15.0]);
    }
}
