//! The NeuS render + loss pipeline for a batch of rays, with its hand-written backward.
//!
//! Per ray with sample depths t₀ … tₙ: the SDF network is evaluated at the n + 1 points
//! `xᵢ = o + tᵢ d` (SDF and geometry features) and at the 6n points `xᵢ ± h·e_k` (i < n) that
//! give the normals by central differences, `nᵢ = (S(xᵢ + h e_k) − S(xᵢ − h e_k)) / 2h`. The
//! colour network maps `[xᵢ, nᵢ, SH₄(d), featuresᵢ]` to the colour of interval i; the ray is
//! rendered with [`render_ray`] at scale `s = exp(10·v)` (NeuS's learnt variance v). The loss is
//! the colour error (L1 as NeuS, or L2), plus `λ_eik · mean (|nᵢ| − 1)²`, plus, with a mask,
//! `λ_mask · BCE(opacity, mask)`.
//!
//! The backward pass chains [`render_ray_backward`] → colour network → normals (each ∂L/∂nᵢ
//! becomes ±1/2h on the six neighbour evaluations) → SDF network at all 7n + 1 points.
//! Everything is generic over [`Real`] so that the whole pipeline is gradient-checked in f64.

use crate::encoding::{SphericalHarmonics, WithInput};
use crate::hashgrid::{HashGrid, HashGridConfig};
use crate::mlp::{Mlp, MlpConfig};
use crate::module::{Activation, Chain};
use crate::module::Module;
use crate::real::Real;
use crate::render::{render_ray, render_ray_backward};

/// Colour loss.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColorLoss {
    /// |c − ĉ| summed over channels (NeuS).
    L1,
    /// (c − ĉ)² summed over channels.
    L2,
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
}

/// Loss weights and numerics of the pipeline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PipelineConfig {
    /// Colour loss.
    pub color_loss: ColorLoss,
    /// Eikonal weight (NeuS: 0.1).
    pub eikonal_weight: f64,
    /// Mask BCE weight (NeuS with masks: 0.1).
    pub mask_weight: f64,
    /// Step of the central differences for normals (Neuralangelo ties it to the finest level).
    pub normal_step: f64,
}

/// SDF network + colour network + learnt variance, parameters `[sdf | colour | v]`.
#[derive(Debug, Clone)]
pub struct Pipeline<S, C> {
    /// SDF network: 3 inputs → 1 + F outputs (SDF, features).
    pub sdf: S,
    /// Colour network: 3 + 3 + 16 + F inputs → 3 outputs (sigmoid).
    pub color: C,
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
    /// Depth Σ w t.
    pub depth: R,
}

impl<S, C> Pipeline<S, C> {
    /// Total parameters: SDF, colour, and the variance v.
    pub fn n_params<R: Real>(&self) -> usize
    where
        S: Module<R>,
        C: Module<R>,
    {
        self.sdf.n_params() + self.color.n_params() + 1
    }

    /// Loss of a batch (averaged over rays) and, if `d_params` is given, its gradient added into
    /// it. Returns the loss and the per-ray outputs. Sequential; see [`Self::loss_parallel`].
    pub fn loss<R: Real>(&self, params: &[R], rays: &[RayInput<R>], d_params: Option<&mut [R]>) -> (R, Vec<RayOutput<R>>)
    where
        S: Module<R>,
        C: Module<R>,
    {
        self.accumulate(params, rays, d_params, R::of(rays.len() as f64))
    }

    /// [`Self::loss`] over chunks of `chunk` rays in parallel, one gradient buffer per worker
    /// (rayon `fold`), summed at the end. Same result as `loss` up to the order of additions.
    pub fn loss_parallel<R: Real>(&self, params: &[R], rays: &[RayInput<R>], d_params: &mut [R], chunk: usize) -> (R, Vec<RayOutput<R>>)
    where
        S: Module<R> + Sync,
        C: Module<R> + Sync,
    {
        use rayon::prelude::*;
        let n = d_params.len();
        let m = R::of(rays.len() as f64);
        type Partial<R> = (R, Vec<R>, Vec<(usize, Vec<RayOutput<R>>)>);
        let (loss, grads, mut outputs): Partial<R> = rays
            .par_chunks(chunk.max(1))
            .enumerate()
            .fold(
                || (R::ZERO, vec![R::ZERO; n], Vec::new()),
                |(l, mut g, mut o), (i, c)| {
                    let (cl, co) = self.accumulate(params, c, Some(&mut g), m);
                    o.push((i, co));
                    (l + cl, g, o)
                },
            )
            .reduce(
                || (R::ZERO, vec![R::ZERO; n], Vec::new()),
                |(la, mut ga, mut oa), (lb, gb, ob)| {
                    for (a, b) in ga.iter_mut().zip(&gb) {
                        *a += *b;
                    }
                    oa.extend(ob);
                    (la + lb, ga, oa)
                },
            );
        for (d, g) in d_params.iter_mut().zip(&grads) {
            *d += *g;
        }
        outputs.sort_by_key(|(i, _)| *i);
        (loss, outputs.into_iter().flat_map(|(_, o)| o).collect())
    }

