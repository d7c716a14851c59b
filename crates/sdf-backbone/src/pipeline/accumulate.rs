//! One work item of the pipeline: the loss of some rays and its gradient, in named stages —
//! [`Rows`] (the row layout), [`Pipeline::sdf_pass`] (SDF and normals), [`Pipeline::color_pass`]
//! (colour inputs, colour network, background), [`Pipeline::ray_terms`] (each ray's render,
//! its loss terms — `terms.rs` — and its render backward), [`Pipeline::network_adjoints`] (background and colour
//! network backward, the SDF outputs' adjoints), then [`Pipeline::sdf_backward`] or
//! [`Pipeline::sdf_tangent_backward`]. All rays of the item go through each network together
//! (one matrix product per layer), the per-ray work in between.

use super::analytic::InputGradientFn;
use super::deferred::Deferred;
use super::{Pipeline, RayInput, RayOutput, SampleLoss, TangentFns, TangentPrecision, scale_derivative, scale_from_variance};
use crate::background::BackgroundPass;
use crate::encoding::SphericalHarmonics;
use crate::module::{DeferringModule, Module, TangentAdjoints};
use crate::real::Real;
use crate::render::{render_ray, render_ray_backward};
use crate::scratch::Buf;

mod terms;

/// What a work item's backward pass leaves to be applied later: the SDF network's deferred
/// record, and the learned background grid's when the item's gradient stops before its tables.
pub(super) struct Records<R: Real> {
    pub(super) sdf: Deferred<R>,
    pub(super) background: Deferred<R>,
}

impl<R: Real> Default for Records<R> {
    fn default() -> Self {
        Records { sdf: None, background: None }
    }
}

/// Colour-network inputs per row before the features: x (3), n (3), SH₄(d) (16).
pub(super) const COLOR_IN_FIXED: usize = 22;

/// The row layout of a work item: ray r owns SDF rows `[sdf_at[r], sdf_at[r] + (np + 1) n_r + 1)`
/// (its n_r + 1 samples, then np probes per sample i < n_r) and colour rows
/// `[col_at[r], col_at[r] + n_r)` (one per interval).
struct Rows {
    sdf_at: Vec<usize>,
    col_at: Vec<usize>,
    sdf: usize,
    col: usize,
}

impl Rows {
    fn of<R>(rays: &[RayInput<R>], np: usize) -> Rows {
        let mut sdf_at = Vec::with_capacity(rays.len() + 1);
        let mut col_at = Vec::with_capacity(rays.len() + 1);
        let (mut sdf, mut col) = (0, 0);
        for ray in rays {
            let n = ray.depths.len() - 1;
            sdf_at.push(sdf);
            col_at.push(col);
            sdf += (np + 1) * n + 1;
            col += n;
        }
        Rows { sdf_at, col_at, sdf, col }
    }
}

/// The SDF network's shape and the normals' numerics of one call.
struct Dims {
    /// SDF outputs per row (1 + features).
    n_out: usize,
    /// Geometry features per row.
    f: usize,
    /// Colour-network inputs per row.
    c_in: usize,
    /// Probe offsets and weights (none for analytic normals).
    probes: &'static [([f64; 3], f64)],
    /// The probes' step h.
    h: f64,
}

/// What the forward pass of a work item leaves for the loss and the backward pass. Fields drop
/// in the order declared, and the scratch pool hands out its buffers by what came back last:
/// the largest buffers go back last, so that the next work item's largest requests find them.
struct Forward<R: Real> {
    background: Option<BackgroundPass<R>>,
    color_ctx: Buf<R>,
    colors: Buf<R>,
    color_in: Buf<R>,
    normals: Vec<[R; 3]>,
    /// The analytic gradients, read through `normals`; kept for their place in the drop order.
    _gradients: Option<Buf<R>>,
    sdf_ctx: Buf<R>,
    sdf_out: Buf<R>,
    points: Buf<R>,
}

/// The adjoints the per-ray loop gathers for one backward pass per network (dropped in the
/// order declared, as [`Forward`]).
struct Adjoints<R: Real> {
    background: Vec<[R; 3]>,
    laplacian: Buf<R>,
    normals: Vec<[R; 3]>,
    sdf_direct: Buf<R>,
    colors: Buf<R>,
    variance: R,
}

