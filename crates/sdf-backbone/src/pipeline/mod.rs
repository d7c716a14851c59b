//! The NeuS render + loss pipeline for a batch of rays, with its hand-written backward.
//!
//! Per ray with sample depths t₀ … tₙ: the SDF network is evaluated at the n + 1 points
//! `xᵢ = o + tᵢ d` (SDF and geometry features) and at the probes that give the normals by
//! numerical differences ([`NormalScheme`]): central, 6n points `xᵢ ± h·e_k`,
//! `nᵢ = (S(xᵢ + h e_k) − S(xᵢ − h e_k)) / 2h`; or tetrahedral, 4n points `xᵢ + h·vⱼ` with
//! v ∈ {(1,−1,−1), (−1,−1,1), (−1,1,−1), (1,1,1)}, `nᵢ = Σⱼ vⱼ S(xᵢ + h vⱼ) / 4h` (a third fewer
//! network evaluations). Central differences are second-order accurate (error O(h²)); the
//! tetrahedral stencil is only first-order: since v_x v_y v_z = 1 at all four vertices, its
//! error is h·(∂²S/∂y∂z, ∂²S/∂x∂z, ∂²S/∂x∂y) + O(h²), which vanishes where the mixed second
//! derivatives do (a plane, and at h → 0). Or analytic ([`NormalScheme::Analytic`]):
//! `nᵢ = ∇ₓS(xᵢ)` exactly, by one reverse pass from the SDF output through the MLP (`dA = dZ W`)
//! and the hash grid (the trilinear weights' gradients on the same 8 corners), with no probe
//! rows; the backward pass needs one tangent only — along `vᵢ = ∂L/∂nᵢ`, since `vᵢ · δnᵢ =
//! δ(∂S/∂x · vᵢ)` — by forward-mode derivatives along it (`Ż = Ȧ Wᵀ`, `Ȧ' = act'(Z) ⊙ Ż`), and
//! runs the reverse of the values and that tangent together (act'' from act', the tables'
//! gradient `w_c ȳ + (∇w_c · v) ẏ̄`). The
//! colour network maps `[xᵢ, nᵢ, SH₄(d), featuresᵢ]` to the colour of interval i; the ray is
//! rendered with [`render_ray`](crate::render::render_ray) at scale `s = exp(10·v)` (NeuS's learnt variance v). The loss is
//! the colour error (L1 as NeuS, or L2) of `colour + (1 − opacity)·background`, plus
//! `λ_eik · mean (|nᵢ| − 1)²`, plus `λ_smooth · mean |nᵢ₊₁ − nᵢ|²` (the normal smoothness),
//! plus, with a mask, `λ_mask · BCE(opacity, mask)`, plus any
//! per-ray loss on the samples supplied by the caller ([`SampleLoss`]: the surface losses).
//!
//! Gradients of a batch are deterministic: rays are cut into fixed chunks, each chunk's gradient
//! is computed on its own and the chunks are summed in order, so the result does not depend on
//! the thread count.
//!
//! The backward pass chains [`render_ray_backward`](crate::render::render_ray_backward) → colour network → normals (each ∂L/∂nᵢ
//! becomes ±1/2h on the six neighbour evaluations) → SDF network at all 7n + 1 points.
//! Everything is generic over [`Real`] so that the whole pipeline is gradient-checked in f64.

use crate::background::BackgroundModel;
use crate::module::{DeferringModule, DeferringTangentModule, Module};
use crate::real::Real;
use crate::scratch::Buf;

mod accumulate;
mod analytic;
mod deferred;
mod inference;
mod normals;
pub use analytic::{AnalyticNormals, TangentFns, TangentPrecision};
pub use deferred::DeferredGradient;
pub use normals::{Differences, NormalScheme};

/// Colour loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorLoss {
    /// |c − ĉ| summed over channels (NeuS).
    L1,
    /// (c − ĉ)² summed over channels.
    L2,
}

