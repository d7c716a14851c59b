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
//! `nᵢ = ∇ₓS(xᵢ)` exactly, by forward-mode derivatives along x, y, z through the hash grid (the
//! trilinear weights' gradients on the same 8 corners) and the MLP (`Ż = Ȧ Wᵀ`, `Ȧ' = act'(Z) ⊙
//! Ż`), with no probe rows; the backward pass needs one tangent only — along `vᵢ = ∂L/∂nᵢ`,
//! since `vᵢ · δnᵢ = δ(∂S/∂x · vᵢ)` — and runs the reverse of the values and that tangent
//! together (act'' from act', the tables' gradient `w_c ȳ + (∇w_c · v) ẏ̄`). The
//! colour network maps `[xᵢ, nᵢ, SH₄(d), featuresᵢ]` to the colour of interval i; the ray is
//! rendered with [`render_ray`] at scale `s = exp(10·v)` (NeuS's learnt variance v). The loss is
//! the colour error (L1 as NeuS, or L2) of `colour + (1 − opacity)·background`, plus
//! `λ_eik · mean (|nᵢ| − 1)²`, plus `λ_smooth · mean |nᵢ₊₁ − nᵢ|²` (the normal smoothness),
//! plus, with a mask, `λ_mask · BCE(opacity, mask)`, plus any
//! per-ray loss on the samples supplied by the caller ([`SampleLoss`]: the surface losses).
//!
//! Gradients of a batch are deterministic: rays are cut into fixed chunks, each chunk's gradient
//! is computed on its own and the chunks are summed in order, so the result does not depend on
//! the thread count.
//!
//! The backward pass chains [`render_ray_backward`] → colour network → normals (each ∂L/∂nᵢ
//! becomes ±1/2h on the six neighbour evaluations) → SDF network at all 7n + 1 points.
//! Everything is generic over [`Real`] so that the whole pipeline is gradient-checked in f64.

use crate::background::BackgroundModel;
use crate::encoding::SphericalHarmonics;
use crate::module::Module;
use crate::real::Real;
use crate::render::{render_ray, render_ray_backward};
use crate::scratch::Buf;

mod deferred;
mod normals;
use deferred::Deferred;
pub use deferred::DeferredGradient;
pub use normals::NormalScheme;

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