impl<R: Real> Adjoints<R> {
    /// Zeros, or nothing at all without a backward pass.
    fn new(backward: bool, rows: &Rows, rays: usize) -> Adjoints<R> {
        let size = |n: usize| if backward { n } else { 0 };
        Adjoints {
            colors: Buf::zeroed(size(rows.col * 3)),
            sdf_direct: Buf::zeroed(size(rows.sdf)),
            normals: vec![[R::ZERO; 3]; size(rows.col)],
            laplacian: Buf::zeroed(size(rows.col)),
            background: vec![[R::ZERO; 3]; size(rays)],
            variance: R::ZERO,
        }
    }
}

/// The batch-wide scalars of a work item's loss.
#[derive(Clone, Copy)]
struct Scale<R> {
    /// The logistic scale s.
    s: R,
    /// The whole batch's ray count.
    m: R,
    /// The colour loss's normaliser.
    color_norm: R,
    /// Whether gradients are wanted.
    backward: bool,
}

/// What the SDF network's forward pass keeps for analytic normals.
#[derive(Clone, Copy, PartialEq)]
pub(super) enum Tangents {
    /// The context its tangent passes read (a training step: the normal and the loss's
    /// backward both read a hash grid's Jacobian, §46).
    Kept,
    /// The forward's own (a render: one reverse pass for the normal finds the corners again).
    Found,
}

/// The SDF network's forward pass at `points` (its outputs into `out`): its context, and with
/// analytic normals (`fns`) ∇ₓS ([`sdf_gradients`]), the context as `tangents` says.
pub(super) fn sdf_forward<S: Module<R>, R: Real>(
    fns: Option<(&TangentFns<S, R>, Tangents)>,
    sdf: &S,
    p_sdf: &[R],
    points: &[R],
    out: &mut [R],
) -> (Buf<R>, Option<Buf<R>>) {
    let rows = points.len() / 3;
    match fns {
        Some((fns, Tangents::Kept)) => {
            let mut ctx = Buf::<R>::to_overwrite(rows * (fns.ctx_per_row)(sdf));
            (fns.forward)(sdf, p_sdf, points, out, &mut ctx);
            let gradients = sdf_gradients(fns.input_gradient, sdf, p_sdf, points, &ctx);
            (ctx, Some(gradients))
        }
        // The plain forward; with analytic normals found from its context.
        found => {
            let mut ctx = Buf::<R>::to_overwrite(rows * sdf.ctx_per_row());
            sdf.forward(p_sdf, points, out, &mut ctx);
            let gradients = found.map(|(fns, _)| sdf_gradients(fns.input_gradient_of_forward, sdf, p_sdf, points, &ctx));
            (ctx, gradients)
        }
    }
}

/// ∇ₓS at every row of `points` (rows × 3) by one reverse pass of the SDF network from its first
/// output, from the forward's `ctx` ([`crate::module::TangentModule::input_gradient`]): a third
/// of the work of three forward tangents through every layer and every output, and all that a
/// normal needs — the loss's reverse pass takes its own tangent along ∂L/∂n (§45).
fn sdf_gradients<S: Module<R>, R: Real>(input_gradient: InputGradientFn<S, R>, sdf: &S, p_sdf: &[R], points: &[R], ctx: &[R]) -> Buf<R> {
    let (rows, n_out) = (points.len() / 3, sdf.n_outputs());
    let mut d_sdf = Buf::<R>::zeroed(rows * n_out);
    for row in d_sdf.chunks_exact_mut(n_out) {
        row[0] = R::ONE;
    }
    let mut gradients = Buf::<R>::to_overwrite(rows * 3);
    input_gradient(sdf, p_sdf, points, ctx, &d_sdf, &mut gradients);
    gradients
}

/// A normal by differences: `Σⱼ vⱼ wⱼ S(x + h vⱼ) / h` over the probes (offset v, weight w),
/// `value(j)` the SDF at probe j.
pub(super) fn probe_normal<R: Real>(probes: &[([f64; 3], f64)], h: R, value: impl Fn(usize) -> R) -> [R; 3] {
    let mut g = [R::ZERO; 3];
    for (j, (offset, w)) in probes.iter().enumerate() {
        let v = value(j);
        for k in 0..3 {
            g[k] += R::of(offset[k] * w) * v;
        }
    }
    g.map(|v| v / h)
}

/// One colour-network input row: `[x, n, SH₄(d), features]`.
pub(super) fn color_row<R: Real>(row: &mut [R], x: &[R], normal: &[R; 3], sh: &[R; 16], features: &[R]) {
    row[..3].copy_from_slice(x);
    row[3..6].copy_from_slice(normal);
    row[6..COLOR_IN_FIXED].copy_from_slice(sh);
    row[COLOR_IN_FIXED..].copy_from_slice(features);
}