/// A per-ray loss on the samples, added to the pipeline's loss (the surface losses of
/// `surface-losses` plug in here). Works in f64 whatever the pipeline's precision.
pub trait SampleLoss: Sync {
    /// Loss of ray `ray` (its index in the batch) from the pipeline's logistic scale `s` (the one
    /// it renders with, [`scale_from_variance`]), its sample depths `t` (n + 1), SDF values `sdf`
    /// (n + 1) and rendering weights `weights` (n); adds ∂loss/∂S into `d_sdf` and ∂loss/∂w into
    /// `d_weights` (no gradient flows into s). The pipeline divides the loss by the batch's ray
    /// count.
    #[allow(clippy::too_many_arguments)]
    fn ray_loss(&self, ray: usize, s: f64, t: &[f64], sdf: &[f64], weights: &[f64], d_sdf: &mut [f64], d_weights: &mut [f64]) -> f64;
}

/// NeuS's learnt variance v → the logistic scale s = exp(10 v), the one place this formula lives.
#[inline]
pub fn scale_from_variance<R: Real>(v: R) -> R {
    (R::of(10.0) * v).exp()
}

/// The variance v whose scale is `s` (the inverse of [`scale_from_variance`]).
#[inline]
pub fn variance_from_scale<R: Real>(s: R) -> R {
    s.ln() / R::of(10.0)
}

/// ∂s/∂v of [`scale_from_variance`], given s.
#[inline]
fn scale_derivative<R: Real>(s: R) -> R {
    R::of(10.0) * s
}

/// No extra loss.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoSampleLoss;

impl SampleLoss for NoSampleLoss {
    fn ray_loss(&self, _: usize, _: f64, _: &[f64], _: &[f64], _: &[f64], _: &mut [f64], _: &mut [f64]) -> f64 {
        0.0
    }
}

/// One ray of a batch.
#[derive(Debug, Clone, PartialEq)]
pub struct RayInput<R> {
    /// Origin (world, normalised frame).
    pub origin: [R; 3],
    /// Unit direction.
    pub direction: [R; 3],
    /// Sample depths t₀ < … < tₙ along the ray (n + 1 values, n ≥ 1).
    pub depths: Vec<R>,
    /// Target colour.
    pub target: [R; 3],
    /// Foreground mask (1 = object), if masks are used.
    pub mask: Option<R>,
    /// Weight of the ray's pixel terms (colour, mask BCE, opacity entropy): 1 for plain
    /// training; a loss-guided sampler's importance correction otherwise (soft mining).
    /// The per-sample regularisers (eikonal, curvature, the caller's) are not weighted.
    pub weight: R,
}

/// A chunk's loss, gradient (all but the deferred parameters and the background's tables),
/// outputs and deferred records.
type Part<R> = (R, Buf<R>, Vec<RayOutput<R>>, accumulate::Records<R>);

/// Loss weights and numerics of the pipeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipelineConfig {
    /// Colour loss.
    pub color_loss: ColorLoss,
    /// Eikonal weight (NeuS: 0.1).
    pub eikonal_weight: f64,
    /// Mask BCE weight (NeuS with masks: 0.1).
    pub mask_weight: f64,
    /// Step of the numerical differences for normals (Neuralangelo ties it to the finest level).
    pub normal_step: f64,
    /// Central or tetrahedral differences, unless the pipeline has analytic normals
    /// ([`Pipeline::analytic`]).
    pub normals: Differences,
    /// Weight of Neuralangelo's curvature loss, mean |ΔS| at the samples, with the Laplacian
    /// from the same probes as the normals: `ΔS ≈ (Σⱼ S(x + h vⱼ) − m S(x)) / (h² c/2)`, where
    /// Σⱼ vⱼvⱼᵀ = c I (c = 2 central, 4 tetrahedral; m probes). Neuralangelo: 5e-4.
    pub curvature_weight: f64,
    /// Colour behind the surface (what an empty ray renders). With masks (`masked_color`) it
    /// only colours renders; without, a fixed background colour is composited in the loss too.
    pub background: [f64; 3],
    /// Masked training as NeuS does it: the colour loss covers foreground rays only (mask ≥ ½),
    /// normalised by their count, on the rendered colour without any background; the mask BCE
    /// alone drives the opacity of backdrop rays. Rays without a mask are foreground.
    pub masked_color: bool,
    /// Weight of the opacity entropy `H(o) = −o ln o − (1 − o) ln(1 − o)` of rays without a
    /// mask (o clamped to [10⁻³, 1 − 10⁻³]): each ray is pushed to hit the surface or miss it,
    /// so that without masks a thin part is a surface rather than a haze (0: off).
    pub opacity_entropy: f64,
    /// Weight of the opacity itself (an L1 on the foreground's opacity) of rays without a mask:
    /// where the learned background explains a pixel as well as the foreground, the pixel goes
    /// to the background; the object, which only the foreground explains from every view,
    /// stays (0: off).
    pub opacity_sparsity: f64,
    /// The guard on the foreground (None: off); see [`OpacityGuard`].
    pub opacity_guard: Option<OpacityGuard>,
    /// Weight of the normal smoothness `mean |nᵢ₊₁ − nᵢ|²` over neighbouring samples of a ray
    /// (0: off). Rays cross the surface from many directions, so over a batch it penalises
    /// `|H d|²`, the Hessian of S along the rays: zero on a plane, large on bumps. It needs only
    /// the normals the pipeline has, so it works with analytic normals, where the curvature
    /// term's Laplacian (from probes) is not available.
    pub normal_smoothness: f64,
    /// Which neighbouring samples the normal smoothness compares.
    pub normal_smoothness_region: SmoothnessRegion,
}