    /// The loss of `rays` divided by `m` (the whole batch's ray count), gradients added.
    fn accumulate<R: Real>(&self, params: &[R], rays: &[RayInput<R>], mut d_params: Option<&mut [R]>, m: R) -> (R, Vec<RayOutput<R>>)
    where
        S: Module<R>,
        C: Module<R>,
    {
        let (n_sdf, n_col) = (self.sdf.n_params(), self.color.n_params());
        let (p_sdf, rest) = params.split_at(n_sdf);
        let (p_col, p_var) = rest.split_at(n_col);
        let var = p_var[0];
        let s = (R::of(10.0) * var).exp();
        let f = self.sdf.n_outputs() - 1;
        let h = R::of(self.config.normal_step);
        let mut total = R::ZERO;
        let mut outputs = Vec::with_capacity(rays.len());
        let sh = SphericalHarmonics;
        for ray in rays {
            let n = ray.depths.len() - 1;
            // Points: n + 1 samples, then 6n normal probes (+x, −x, +y, −y, +z, −z per sample).
            let mut points = Vec::with_capacity(3 * (7 * n + 1));
            for &t in &ray.depths {
                for k in 0..3 {
                    points.push(ray.origin[k] + t * ray.direction[k]);
                }
            }
            for i in 0..n {
                for k in 0..3 {
                    for sign in [R::ONE, -R::ONE] {
                        let mut p = [points[3 * i], points[3 * i + 1], points[3 * i + 2]];
                        p[k] += sign * h;
                        points.extend_from_slice(&p);
                    }
                }
            }
            let rows = points.len() / 3;
            let n_out = 1 + f;
            let mut sdf_out = vec![R::ZERO; rows * n_out];
            let mut sdf_ctx = vec![R::ZERO; rows * self.sdf.ctx_per_row()];
            self.sdf.forward(p_sdf, &points, &mut sdf_out, &mut sdf_ctx);
            let sdf_values: Vec<R> = (0..=n).map(|i| sdf_out[i * n_out]).collect();
            let probe = |i: usize, k: usize, side: usize| sdf_out[(n + 1 + 6 * i + 2 * k + side) * n_out];
            let normals: Vec<[R; 3]> = (0..n).map(|i| [0, 1, 2].map(|k| (probe(i, k, 0) - probe(i, k, 1)) / (h + h))).collect();

            // Colour network inputs [x, n, SH(d), features].
            let mut sh_d = [R::ZERO; 16];
            sh.forward(&[], &ray.direction, &mut sh_d, &mut []);
            let c_in = 22 + f;
            let mut color_in = vec![R::ZERO; n * c_in];
            for i in 0..n {
                let row = &mut color_in[i * c_in..(i + 1) * c_in];
                row[..3].copy_from_slice(&points[3 * i..3 * i + 3]);
                row[3..6].copy_from_slice(&normals[i]);
                row[6..22].copy_from_slice(&sh_d);
                row[22..].copy_from_slice(&sdf_out[i * n_out + 1..(i + 1) * n_out]);
            }
            let mut colors_flat = vec![R::ZERO; n * 3];
            let mut color_ctx = vec![R::ZERO; n * self.color.ctx_per_row()];
            self.color.forward(p_col, &color_in, &mut colors_flat, &mut color_ctx);
            let colors: Vec<[R; 3]> = colors_flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();

            let r = render_ray(&sdf_values, &ray.depths, &colors, s);
            // Losses.
            let mut d_color = [R::ZERO; 3];
            let mut loss = R::ZERO;
            for k in 0..3 {
                let e = r.color[k] - ray.target[k];
                match self.config.color_loss {
                    ColorLoss::L1 => {
                        loss += e.abs();
                        d_color[k] = if e > R::ZERO { R::ONE } else if e < R::ZERO { -R::ONE } else { R::ZERO };
                    }
                    ColorLoss::L2 => {
                        loss += e * e;
                        d_color[k] = e + e;
                    }
                }
            }
            let eik_w = R::of(self.config.eikonal_weight) / R::of(n as f64);
            let mut d_normals = vec![[R::ZERO; 3]; n];
            for i in 0..n {
                let len = (normals[i][0] * normals[i][0] + normals[i][1] * normals[i][1] + normals[i][2] * normals[i][2]).sqrt();
                let e = len - R::ONE;
                loss += eik_w * e * e;
                if len > R::ZERO {
                    for k in 0..3 {
                        d_normals[i][k] = eik_w * (e + e) * normals[i][k] / len;
                    }
                }
            }
            let mut d_opacity = R::ZERO;
            if let Some(mask) = ray.mask {
                // BCE with the opacity clamped away from 0 and 1 (NeuS clips to [1e-3, 1 − 1e-3]).
                let eps = R::of(1e-3);
                let o = r.opacity.max(eps).min(R::ONE - eps);
                let w = R::of(self.config.mask_weight);
                loss += -w * (mask * o.ln() + (R::ONE - mask) * (R::ONE - o).ln());
                if r.opacity > eps && r.opacity < R::ONE - eps {
                    d_opacity = -w * (mask / o - (R::ONE - mask) / (R::ONE - o));
                }
            }
            total += loss / m;
            outputs.push(RayOutput { color: r.color, opacity: r.opacity, depth: r.depth });

            let Some(d_params) = d_params.as_deref_mut() else { continue };
            let inv_m = R::ONE / m;
            let g = render_ray_backward(
                &sdf_values,
                &ray.depths,
                &colors,
                s,
                &r,
                d_color.map(|d| d * inv_m),
                R::ZERO,
                d_opacity * inv_m,
                None,
            );
            let (d_sdf_params, rest) = d_params.split_at_mut(n_sdf);
            let (d_col_params, d_var) = rest.split_at_mut(n_col);
            d_var[0] += g.s * R::of(10.0) * s;
            // Colour network backward → ∂L/∂n, ∂L/∂features.
            let d_colors_flat: Vec<R> = g.colors.iter().flatten().copied().collect();
            let mut d_color_in = vec![R::ZERO; n * c_in];
            self.color.backward(p_col, &color_in, &color_ctx, &d_colors_flat, d_col_params, Some(&mut d_color_in));
            // ∂L/∂(SDF outputs) at every point.
            let mut d_sdf_out = vec![R::ZERO; rows * n_out];
            for i in 0..=n {
                d_sdf_out[i * n_out] = g.sdf[i];
            }
            for i in 0..n {
                let row = &d_color_in[i * c_in..(i + 1) * c_in];
                for j in 0..f {
                    d_sdf_out[i * n_out + 1 + j] += row[22 + j];
                }
                for k in 0..3 {
                    let dn = (row[3 + k] + d_normals[i][k] * inv_m) / (h + h);
                    d_sdf_out[(n + 1 + 6 * i + 2 * k) * n_out] += dn;
                    d_sdf_out[(n + 1 + 6 * i + 2 * k + 1) * n_out] -= dn;
                }
            }
            self.sdf.backward(p_sdf, &points, &sdf_ctx, &d_sdf_out, d_sdf_params, None);
        }
        (total, outputs)
    }
}