impl<S, C> Pipeline<S, C> {
    /// The loss of `rays` (the batch's rays from index `first`) divided by `m` (the whole batch's
    /// ray count; the colour loss by `color_norm`), gradients added to `d_params`, which covers
    /// every parameter after the SDF network's deferred ones ([`DeferringModule::deferred_params`]);
    /// their gradient is returned as (points, record) for [`DeferringModule::apply_deferred`].
    #[allow(clippy::too_many_arguments)]
    pub(super) fn accumulate<R: Real + TangentPrecision>(
        &self,
        params: &[R],
        rays: &[RayInput<R>],
        first: usize,
        d_params: Option<&mut [R]>,
        m: R,
        color_norm: R,
        extra: &dyn SampleLoss,
    ) -> (R, Vec<RayOutput<R>>, Records<R>)
    where
        S: DeferringModule<R>,
        C: Module<R>,
    {
        let _span = crate::profile::span(crate::profile::Stage::LossPass);
        let (n_sdf, n_col) = (self.sdf.n_params(), self.color.n_params());
        let (p_sdf, rest) = params.split_at(n_sdf);
        let (p_col, p_var) = rest.split_at(n_col);
        let f = self.sdf.n_outputs() - 1;
        let probes = if self.analytic.is_some() { &[] } else { self.config.normals.probes() };
        let dims = Dims { n_out: 1 + f, f, c_in: COLOR_IN_FIXED + f, probes, h: self.config.normal_step };
        let rows = Rows::of(rays, probes.len());
        let (points, sdf_out, sdf_ctx, gradients) = self.sdf_pass(p_sdf, rays, &rows, &dims);
        let mut fwd = self.color_pass(p_col, &p_var[1..], rays, &rows, &dims, points, sdf_out, sdf_ctx, gradients);
        let scale = Scale { s: scale_from_variance(p_var[0]), m, color_norm, backward: d_params.is_some() };
        let mut adj = Adjoints::new(scale.backward, &rows, rays.len());
        let mut total = R::ZERO;
        let mut outputs = Vec::with_capacity(rays.len());
        for (r, ray) in rays.iter().enumerate() {
            let (loss, output) = self.ray_terms(r, ray, first, &rows, &dims, &fwd, scale, extra, &mut adj);
            total += loss / m;
            outputs.push(output);
        }
        let Some(d_params) = d_params else { return (total, outputs, Records::default()) };
        let (d_sdf_params, rest) = d_params.split_at_mut(n_sdf - self.sdf.deferred_params());
        let (d_col_params, d_rest) = rest.split_at_mut(n_col);
        d_rest[0] += adj.variance;
        let (d_color_in, d_sdf_out, background) =
            self.network_adjoints(p_col, &p_var[1..], &mut d_rest[1..], d_col_params, rays, &rows, &dims, &fwd, &adj);
        let sdf = match &self.analytic {
            Some(analytic) => {
                let fns = R::tangent_fns(analytic);
                self.sdf_tangent_backward(fns, p_sdf, rays, &rows, &dims, &fwd, &adj, &d_color_in, &d_sdf_out, d_sdf_params)
            }
            None => self.sdf_backward(p_sdf, &mut fwd, &d_sdf_out, d_sdf_params),
        };
        (total, outputs, Records { sdf, background })
    }