/// Which neighbouring samples of a ray the normal smoothness ([`PipelineConfig::normal_smoothness`])
/// compares; the mean is over all of the ray's pairs either way.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SmoothnessRegion {
    /// Every pair of neighbouring samples.
    Everywhere,
    /// Pairs with at least one sample outside the solid or less than `depth` inside it
    /// (S > −depth): free space and a band at the surface, not the solid's depth. Along a ray
    /// through a solid the normals turn from the near side's to the far side's (through a
    /// sphere's centre by 180°); smoothed there, they push the far side, which the views may
    /// never see, outwards.
    Outside {
        /// How deep inside the solid pairs still count (0: only pairs with a sample outside).
        depth: f64,
    },
}

/// The guard on the foreground: an L1 on the foreground's opacity of the rays without a mask
/// whose learned background alone paints the pixel — at least as close to the target as the
/// composite, and within `tolerance` (RMS per channel) of it where one is given (a constant of
/// the step, no gradient through the comparison). Foreground mass in front of what the
/// background paints — a floater where a near wall is painted inside the bound — is taken back;
/// a solid object, whose colour the background behind it does not learn (it sees the object only
/// through the foreground's transmittance), is not; a thin part's few pixels can be (the
/// trainer's docs/DECISIONS.md §36). Needs a learned background.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OpacityGuard {
    /// Weight of the L1 on a guarded ray's opacity.
    pub weight: f64,
    /// How close (RMS colour error per channel) the background alone must come to the target
    /// (None: no bound beyond the composite's error).
    pub tolerance: Option<f64>,
}

/// SDF network + colour network + learnt variance (+ an optional learned background),
/// parameters `[sdf | colour | v | background]`.
#[derive(Debug, Clone)]
pub struct Pipeline<S, C> {
    /// SDF network: 3 inputs → 1 + F outputs (SDF, features).
    pub sdf: S,
    /// Colour network: 3 + 3 + 16 + F inputs → 3 outputs (sigmoid).
    pub color: C,
    /// Learned background for unmasked captures (NeRF++'s inverted sphere outside the bound,
    /// [`BackgroundModel`]), composited behind the surface instead of `config.background`.
    pub background: Option<BackgroundModel>,
    /// Configuration.
    pub config: PipelineConfig,
    /// Analytic normals (the exact ∇ₓS, no probes) instead of `config.normals`' differences:
    /// only for an SDF network with tangents ([`AnalyticNormals::new`],
    /// [`Pipeline::with_analytic_normals`]).
    pub analytic: Option<AnalyticNormals<S>>,
}

