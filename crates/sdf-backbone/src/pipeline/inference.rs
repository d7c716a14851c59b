//! A render without a loss: the forward pass of rays whose SDF values at their depths are
//! already known (the up-sampling evaluated every one of them), in four batched stages.
//!
//! 1. The weights of every interval from those values at the model's scale s (no network).
//! 2. The *kept* intervals, those whose weight exceeds `negligible / n` (n intervals on the
//!    ray): only their colour is needed, so the SDF network runs at their first sample alone
//!    (features and normals: analytic ones by one reverse pass from the SDF value, no tangents;
//!    or by probes) and the colour network on those rows. The
//!    dropped intervals' weights sum to at most `negligible` per ray. With a colour stride
//!    k > 1, the networks run on every k-th interval of each run of consecutive kept intervals
//!    (and its last), and the intervals between take the colour and normal on the line in depth
//!    between the two evaluated on either side ([`colour_sources`]): a soft model keeps a
//!    dozen or more intervals per ray, along which the colour changes little.
//! 3. The learned background only for the rays that let more than `negligible` through, and
//!    along each only as far as what lies behind can carry more than `negligible`.
//! 4. Each ray composited: `colour = Σ_kept wᵢ cᵢ + (1 − O) C_bg` (the background term dropped
//!    where 1 − O ≤ `negligible`), opacity O and depth from every interval, normal from the kept.
//!
//! So with stride 1 the colour differs from the loss pass's by at most about `2 · negligible` per
//! channel, and with `negligible = 0` it is the loss pass's up to rounding (test); a stride
//! adds the interpolation's error, bounded by no formula (measured against stride 1 on renders:
//! BENCHMARKS.md, "A render's colour stride (§51)"); opacity and depth never change: no context for a backward
//! pass, no loss terms, no allocation per ray, and most rows of the loss pass never evaluated
//! (a ray's last sample, the samples that carry no weight, the background of opaque rays).

use super::accumulate::{COLOR_IN_FIXED, Tangents, color_row, probe_normal, sdf_forward};
use super::{Pipeline, RayInput, RayOutput, TangentPrecision, scale_from_variance};
use crate::encoding::SphericalHarmonics;
use crate::module::Module;
use crate::real::Real;
use crate::render::render_weights_into;
use crate::scratch::Buf;
use std::num::NonZeroUsize;

/// A kept interval: its ray, its index on the ray, its weight.
#[derive(Debug, Clone, Copy)]
struct Kept<R> {
    ray: usize,
    interval: usize,
    weight: R,
}