/// The Neuralangelo-style pipeline sized for a 2-core CPU.
pub type HashGridPipeline = Pipeline<Chain<WithInput<HashGrid>, Mlp>, Mlp>;

/// The CPU preset: raw xyz + hash grid ([`HashGridConfig::neuralangelo_cpu`]) → SDF MLP 2 × 64
/// (softplus 100) → SDF + 15 features; colour MLP 2 × 64 (ReLU, sigmoid output); L1 colour loss,
/// eikonal 0.1, mask BCE 0.1, normal step = the finest cell (1/256). Returns it with its
/// parameters initialised: grid ±1e-4, SDF MLP geometric (sphere of radius `radius`), colour MLP
/// He, variance 0.3 (NeuS: s = e³ ≈ 20).
pub fn neuralangelo_cpu(radius: f64, seed: u64) -> (HashGridPipeline, Vec<f32>) {
    let grid = HashGrid::new(HashGridConfig::neuralangelo_cpu());
    let features = 15;
    let sdf_mlp = Mlp::new(MlpConfig {
        n_inputs: 3 + Module::<f32>::n_outputs(&grid),
        width: 64,
        hidden_layers: 2,
        n_outputs: 1 + features,
        skip: None,
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 22 + features,
        width: 64,
        hidden_layers: 2,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Sigmoid,
    });
    let n_grid = Module::<f32>::n_params(&grid);
    let n_sdf = n_grid + Module::<f32>::n_params(&sdf_mlp);
    let pipeline = Pipeline {
        sdf: Chain { a: WithInput { encoding: grid }, b: sdf_mlp },
        color,
        config: PipelineConfig { color_loss: ColorLoss::L1, eikonal_weight: 0.1, mask_weight: 0.1, normal_step: 1.0 / 256.0 },
    };
    let n = pipeline.n_params::<f32>();
    let mut params = vec![0.0f32; n];
    pipeline.sdf.a.encoding.init(&mut params[..n_grid], 1e-4, seed);
    pipeline.sdf.b.init_geometric(&mut params[n_grid..n_sdf], radius, 3, seed + 1);
    pipeline.color.init_default(&mut params[n_sdf..n - 1], seed + 2);
    params[n - 1] = 0.3;
    (pipeline, params)
}