/// Per-ray results of the forward pass.
#[derive(Debug, Clone, PartialEq)]
pub struct RayOutput<R> {
    /// Rendered colour.
    pub color: [R; 3],
    /// Opacity Σ w.
    pub opacity: R,
    /// Depth Σ w t (distance along the ray).
    pub depth: R,
    /// Normal Σ w n (not normalised).
    pub normal: [R; 3],
}

impl<S, C> Pipeline<S, C> {
    /// How this pipeline takes its normals.
    pub fn normal_scheme(&self) -> NormalScheme {
        if self.analytic.is_some() { NormalScheme::Analytic } else { self.config.normals.into() }
    }

    /// This pipeline with analytic normals: only for an SDF network with tangents.
    pub fn with_analytic_normals(mut self) -> Self
    where
        S: DeferringTangentModule<f32> + DeferringTangentModule<f64>,
    {
        self.analytic = Some(AnalyticNormals::new());
        self
    }

    /// Takes normals by `scheme` (a user's choice; analytic needs a network with tangents).
    pub fn set_normals(&mut self, scheme: NormalScheme)
    where
        S: DeferringTangentModule<f32> + DeferringTangentModule<f64>,
    {
        match scheme.differences() {
            Some(differences) => {
                self.config.normals = differences;
                self.analytic = None;
            }
            None => self.analytic = Some(AnalyticNormals::new()),
        }
    }

    /// The deferred gradient of these per-work-item records: applied by the tangent passes when
    /// they came from analytic normals.
    fn deferred_gradient<R: Real + TangentPrecision>(&self, records: Vec<(Buf<R>, Buf<R>)>) -> DeferredGradient<S, R> {
        DeferredGradient { records, tangent: self.analytic.as_ref().map(|a| R::tangent_fns(a).apply_block) }
    }

    /// Total parameters: SDF, colour, and the variance v.
    pub fn n_params<R: Real>(&self) -> usize
    where
        S: Module<R>,
        C: Module<R>,
    {
        self.sdf.n_params() + self.color.n_params() + 1 + self.background.as_ref().map_or(0, BackgroundModel::n_params)
    }