/// A chunk's loss, gradient (all but the deferred parameters), outputs and deferred record.
type Part<R> = (R, Buf<R>, Vec<RayOutput<R>>, Deferred<R>);

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
    /// Central or tetrahedral differences.
    pub normals: NormalScheme,
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
    /// Weight of the normal smoothness `mean |nᵢ₊₁ − nᵢ|²` over neighbouring samples of a ray
    /// (0: off). Rays cross the surface from many directions, so over a batch it penalises
    /// `|H d|²`, the Hessian of S along the rays: zero on a plane, large on bumps. It needs only
    /// the normals the pipeline has, so it works with analytic normals, where the curvature
    /// term's Laplacian (from probes) is not available.
    pub normal_smoothness: f64,
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
    pub fn loss<R: Real>(&self, params: &[R], rays: &[RayInput<R>], d_params: Option<&mut [R]>, extra: &dyn SampleLoss) -> (R, Vec<RayOutput<R>>)
    where
        S: Module<R>,
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
                let (loss, outputs, deferred) = self.accumulate(params, rays, 0, Some(d_rest), m, norm, extra);
                let tangent = self.config.normals == NormalScheme::Analytic;
                DeferredGradient { records: deferred.into_iter().collect(), tangent }.apply(&self.sdf, d_deferred);
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
    pub fn loss_parallel<R: Real>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_params: &mut [R],
        chunk: usize,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>)
    where
        S: Module<R> + Sync,
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
    /// [`Module::deferred_params`], the first ones) left out: `d_rest` is the gradient of the
    /// parameters after them, and their own gradient comes back as records to apply (whole, or one
    /// block at a time with [`DeferredGradient::apply_block`]).
    pub fn loss_parallel_split<R: Real>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        d_rest: &mut [R],
        chunk: usize,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>, DeferredGradient<R>)
    where
        S: Module<R> + Sync,
        C: Module<R> + Sync,
    {
        use rayon::prelude::*;
        let n_rest = d_rest.len();
        let m = R::of(rays.len() as f64);
        let norm = self.color_normaliser::<R>(rays);
        let chunk = chunk.max(1);
        let parts: Vec<Part<R>> = rays
            .par_chunks(chunk)
            .enumerate()
            .map(|(i, c)| {
                let mut g = Buf::<R>::zeroed(n_rest);
                let (l, o, deferred) = self.accumulate(params, c, i * chunk, Some(&mut g), m, norm, extra);
                (l, g, o, deferred)
            })
            .collect();
        let mut loss = R::ZERO;
        let mut outputs = Vec::with_capacity(rays.len());
        let mut grads = Vec::with_capacity(parts.len());
        let mut records = Vec::with_capacity(parts.len());
        for (l, g, o, d) in parts {
            loss += l;
            grads.push(g);
            outputs.extend(o);
            records.extend(d);
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
        (loss, outputs, DeferredGradient { records, tangent: self.config.normals == NormalScheme::Analytic })
    }

    /// SDF values (first output of the SDF network) at `points` (xyz rows), in parallel chunks.
    pub fn sdf_values<R: Real>(&self, params: &[R], points: &[R]) -> Vec<R>
    where
        S: Module<R> + Sync,
    {
        use rayon::prelude::*;
        let net = &self.sdf;
        let p_sdf = &params[..net.n_params()];
        let n_out = net.n_outputs();
        let mut out = vec![R::ZERO; points.len() / 3];
        out.par_chunks_mut(1024).zip(points.par_chunks(3 * 1024)).for_each(|(o, x)| {
            let rows = o.len();
            let mut y = vec![R::ZERO; rows * n_out];
            let mut ctx = vec![R::ZERO; rows * net.ctx_per_row()];
            net.forward(p_sdf, x, &mut y, &mut ctx);
            for (v, row) in o.iter_mut().zip(y.chunks_exact(n_out)) {
                *v = row[0];
            }
        });
        out
    }

    /// The loss of `rays` (the batch's rays from index `first`) divided by `m` (the whole batch's
    /// ray count; the colour loss by `color_norm`), gradients added to `d_params`, which covers
    /// every parameter after the SDF network's deferred ones ([`Module::deferred_params`]); their
    /// gradient is returned as (points, record) for [`Module::apply_deferred`]. All rays of the call go
    /// through each network together (one matrix product per layer), the per-ray work in between.
    #[allow(clippy::too_many_arguments)]
    fn accumulate<R: Real>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        first: usize,
        d_params: Option<&mut [R]>,
        m: R,
        color_norm: R,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>, Deferred<R>)
    where
        S: Module<R>,
        C: Module<R>,
    {
        let _span = crate::profile::span(crate::profile::Stage::LossPass);
        let (n_sdf, n_col) = (self.sdf.n_params(), self.color.n_params());
        let n_def = self.sdf.deferred_params();
        let (p_sdf, rest) = params.split_at(n_sdf);
        let (p_col, p_var) = rest.split_at(n_col);
        let (var, p_bg) = (p_var[0], &p_var[1..]);
        let s = scale_from_variance(var);
        let f = self.sdf.n_outputs() - 1;
        let n_out = 1 + f;
        let h = R::of(self.config.normal_step);
        let probes = self.config.normals.probes();
        let np = probes.len();
        let fixed_background = self.config.background.map(R::of);
        let sh = SphericalHarmonics;
        let c_in = 22 + f;

        // Row layout: ray r owns SDF rows [sdf_at[r], sdf_at[r] + (np + 1) n_r + 1) (n_r + 1
        // samples, then np probes per sample i < n_r) and colour rows [col_at[r], col_at[r] + n_r).
        let mut sdf_at = Vec::with_capacity(rays.len() + 1);
        let mut col_at = Vec::with_capacity(rays.len() + 1);
        let (mut sdf_rows, mut col_rows) = (0, 0);
        for ray in rays {
            let n = ray.depths.len() - 1;
            sdf_at.push(sdf_rows);
            col_at.push(col_rows);
            sdf_rows += (np + 1) * n + 1;
            col_rows += n;
        }
        let mut points = Buf::<R>::zeroed(3 * sdf_rows);
        let mut at = 0;
        for ray in rays {
            let n = ray.depths.len() - 1;
            let base = at;
            for &t in &ray.depths {
                for k in 0..3 {
                    points[at + k] = ray.origin[k] + t * ray.direction[k];
                }
                at += 3;
            }
            for i in 0..n {
                for (offset, _) in probes {
                    for k in 0..3 {
                        points[at + k] = points[base + 3 * i + k] + R::of(offset[k]) * h;
                    }
                    at += 3;
                }
            }
        }
        let mut sdf_out = Buf::<R>::zeroed(sdf_rows * n_out);
        let mut sdf_ctx = Buf::<R>::zeroed(sdf_rows * self.sdf.ctx_per_row());
        self.sdf.forward(p_sdf, &points, &mut sdf_out, &mut sdf_ctx);
        // Analytic normals: the derivatives of the outputs along x, y, z at every point
        // (rows × 3 × n_out; the SDF's are ∇ₓS).
        let analytic = self.config.normals == NormalScheme::Analytic;
        debug_assert!(!analytic || self.sdf.has_tangents(), "analytic normals need an SDF network with tangents");
        let gradients = analytic.then(|| {
            let mut axes = Buf::<R>::zeroed(sdf_rows * 9);
            for row in axes.chunks_exact_mut(9) {
                row[0] = R::ONE;
                row[4] = R::ONE;
                row[8] = R::ONE;
            }
            let mut out = Buf::<R>::zeroed(sdf_rows * 3 * n_out);
            self.sdf.forward_tangents(p_sdf, &points, &sdf_ctx, 3, &axes, &mut out);
            out
        });

        // Normals and colour-network inputs [x, n, SH(d), features] of every interval.
        let mut normals: Vec<[R; 3]> = Vec::with_capacity(col_rows);
        let mut sh_all: Vec<[R; 16]> = Vec::with_capacity(rays.len());
        let mut color_in = Buf::<R>::zeroed(col_rows * c_in);
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (sdf_at[r], col_at[r]);
            let mut sh_d = [R::ZERO; 16];
            sh.forward(&[], &ray.direction, &mut sh_d, &mut []);
            sh_all.push(sh_d);
            for i in 0..n {
                let nrm = match &gradients {
                    Some(grad) => [0, 1, 2].map(|k| grad[((b + i) * 3 + k) * n_out]),
                    None => {
                        let mut g = [R::ZERO; 3];
                        for (j, (offset, w)) in probes.iter().enumerate() {
                            let v = sdf_out[(b + n + 1 + np * i + j) * n_out];
                            for k in 0..3 {
                                g[k] += R::of(offset[k] * w) * v;
                            }
                        }
                        g.map(|v| v / h)
                    }
                };
                normals.push(nrm);
                let row = &mut color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                row[..3].copy_from_slice(&points[3 * (b + i)..3 * (b + i) + 3]);
                row[3..6].copy_from_slice(&nrm);
                row[6..22].copy_from_slice(&sh_d);
                row[22..].copy_from_slice(&sdf_out[(b + i) * n_out + 1..(b + i + 1) * n_out]);
            }
        }
        let mut colors_flat = Buf::<R>::zeroed(col_rows * 3);
        let mut color_ctx = Buf::<R>::zeroed(col_rows * self.color.ctx_per_row());
        self.color.forward(p_col, &color_in, &mut colors_flat, &mut color_ctx);
        // Learned background of every ray.
        let bg_pass = self.background.as_ref().map(|model| {
            let origins: Vec<[R; 3]> = rays.iter().map(|r| r.origin).collect();
            let directions: Vec<[R; 3]> = rays.iter().map(|r| r.direction).collect();
            model.forward(p_bg, &origins, &directions, &sh_all)
        });

        let mut total = R::ZERO;
        let mut outputs = Vec::with_capacity(rays.len());
        let backward = d_params.is_some();
        let inv_m = R::ONE / m;
        // Per-row gradients gathered for one backward pass per network.
        let mut d_colors_flat = Buf::<R>::zeroed(if backward { col_rows * 3 } else { 0 });
        let mut d_sdf_direct = Buf::<R>::zeroed(if backward { sdf_rows } else { 0 });
        let mut d_normals_all = if backward { vec![[R::ZERO; 3]; col_rows] } else { Vec::new() };
        let mut d_laplacian_all = Buf::<R>::zeroed(if backward { col_rows } else { 0 });
        let mut d_bg_all = vec![[R::ZERO; 3]; if backward { rays.len() } else { 0 }];
        let mut d_var = R::ZERO;
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (sdf_at[r], col_at[r]);
            let sdf_values: Vec<R> = (0..=n).map(|i| sdf_out[(b + i) * n_out]).collect();
            let probe = |i: usize, j: usize| sdf_out[(b + n + 1 + np * i + j) * n_out];
            let colors: Vec<[R; 3]> = colors_flat[3 * c0..3 * (c0 + n)].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
            let nrms = &normals[c0..c0 + n];
            let r_out = render_ray(&sdf_values, &ray.depths, &colors, s);
            let background = match &bg_pass {
                Some(pass) => pass.colors[r],
                None => fixed_background,
            };
            let composited: [R; 3] = [0, 1, 2].map(|k| r_out.color[k] + (R::ONE - r_out.opacity) * background[k]);
            // Colour loss: on the composited colour, or (masked) on the rendered colour of
            // foreground rays only, normalised by their count instead of the batch's.
            let masked = self.config.masked_color;
            let color_weight = ray.weight
                * if !masked {
                    R::ONE
                } else if ray.mask.is_none_or(|mk| mk >= R::of(0.5)) {
                    m / color_norm
                } else {
                    R::ZERO
                };
            let predicted = if masked { r_out.color } else { composited };
            let mut d_color = [R::ZERO; 3];
            let mut loss = R::ZERO;
            for k in 0..3 {
                let e = predicted[k] - ray.target[k];
                match self.config.color_loss {
                    ColorLoss::L1 => {
                        loss += color_weight * e.abs();
                        let sign = if e > R::ZERO {
                            R::ONE
                        } else if e < R::ZERO {
                            -R::ONE
                        } else {
                            R::ZERO
                        };
                        d_color[k] = color_weight * sign;
                    }
                    ColorLoss::L2 => {
                        loss += color_weight * e * e;
                        d_color[k] = color_weight * (e + e);
                    }
                }
            }
            let mut d_opacity =
                if masked { R::ZERO } else { -(d_color[0] * background[0] + d_color[1] * background[1] + d_color[2] * background[2]) };
            // Curvature: mean |ΔS| over the samples.
            let curv_w = R::of(self.config.curvature_weight) / R::of(n as f64);
            let c_probe: f64 = probes.iter().map(|(o, _)| o[0] * o[0]).sum();
            let lap_den = h * h * R::of(c_probe * 0.5);
            if self.config.curvature_weight > 0.0 && np > 0 {
                for i in 0..n {
                    let mut lap = -R::of(np as f64) * sdf_values[i];
                    for j in 0..np {
                        lap += probe(i, j);
                    }
                    lap = lap / lap_den;
                    loss += curv_w * lap.abs();
                    if backward {
                        d_laplacian_all[c0 + i] = if lap > R::ZERO {
                            curv_w / lap_den
                        } else if lap < R::ZERO {
                            -curv_w / lap_den
                        } else {
                            R::ZERO
                        } * inv_m;
                    }
                }
            }
            let eik_w = R::of(self.config.eikonal_weight) / R::of(n as f64);
            for i in 0..n {
                let nv = nrms[i];
                let len = (nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2]).sqrt();
                let e = len - R::ONE;
                loss += eik_w * e * e;
                if backward && len > R::ZERO {
                    for k in 0..3 {
                        d_normals_all[c0 + i][k] = eik_w * (e + e) * nv[k] / len * inv_m;
                    }
                }
            }
            if self.config.normal_smoothness > 0.0 && n > 1 {
                let w = R::of(self.config.normal_smoothness) / R::of((n - 1) as f64);
                for i in 0..n - 1 {
                    let change = [0, 1, 2].map(|k| nrms[i + 1][k] - nrms[i][k]);
                    loss += w * (change[0] * change[0] + change[1] * change[1] + change[2] * change[2]);
                    if backward {
                        for k in 0..3 {
                            let d = w * (change[k] + change[k]) * inv_m;
                            d_normals_all[c0 + i + 1][k] += d;
                            d_normals_all[c0 + i][k] -= d;
                        }
                    }
                }
            }
            if ray.mask.is_none() && self.config.opacity_entropy > 0.0 {
                let eps = R::of(1e-3);
                let o = r_out.opacity.max(eps).min(R::ONE - eps);
                let w = R::of(self.config.opacity_entropy) * ray.weight;
                loss += -w * (o * o.ln() + (R::ONE - o) * (R::ONE - o).ln());
                if r_out.opacity > eps && r_out.opacity < R::ONE - eps {
                    d_opacity += w * ((R::ONE - o) / o).ln();
                }
            }
            if let Some(mask) = ray.mask {
                // BCE with the opacity clamped away from 0 and 1 (NeuS clips to [1e-3, 1 − 1e-3]).
                let eps = R::of(1e-3);
                let o = r_out.opacity.max(eps).min(R::ONE - eps);
                let w = R::of(self.config.mask_weight) * ray.weight;
                loss += -w * (mask * o.ln() + (R::ONE - mask) * (R::ONE - o).ln());
                if r_out.opacity > eps && r_out.opacity < R::ONE - eps {
                    d_opacity += -w * (mask / o - (R::ONE - mask) / (R::ONE - o));
                }
            }
            // The caller's loss on the samples (f64).
            let t64: Vec<f64> = ray.depths.iter().map(|v| v.to_f64()).collect();
            let sdf64: Vec<f64> = sdf_values.iter().map(|v| v.to_f64()).collect();
            let w64: Vec<f64> = r_out.weights.iter().map(|v| v.to_f64()).collect();
            let mut d_sdf_extra = vec![0.0f64; n + 1];
            let mut d_w_extra = vec![0.0f64; n];
            loss += R::of(extra.ray_loss(first + r, s.to_f64(), &t64, &sdf64, &w64, &mut d_sdf_extra, &mut d_w_extra));
            total += loss / m;
            let mut normal = [R::ZERO; 3];
            for i in 0..n {
                for k in 0..3 {
                    normal[k] += r_out.weights[i] * nrms[i][k];
                }
            }
            outputs.push(RayOutput { color: composited, opacity: r_out.opacity, depth: r_out.depth, normal });
            if !backward {
                continue;
            }
            let d_w: Vec<R> = d_w_extra.iter().map(|&v| R::of(v) * inv_m).collect();
            let g =
                render_ray_backward(&sdf_values, &ray.depths, &colors, s, &r_out, d_color.map(|d| d * inv_m), R::ZERO, d_opacity * inv_m, Some(&d_w));
            d_var += g.s * scale_derivative(s);
            if !masked {
                for k in 0..3 {
                    d_bg_all[r][k] = d_color[k] * (R::ONE - r_out.opacity) * inv_m;
                }
            }
            for (i, c) in g.colors.iter().enumerate() {
                d_colors_flat[3 * (c0 + i)..3 * (c0 + i) + 3].copy_from_slice(c);
            }
            for i in 0..=n {
                d_sdf_direct[b + i] = g.sdf[i] + R::of(d_sdf_extra[i]) * inv_m;
            }
        }
        let Some(d_params) = d_params else { return (total, outputs, None) };
        let (d_sdf_params, rest) = d_params.split_at_mut(n_sdf - n_def);
        let (d_col_params, d_rest) = rest.split_at_mut(n_col);
        d_rest[0] += d_var;
        if let (Some(model), Some(pass)) = (&self.background, &bg_pass) {
            model.backward(p_bg, pass, &d_bg_all, &mut d_rest[1..]);
        }
        // Colour network backward → ∂L/∂n, ∂L/∂features.
        let mut d_color_in = Buf::<R>::zeroed(col_rows * c_in);
        self.color.backward(p_col, &color_in, &color_ctx, &d_colors_flat, d_col_params, Some(&mut d_color_in));
        // ∂L/∂(SDF outputs) at every point.
        let mut d_sdf_out = Buf::<R>::zeroed(sdf_rows * n_out);
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (sdf_at[r], col_at[r]);
            for i in 0..=n {
                d_sdf_out[(b + i) * n_out] = d_sdf_direct[b + i];
            }
            for i in 0..n {
                let row = &d_color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                for j in 0..f {
                    d_sdf_out[(b + i) * n_out + 1 + j] += row[22 + j];
                }
                let d_lap = d_laplacian_all[c0 + i];
                for (j, (offset, w)) in probes.iter().enumerate() {
                    let mut d = R::ZERO;
                    for k in 0..3 {
                        d += (row[3 + k] + d_normals_all[c0 + i][k]) * R::of(offset[k] * w);
                    }
                    d_sdf_out[(b + n + 1 + np * i + j) * n_out] += d / h + d_lap;
                }
                d_sdf_out[(b + i) * n_out] -= R::of(np as f64) * d_lap;
            }
        }
        if analytic {
            // L depends on nᵢ = ∇ₓS(xᵢ) through vᵢ = ∂L/∂nᵢ, and vᵢ·δnᵢ = δ(∂S/∂x · vᵢ): the
            // derivative of S along vᵢ, with adjoint 1, whatever vᵢ's length.
            let mut v = Buf::<R>::zeroed(3 * sdf_rows);
            let mut d_tangent_out = Buf::<R>::zeroed(sdf_rows * n_out);
            for (r, ray) in rays.iter().enumerate() {
                let n = ray.depths.len() - 1;
                let (b, c0) = (sdf_at[r], col_at[r]);
                for i in 0..n {
                    let row = &d_color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                    for k in 0..3 {
                        v[3 * (b + i) + k] = row[3 + k] + d_normals_all[c0 + i][k];
                    }
                    d_tangent_out[(b + i) * n_out] = R::ONE;
                }
            }
            if n_def == 0 {
                self.sdf.backward_tangent(p_sdf, &points, &sdf_ctx, &v, &d_sdf_out, &d_tangent_out, d_sdf_params, None);
                return (total, outputs, None);
            }
            let mut record = Buf::<R>::zeroed(2 * sdf_rows * self.sdf.deferred_width());
            self.sdf.backward_tangent_deferring(p_sdf, &points, &sdf_ctx, &v, &d_sdf_out, &d_tangent_out, d_sdf_params, &mut record);
            // The record's input: the points, then their tangents.
            let mut points_and_tangents = Buf::<R>::zeroed(6 * sdf_rows);
            points_and_tangents[..3 * sdf_rows].copy_from_slice(&points);
            points_and_tangents[3 * sdf_rows..].copy_from_slice(&v);
            return (total, outputs, Some((points_and_tangents, record)));
        }
        if n_def == 0 {
            self.sdf.backward(p_sdf, &points, &sdf_ctx, &d_sdf_out, d_sdf_params, None);
            return (total, outputs, None);
        }
        let mut record = Buf::<R>::zeroed(sdf_rows * self.sdf.deferred_width());
        self.sdf.backward_deferring(p_sdf, &points, &sdf_ctx, &d_sdf_out, d_sdf_params, &mut record);
        (total, outputs, Some((points, record)))
    }
}