    /// The sample points and probes of every ray through the SDF network: its outputs and
    /// context, and with analytic normals ∇ₓS at every point (rows × 3).
    fn sdf_pass<R: Real + TangentPrecision>(
        &self,
        p_sdf: &[R],
        rays: &[RayInput<R>],
        rows: &Rows,
        dims: &Dims,
    ) -> (Buf<R>, Buf<R>, Buf<R>, Option<Buf<R>>)
    where
        S: Module<R>,
    {
        let h = R::of(dims.h);
        let mut points = Buf::<R>::to_overwrite(3 * rows.sdf);
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
                for (offset, _) in dims.probes {
                    for k in 0..3 {
                        points[at + k] = points[base + 3 * i + k] + R::of(offset[k]) * h;
                    }
                    at += 3;
                }
            }
        }
        let mut sdf_out = Buf::<R>::to_overwrite(rows.sdf * dims.n_out);
        let fns = self.analytic.as_ref().map(|a| (R::tangent_fns(a), Tangents::Kept));
        let (sdf_ctx, gradients) = sdf_forward(fns, &self.sdf, p_sdf, &points, &mut sdf_out);
        (points, sdf_out, sdf_ctx, gradients)
    }

    /// The normal of every interval (analytic, or from the probes), the colour network's inputs
    /// `[x, n, SH(d), features]` and its colours, and the learned background of every ray.
    #[allow(clippy::too_many_arguments)]
    fn color_pass<R: Real>(
        &self,
        p_col: &[R],
        p_bg: &[R],
        rays: &[RayInput<R>],
        rows: &Rows,
        dims: &Dims,
        points: Buf<R>,
        sdf_out: Buf<R>,
        sdf_ctx: Buf<R>,
        gradients: Option<Buf<R>>,
    ) -> Forward<R>
    where
        C: Module<R>,
    {
        let (n_out, c_in, np, h) = (dims.n_out, dims.c_in, dims.probes.len(), R::of(dims.h));
        let mut normals: Vec<[R; 3]> = Vec::with_capacity(rows.col);
        let mut sh: Vec<[R; 16]> = Vec::with_capacity(rays.len());
        let mut color_in = Buf::<R>::to_overwrite(rows.col * c_in);
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (rows.sdf_at[r], rows.col_at[r]);
            let mut sh_d = [R::ZERO; 16];
            SphericalHarmonics.forward(&[], &ray.direction, &mut sh_d, &mut []);
            sh.push(sh_d);
            for i in 0..n {
                let nrm = match gradients.as_deref() {
                    Some(grad) => [0, 1, 2].map(|k| grad[(b + i) * 3 + k]),
                    None => probe_normal(dims.probes, h, |j| sdf_out[(b + n + 1 + np * i + j) * n_out]),
                };
                normals.push(nrm);
                let row = &mut color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                color_row(row, &points[3 * (b + i)..3 * (b + i) + 3], &nrm, &sh_d, &sdf_out[(b + i) * n_out + 1..(b + i + 1) * n_out]);
            }
        }
        let mut colors = Buf::<R>::to_overwrite(rows.col * 3);
        let mut color_ctx = Buf::<R>::to_overwrite(rows.col * self.color.ctx_per_row());
        self.color.forward(p_col, &color_in, &mut colors, &mut color_ctx);
        let background = self.background.as_ref().map(|model| {
            let origins: Vec<[R; 3]> = rays.iter().map(|r| r.origin).collect();
            let directions: Vec<[R; 3]> = rays.iter().map(|r| r.direction).collect();
            model.forward(p_bg, &origins, &directions, &sh)
        });
        Forward { background, color_ctx, colors, color_in, normals, _gradients: gradients, sdf_ctx, sdf_out, points }
    }

    /// Ray `r`: its render, every loss term (colour, curvature, eikonal, normal smoothness,
    /// opacity entropy, mask, the caller's), and with a backward pass the render's backward into
    /// `adj`. Returns the ray's loss (not yet divided by the batch) and its outputs.
    #[allow(clippy::too_many_arguments)]
    fn ray_terms<R: Real>(
        &self,
        r: usize,
        ray: &RayInput<R>,
        first: usize,
        rows: &Rows,
        dims: &Dims,
        fwd: &Forward<R>,
        scale: Scale<R>,
        extra: &dyn SampleLoss,
        adj: &mut Adjoints<R>,
    ) -> (R, RayOutput<R>) {
        let (n_out, np) = (dims.n_out, dims.probes.len());
        let n = ray.depths.len() - 1;
        let (b, c0) = (rows.sdf_at[r], rows.col_at[r]);
        let sdf_values: Vec<R> = (0..=n).map(|i| fwd.sdf_out[(b + i) * n_out]).collect();
        let colors: Vec<[R; 3]> = fwd.colors[3 * c0..3 * (c0 + n)].chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        let nrms = &fwd.normals[c0..c0 + n];
        let r_out = render_ray(&sdf_values, &ray.depths, &colors, scale.s);
        let background = match &fwd.background {
            Some(pass) => pass.colors[r],
            None => self.config.background.map(R::of),
        };
        let composited: [R; 3] = [0, 1, 2].map(|k| r_out.color[k] + (R::ONE - r_out.opacity) * background[k]);
        let (mut loss, d_color, mut d_opacity) = self.color_term(ray, &r_out, composited, background, scale);
        let inv_m = R::ONE / scale.m;
        let probe = |i: usize, j: usize| fwd.sdf_out[(b + n + 1 + np * i + j) * n_out];
        self.curvature_term(&sdf_values, &probe, dims, scale.backward.then(|| &mut adj.laplacian[c0..c0 + n]), inv_m, &mut loss);
        let d_normals = scale.backward.then(|| &mut adj.normals[c0..c0 + n]);
        self.normal_terms(nrms, &sdf_values, d_normals, inv_m, &mut loss);
        let learned = fwd.background.as_ref().map(|pass| pass.colors[r]);
        let guard = self.config.opacity_guard.filter(|g| Self::background_explains(ray, composited, learned, g.tolerance));
        self.opacity_terms(ray, r_out.opacity, guard.map_or(0.0, |g| g.weight), &mut loss, &mut d_opacity);
        // The caller's loss on the samples (f64).
        let t64: Vec<f64> = ray.depths.iter().map(|v| v.to_f64()).collect();
        let sdf64: Vec<f64> = sdf_values.iter().map(|v| v.to_f64()).collect();
        let w64: Vec<f64> = r_out.weights.iter().map(|v| v.to_f64()).collect();
        let mut d_sdf_extra = vec![0.0f64; n + 1];
        let mut d_w_extra = vec![0.0f64; n];
        loss += R::of(extra.ray_loss(first + r, scale.s.to_f64(), &t64, &sdf64, &w64, &mut d_sdf_extra, &mut d_w_extra));
        let mut normal = [R::ZERO; 3];
        for i in 0..n {
            for k in 0..3 {
                normal[k] += r_out.weights[i] * nrms[i][k];
            }
        }
        let output = RayOutput { color: composited, opacity: r_out.opacity, depth: r_out.depth, normal };
        if scale.backward {
            let d_w: Vec<R> = d_w_extra.iter().map(|&v| R::of(v) * inv_m).collect();
            let g = render_ray_backward(
                &sdf_values,
                &ray.depths,
                &colors,
                scale.s,
                &r_out,
                d_color.map(|d| d * inv_m),
                R::ZERO,
                d_opacity * inv_m,
                Some(&d_w),
            );
            adj.variance += g.s * scale_derivative(scale.s);
            if !self.config.masked_color {
                for k in 0..3 {
                    adj.background[r][k] = d_color[k] * (R::ONE - r_out.opacity) * inv_m;
                }
            }
            for (i, c) in g.colors.iter().enumerate() {
                adj.colors[3 * (c0 + i)..3 * (c0 + i) + 3].copy_from_slice(c);
            }
            for i in 0..=n {
                adj.sdf_direct[b + i] = g.sdf[i] + R::of(d_sdf_extra[i]) * inv_m;
            }
        }
        (loss, output)
    }

    /// The background's and the colour network's backward passes, and the adjoints of the SDF
    /// network's outputs at every point: the render's, the features' (through the colour
    /// network), and the probes' (through the normals and the curvature). Returns the colour
    /// network's input adjoints, the SDF outputs' adjoints, and the record of the background
    /// grid's tables when `d_bg_params` stops before them (their gradient is then added later,
    /// [`crate::BackgroundModel::add_deferred`]).
    #[allow(clippy::too_many_arguments)]
    fn network_adjoints<R: Real>(
        &self,
        p_col: &[R],
        p_bg: &[R],
        d_bg_params: &mut [R],
        d_col_params: &mut [R],
        rays: &[RayInput<R>],
        rows: &Rows,
        dims: &Dims,
        fwd: &Forward<R>,
        adj: &Adjoints<R>,
    ) -> (Buf<R>, Buf<R>, Deferred<R>)
    where
        C: Module<R>,
    {
        let mut background = None;
        if let (Some(model), Some(pass)) = (&self.background, &fwd.background) {
            if d_bg_params.len() == model.n_params() {
                model.backward(p_bg, pass, &adj.background, d_bg_params);
            } else {
                debug_assert_eq!(d_bg_params.len(), model.tables().start, "the background's gradient: whole, or without its tables");
                background = model.backward_deferring(p_bg, pass, &adj.background, d_bg_params);
            }
        }
        let (n_out, c_in, np, h) = (dims.n_out, dims.c_in, dims.probes.len(), R::of(dims.h));
        let mut d_color_in = Buf::<R>::zeroed(rows.col * c_in);
        self.color.backward(p_col, &fwd.color_in, &fwd.color_ctx, &adj.colors, d_col_params, Some(&mut d_color_in));
        let mut d_sdf_out = Buf::<R>::zeroed(rows.sdf * n_out);
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (rows.sdf_at[r], rows.col_at[r]);
            for i in 0..=n {
                d_sdf_out[(b + i) * n_out] = adj.sdf_direct[b + i];
            }
            for i in 0..n {
                let row = &d_color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                for j in 0..dims.f {
                    d_sdf_out[(b + i) * n_out + 1 + j] += row[COLOR_IN_FIXED + j];
                }
                let d_lap = adj.laplacian[c0 + i];
                for (j, (offset, w)) in dims.probes.iter().enumerate() {
                    let mut d = R::ZERO;
                    for k in 0..3 {
                        d += (row[3 + k] + adj.normals[c0 + i][k]) * R::of(offset[k] * w);
                    }
                    d_sdf_out[(b + n + 1 + np * i + j) * n_out] += d / h + d_lap;
                }
                d_sdf_out[(b + i) * n_out] -= R::of(np as f64) * d_lap;
            }
        }
        (d_color_in, d_sdf_out, background)
    }

    /// The SDF network's backward pass (numerical normals: the probes are rows like the
    /// samples); a deferring network's record of its deferred gradient.
    fn sdf_backward<R: Real>(&self, p_sdf: &[R], fwd: &mut Forward<R>, d_sdf_out: &[R], d_sdf_params: &mut [R]) -> Deferred<R>
    where
        S: DeferringModule<R>,
    {
        if self.sdf.deferred_params() == 0 {
            self.sdf.backward(p_sdf, &fwd.points, &fwd.sdf_ctx, d_sdf_out, d_sdf_params, None);
            return None;
        }
        let mut record = Buf::<R>::zeroed(fwd.points.len() / 3 * self.sdf.deferred_width());
        self.sdf.backward_deferring(p_sdf, &fwd.points, &fwd.sdf_ctx, d_sdf_out, d_sdf_params, &mut record);
        // The record's input: the points themselves.
        Some((fwd.points.take(), record))
    }

    /// The SDF network's backward pass with analytic normals. L depends on nᵢ = ∇ₓS(xᵢ) through
    /// vᵢ = ∂L/∂nᵢ, and vᵢ·δnᵢ = δ(∂S/∂x · vᵢ): the derivative of S along vᵢ, with adjoint 1,
    /// whatever vᵢ's length — one tangent per point, reversed with the values.
    #[allow(clippy::too_many_arguments)]
    fn sdf_tangent_backward<R: Real>(
        &self,
        fns: &TangentFns<S, R>,
        p_sdf: &[R],
        rays: &[RayInput<R>],
        rows: &Rows,
        dims: &Dims,
        fwd: &Forward<R>,
        adj: &Adjoints<R>,
        d_color_in: &[R],
        d_sdf_out: &[R],
        d_sdf_params: &mut [R],
    ) -> Deferred<R>
    where
        S: DeferringModule<R>,
    {
        let (n_out, c_in) = (dims.n_out, dims.c_in);
        let mut v = Buf::<R>::zeroed(3 * rows.sdf);
        let mut d_tangent_out = Buf::<R>::zeroed(rows.sdf * n_out);
        for (r, ray) in rays.iter().enumerate() {
            let n = ray.depths.len() - 1;
            let (b, c0) = (rows.sdf_at[r], rows.col_at[r]);
            for i in 0..n {
                let row = &d_color_in[(c0 + i) * c_in..(c0 + i + 1) * c_in];
                for k in 0..3 {
                    v[3 * (b + i) + k] = row[3 + k] + adj.normals[c0 + i][k];
                }
                d_tangent_out[(b + i) * n_out] = R::ONE;
            }
        }
        let pass = |tangent_in, d_tangent_out| TangentAdjoints {
            params: p_sdf,
            input: &fwd.points,
            ctx: &fwd.sdf_ctx,
            tangent_in,
            d_output: d_sdf_out,
            d_tangent_out,
        };
        if self.sdf.deferred_params() == 0 {
            (fns.backward)(&self.sdf, pass(&v, &d_tangent_out), d_sdf_params);
            return None;
        }
        let mut record = Buf::<R>::zeroed(2 * rows.sdf * self.sdf.deferred_width());
        (fns.backward_deferring)(&self.sdf, pass(&v, &d_tangent_out), d_sdf_params, &mut record);
        // The record's input: the points, then their tangents.
        let mut points_and_tangents = Buf::<R>::zeroed(6 * rows.sdf);
        points_and_tangents[..3 * rows.sdf].copy_from_slice(&fwd.points);
        points_and_tangents[3 * rows.sdf..].copy_from_slice(&v);
        Some((points_and_tangents, record))
    }
}