impl<S, C> Pipeline<S, C> {
    /// Renders `rays` forward only, given `sdf[r]`, the SDF at every depth of ray r (as
    /// [`Self::upsample_for_render`] returns them), dropping per ray intervals and background that
    /// carry at most `negligible` of its colour (see the module docs; 0 drops only what carries
    /// nothing), the colour networks run on every `colour_stride`-th kept interval of a run (1:
    /// every one). Sequential: callers run chunks of rays in parallel.
    pub fn render_known<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        sdf: &[Vec<R>],
        negligible: R,
        colour_stride: NonZeroUsize,
    ) -> Vec<RayOutput<R>>
    where
        S: Module<R>,
        C: Module<R>,
    {
        let _span = crate::profile::span(crate::profile::Stage::RenderPass);
        assert_eq!(rays.len(), sdf.len(), "render_known: one list of SDF values per ray");
        let (n_sdf, n_col) = (self.sdf.n_params(), self.color.n_params());
        let (p_sdf, rest) = params.split_at(n_sdf);
        let (p_col, p_var) = rest.split_at(n_col);
        let s = scale_from_variance(p_var[0]);
        let mut outputs = Vec::with_capacity(rays.len());
        let mut kept = Vec::new();
        let mut weights = Vec::new();
        for (r, (ray, values)) in rays.iter().zip(sdf).enumerate() {
            assert_eq!(ray.depths.len(), values.len(), "render_known: ray {r} has {} depths and {} SDF values", ray.depths.len(), values.len());
            render_weights_into(values, s, &mut weights);
            let cut = negligible / R::of(weights.len().max(1) as f64);
            let (mut opacity, mut depth) = (R::ZERO, R::ZERO);
            for (i, &w) in weights.iter().enumerate() {
                opacity += w;
                depth += w * (ray.depths[i] + ray.depths[i + 1]) * R::of(0.5);
                if w > cut {
                    kept.push(Kept { ray: r, interval: i, weight: w });
                }
            }
            outputs.push(RayOutput { color: [R::ZERO; 3], opacity, depth, normal: [R::ZERO; 3] });
        }
        // SH₄ of each ray's direction, for the colour network and the background.
        let sh: Vec<[R; 16]> = rays
            .iter()
            .map(|ray| {
                let mut sh = [R::ZERO; 16];
                SphericalHarmonics.forward(&[], &ray.direction, &mut sh, &mut []);
                sh
            })
            .collect();
        let (evaluated, sources) = colour_sources(&kept, rays, colour_stride);
        let (colors, normals) = self.kept_colors(p_sdf, p_col, rays, &sh, &evaluated);
        for (k, source) in kept.iter().zip(&sources) {
            let (c, n) = source.colour_and_normal(&colors, &normals);
            let out = &mut outputs[k.ray];
            for j in 0..3 {
                out.color[j] += k.weight * c[j];
                out.normal[j] += k.weight * n[j];
            }
        }
        self.composite_background(&p_var[1..], rays, &sh, &mut outputs, negligible);
        outputs
    }

    /// The colour (rows × 3) and normal of every kept interval: the SDF network at its first
    /// sample (and the probes, for normals by differences), then the colour network.
    fn kept_colors<R: Real + TangentPrecision>(
        &self,
        p_sdf: &[R],
        p_col: &[R],
        rays: &[RayInput<R>],
        sh: &[[R; 16]],
        kept: &[Kept<R>],
    ) -> (Buf<R>, Vec<[R; 3]>)
    where
        S: Module<R>,
        C: Module<R>,
    {
        let rows = kept.len();
        let probes = if self.analytic.is_some() { &[] } else { self.config.normals.probes() };
        let (np, h) = (probes.len(), R::of(self.config.normal_step));
        let mut points = Buf::<R>::to_overwrite(3 * rows * (1 + np));
        for (j, k) in kept.iter().enumerate() {
            let ray = &rays[k.ray];
            let t = ray.depths[k.interval];
            let x = [0, 1, 2].map(|a| ray.origin[a] + t * ray.direction[a]);
            points[3 * j..3 * j + 3].copy_from_slice(&x);
            for (p, (offset, _)) in probes.iter().enumerate() {
                let at = 3 * (rows + np * j + p);
                for a in 0..3 {
                    points[at + a] = x[a] + R::of(offset[a]) * h;
                }
            }
        }
        let n_out = self.sdf.n_outputs();
        let mut sdf_out = Buf::<R>::to_overwrite(rows * (1 + np) * n_out);
        // No probes with analytic normals.
        let fns = self.analytic.as_ref().map(|a| (R::tangent_fns(a), Tangents::Found));
        let (_, gradients) = sdf_forward(fns, &self.sdf, p_sdf, &points, &mut sdf_out);
        let normals: Vec<[R; 3]> = match gradients {
            Some(grad) => grad.chunks_exact(3).map(|g| [g[0], g[1], g[2]]).collect(),
            None => (0..rows).map(|j| probe_normal(probes, h, |p| sdf_out[(rows + np * j + p) * n_out])).collect(),
        };
        let c_in = COLOR_IN_FIXED + n_out - 1;
        let mut color_in = Buf::<R>::to_overwrite(rows * c_in);
        for (j, k) in kept.iter().enumerate() {
            let row = &mut color_in[j * c_in..(j + 1) * c_in];
            color_row(row, &points[3 * j..3 * j + 3], &normals[j], &sh[k.ray], &sdf_out[j * n_out + 1..(j + 1) * n_out]);
        }
        let mut colors = Buf::<R>::to_overwrite(rows * 3);
        self.color.infer(p_col, &color_in, &mut colors);
        (colors, normals)
    }

    /// Adds `(1 − O) C_bg` to every output: the learned background for the rays that let more
    /// than `negligible` through (the others keep their colour), each evaluated no further along
    /// than it carries more than `negligible` of the colour ([`crate::BackgroundModel::render`]),
    /// or the fixed background colour.
    fn composite_background<R: Real>(&self, p_bg: &[R], rays: &[RayInput<R>], sh: &[[R; 16]], outputs: &mut [RayOutput<R>], negligible: R) {
        let Some(model) = &self.background else {
            let background = self.config.background.map(R::of);
            for out in outputs.iter_mut() {
                let left = R::ONE - out.opacity;
                for k in 0..3 {
                    out.color[k] += left * background[k];
                }
            }
            return;
        };
        let through: Vec<usize> = (0..rays.len()).filter(|&r| R::ONE - outputs[r].opacity > negligible).collect();
        if through.is_empty() {
            return;
        }
        let origins: Vec<[R; 3]> = through.iter().map(|&r| rays[r].origin).collect();
        let directions: Vec<[R; 3]> = through.iter().map(|&r| rays[r].direction).collect();
        let sh: Vec<[R; 16]> = through.iter().map(|&r| sh[r]).collect();
        // What a ray's background may drop: `(1 − O) T ≤ negligible` past its evaluated samples.
        let budgets: Vec<R> = through.iter().map(|&r| negligible / (R::ONE - outputs[r].opacity)).collect();
        let (colors, _) = model.render(p_bg, &origins, &directions, &sh, &budgets);
        for (&r, c) in through.iter().zip(&colors) {
            let out = &mut outputs[r];
            let left = R::ONE - out.opacity;
            for k in 0..3 {
                out.color[k] += left * c[k];
            }
        }
    }
}