    /// Loss of a batch (averaged over rays) and, if `d_params` is given, its gradient added into
    /// it. Returns the loss and the per-ray outputs. Sequential; see [`Self::loss_parallel`].
    pub fn loss<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_params: Option<&mut [R]>,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>)
    where
        S: DeferringModule<R>,
        C: Module<R>,
    {
        let norm = self.color_normaliser::<R>(rays);
        let m = R::of(rays.len() as f64);
        match d_params {
            None => {
                let (loss, outputs, _) = self.accumulate(params, rays, 0, None, m, norm, extra);
                (loss, outputs)
            }
            Some(d_params) => {
                let n_def = self.sdf.deferred_params();
                let (d_deferred, d_rest) = d_params.split_at_mut(n_def);
                let (loss, outputs, records) = self.accumulate(params, rays, 0, Some(d_rest), m, norm, extra);
                self.deferred_gradient(records.sdf.into_iter().collect()).apply(&self.sdf, d_deferred);
                (loss, outputs)
            }
        }
    }

    /// The colour loss's normaliser: the number of rays, or of foreground rays when the colour
    /// loss is masked (at least 1).
    fn color_normaliser<R: Real>(&self, rays: &[RayInput<R>]) -> R {
        if self.config.masked_color {
            R::of(rays.iter().filter(|r| r.mask.is_none_or(|m| m.to_f64() >= 0.5)).count().max(1) as f64)
        } else {
            R::of(rays.len() as f64)
        }
    }

    /// [`Self::loss`] over chunks of `chunk` rays in parallel: one gradient buffer per chunk,
    /// summed in chunk order, so the result is the same for any thread count (and equals `loss`
    /// up to the order of additions).
    pub fn loss_parallel<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_params: &mut [R],
        chunk: usize,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>)
    where
        S: DeferringModule<R> + Sync,
        C: Module<R> + Sync,
    {
        let n_def = self.sdf.deferred_params();
        let (d_deferred, d_rest) = d_params.split_at_mut(n_def);
        let (loss, outputs, deferred) = self.loss_parallel_split(params, rays, d_rest, chunk, extra);
        if n_def > 0 {
            deferred.apply(&self.sdf, d_deferred);
        }
        (loss, outputs)
    }

    /// [`Self::loss_parallel`] with the SDF network's deferred parameters (a hash grid's tables,
    /// [`DeferringModule::deferred_params`], the first ones) left out: `d_rest` is the gradient of the
    /// parameters after them, and their own gradient comes back as records to apply (whole, or one
    /// block at a time with [`DeferredGradient::apply_block`]).
    pub fn loss_parallel_split<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_rest: &mut [R],
        chunk: usize,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>, DeferredGradient<S, R>)
    where
        S: DeferringModule<R> + Sync,
        C: Module<R> + Sync,
    {
        use rayon::prelude::*;
        // The learned background's tables (the last parameters) are left out of the chunks'
        // buffers, which would otherwise be mostly zeros to clear and sum: their gradient is
        // added from the chunks' records, to the same bits.
        let n_tables = self.background.as_ref().map_or(0, |b| b.tables().len());
        let (d_rest, d_tables) = d_rest.split_at_mut(d_rest.len() - n_tables);
        let n_rest = d_rest.len();
        let m = R::of(rays.len() as f64);
        let norm = self.color_normaliser::<R>(rays);
        let chunk = chunk.max(1);
        let parts: Vec<Part<R>> = rays
            .par_chunks(chunk)
            .enumerate()
            .map(|(i, c)| {
                let mut g = Buf::<R>::zeroed(n_rest);
                let (l, o, records) = self.accumulate(params, c, i * chunk, Some(&mut g), m, norm, extra);
                (l, g, o, records)
            })
            .collect();
        let mut loss = R::ZERO;
        let mut outputs = Vec::with_capacity(rays.len());
        let mut grads = Vec::with_capacity(parts.len());
        let (mut records, mut background) = (Vec::with_capacity(parts.len()), Vec::new());
        for (l, g, o, r) in parts {
            loss += l;
            grads.push(g);
            outputs.extend(o);
            records.extend(r.sdf);
            background.extend(r.background);
        }
        // Σ over chunks in chunk order, in parallel over the parameters.
        d_rest.par_chunks_mut(1 << 14).enumerate().for_each(|(block, d)| {
            let (start, len) = (block << 14, d.len());
            for g in &grads {
                for (d, g) in d.iter_mut().zip(&g[start..start + len]) {
                    *d += *g;
                }
            }
        });
        if let Some(model) = &self.background {
            model.add_deferred(&background, d_tables);
        }
        (loss, outputs, self.deferred_gradient(records))
    }

    /// [`Self::loss_parallel_split`]'s loss and `d_rest` as one buffer of all of `d_rest`'s
    /// parameters per chunk (the learned background's tables included), summed in chunk order:
    /// the reference whose bits its records of the background's tables are tested against.
    #[cfg(test)]
    pub(crate) fn loss_split_dense_reference<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_rest: &mut [R],
        chunk: usize,
    ) -> R
    where
        S: DeferringModule<R>,
        C: Module<R>,
    {
        let (m, norm) = (R::of(rays.len() as f64), self.color_normaliser::<R>(rays));
        let mut loss = R::ZERO;
        for (i, c) in rays.chunks(chunk).enumerate() {
            let mut g = Buf::<R>::zeroed(d_rest.len());
            loss += self.accumulate(params, c, i * chunk, Some(&mut g), m, norm, &NoSampleLoss).0;
            d_rest.iter_mut().zip(g.iter()).for_each(|(d, g)| *d += *g);
        }
        loss
    }

    /// SDF values (first output of the SDF network) at `points` (xyz rows), in parallel chunks.
    pub fn sdf_values<R: Real>(&self, params: &[R], points: &[R]) -> Vec<R>
    where
        S: Module<R> + Sync,
    {
        use rayon::prelude::*;
        let net = &self.sdf;
        let p_sdf = &params[..net.n_params()];
        let mut out = vec![R::ZERO; points.len() / 3];
        out.par_chunks_mut(1024).zip(points.par_chunks(3 * 1024)).for_each(|(o, x)| net.forward_first(p_sdf, x, o));
        out
    }
}