/// Where a kept interval's colour and normal come from: its own row of the networks, or the
/// line in depth between evaluated rows `lo` and `lo + 1` of its run, a fraction `f` of the way.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Source<R> {
    Own(usize),
    Between { lo: usize, f: R },
}

impl<R: Real> Source<R> {
    /// The colour and normal from the evaluated rows' `colors` (rows × 3) and `normals`.
    fn colour_and_normal(&self, colors: &[R], normals: &[[R; 3]]) -> ([R; 3], [R; 3]) {
        match *self {
            Source::Own(e) => ([0, 1, 2].map(|j| colors[3 * e + j]), normals[e]),
            Source::Between { lo, f } => {
                let lerp = |a: R, b: R| a + f * (b - a);
                let colour = [0, 1, 2].map(|j| lerp(colors[3 * lo + j], colors[3 * (lo + 1) + j]));
                (colour, [0, 1, 2].map(|j| lerp(normals[lo][j], normals[lo + 1][j])))
            }
        }
    }
}

/// The kept intervals (in ray order, as [`Pipeline::render_known`] lists them) whose colour the
/// networks evaluate, and where each kept interval's colour comes from: in each run of
/// consecutive intervals of a ray, every `stride`-th from its first, and its last; each other
/// one a fraction of the way between the evaluated ones on either side, by its first sample's
/// depth (where its colour is evaluated with stride 1). A run never reaches across a dropped
/// interval, so no colour is drawn across empty space between two surfaces.
fn colour_sources<R: Real>(kept: &[Kept<R>], rays: &[RayInput<R>], stride: NonZeroUsize) -> (Vec<Kept<R>>, Vec<Source<R>>) {
    let stride = stride.get();
    let mut evaluated = Vec::with_capacity(kept.len() / stride + 1);
    let mut sources = Vec::with_capacity(kept.len());
    let mut start = 0;
    while start < kept.len() {
        let first = kept[start];
        let len = kept[start..].iter().enumerate().take_while(|(j, k)| k.ray == first.ray && k.interval == first.interval + j).count();
        let depth = |q: usize| rays[first.ray].depths[first.interval + q];
        for p in 0..len {
            if p % stride == 0 || p + 1 == len {
                sources.push(Source::Own(evaluated.len()));
                evaluated.push(kept[start + p]);
            } else {
                // Between the last evaluated (lo, pushed) and the next (hi, pushed after this).
                let lo = p - p % stride;
                let hi = (lo + stride).min(len - 1);
                // Depths may repeat (a sample placed on another): a span of none takes lo's colour.
                let span = depth(hi) - depth(lo);
                let f = if span > R::ZERO { (depth(p) - depth(lo)) / span } else { R::ZERO };
                sources.push(Source::Between { lo: evaluated.len() - 1, f });
            }
        }
        start += len;
    }
    (evaluated, sources)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs split where a ray changes or an interval is dropped; every `stride`-th of a run and
    /// its last evaluated; the others a fraction of the way in depth between their neighbours.
    #[test]
    fn colour_sources_evaluate_every_strideth_interval_of_a_run_and_its_last() {
        let ray = |depths: Vec<f64>| RayInput { origin: [0.0; 3], direction: [0.0, 0.0, 1.0], depths, target: [0.0; 3], mask: None, weight: 1.0 };
        let rays = [ray((0..12).map(|i| f64::from(i * i)).collect()), ray((0..6).map(f64::from).collect()), ray(vec![1.0, 1.0, 1.0, 1.0, 2.0])];
        // Ray 0: intervals 1..=7 (a run of 7), then 9, 10 (interval 8 dropped); ray 1: 0..=2;
        // ray 2: 0..=2 with repeated depths.
        let kept: Vec<Kept<f64>> =
            [(0, 1), (0, 2), (0, 3), (0, 4), (0, 5), (0, 6), (0, 7), (0, 9), (0, 10), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2)]
                .map(|(ray, interval)| Kept { ray, interval, weight: 0.1 })
                .to_vec();
        let (evaluated, sources) = colour_sources(&kept, &rays, NonZeroUsize::new(3).unwrap());
        let at: Vec<(usize, usize)> = evaluated.iter().map(|k| (k.ray, k.interval)).collect();
        assert_eq!(at, [(0, 1), (0, 4), (0, 7), (0, 9), (0, 10), (1, 0), (1, 2), (2, 0), (2, 2)]);
        use Source::{Between, Own};
        // Ray 0's depths are i²: interval 2 lies (4 − 1)/(16 − 1) of the way from 1 to 4.
        let want = [
            Own(0),
            Between { lo: 0, f: 3.0 / 15.0 },
            Between { lo: 0, f: 8.0 / 15.0 },
            Own(1),
            Between { lo: 1, f: 9.0 / 33.0 },
            Between { lo: 1, f: 20.0 / 33.0 },
            Own(2),
            Own(3),
            Own(4),
            Own(5),
            Between { lo: 5, f: 0.5 },
            Own(6),
            // Between two samples at one depth: lo's colour, not 0/0.
            Own(7),
            Between { lo: 7, f: 0.0 },
            Own(8),
        ];
        assert_eq!(sources, want);
        // A colour and normal linear in depth come back exact at every kept interval, from the
        // evaluated rows alone (a reversed or held fraction would not).
        let linear = |k: &Kept<f64>| {
            let t = rays[k.ray].depths[k.interval];
            ([0.5 + 0.1 * t, 2.0 - 0.03 * t, 0.25 * t + k.ray as f64], [t, -t, 1.0 + k.ray as f64])
        };
        let colors: Vec<f64> = evaluated.iter().flat_map(|k| linear(k).0).collect();
        let normals: Vec<[f64; 3]> = evaluated.iter().map(|k| linear(k).1).collect();
        for (k, source) in kept.iter().zip(&sources) {
            let ((c, n), (want_c, want_n)) = (source.colour_and_normal(&colors, &normals), linear(k));
            for j in 0..3 {
                assert!((c[j] - want_c[j]).abs() < 1e-12 && (n[j] - want_n[j]).abs() < 1e-12, "{k:?}: {c:?} {n:?}");
            }
        }
        // Stride 1: every kept interval its own.
        let (evaluated, sources) = colour_sources(&kept, &rays, NonZeroUsize::MIN);
        assert_eq!(evaluated.len(), kept.len());
        assert!(sources.iter().enumerate().all(|(j, s)| *s == Own(j)));
    }
}
