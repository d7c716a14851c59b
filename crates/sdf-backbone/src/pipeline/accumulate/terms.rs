//! The loss terms of one ray (a work item's [`Pipeline::ray_terms`] calls them in this order):
//! colour, curvature, eikonal and normal smoothness, the terms on the opacity. Each adds to the
//! ray's loss and writes its adjoints (already divided by the batch where they are per sample).

use super::super::{ColorLoss, Pipeline, RayInput, SmoothnessRegion};
use super::{Dims, Scale};
use crate::real::Real;
use crate::render::RayRender;

impl<S, C> Pipeline<S, C> {
    /// The colour loss of a ray: on the composited colour, or (masked) on the rendered colour of
    /// foreground rays only, normalised by their count instead of the batch's. Returns the loss,
    /// its adjoint of the compared colour and of the opacity (through the background).
    pub(super) fn color_term<R: Real>(
        &self,
        ray: &RayInput<R>,
        r_out: &RayRender<R>,
        composited: [R; 3],
        background: [R; 3],
        scale: Scale<R>,
    ) -> (R, [R; 3], R) {
        let masked = self.config.masked_color;
        let color_weight = ray.weight
            * if !masked {
                R::ONE
            } else if ray.mask.is_none_or(|mk| mk >= R::of(0.5)) {
                scale.m / scale.color_norm
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
                    d_color[k] = color_weight * sign(e);
                }
                ColorLoss::L2 => {
                    loss += color_weight * e * e;
                    d_color[k] = color_weight * (e + e);
                }
            }
        }
        let d_opacity = if masked { R::ZERO } else { -(d_color[0] * background[0] + d_color[1] * background[1] + d_color[2] * background[2]) };
        (loss, d_color, d_opacity)
    }

    /// Curvature: mean |ΔS| over a ray's samples, the Laplacian from the probes; its adjoint per
    /// sample into `d_laplacian` (already divided by the batch).
    pub(super) fn curvature_term<R: Real>(
        &self,
        sdf: &[R],
        probe: &dyn Fn(usize, usize) -> R,
        dims: &Dims,
        d_laplacian: Option<&mut [R]>,
        inv_m: R,
        loss: &mut R,
    ) {
        let (n, np, h) = (sdf.len() - 1, dims.probes.len(), R::of(dims.h));
        if !(self.config.curvature_weight > 0.0 && np > 0) {
            return;
        }
        let curv_w = R::of(self.config.curvature_weight) / R::of(n as f64);
        let c_probe: f64 = dims.probes.iter().map(|(o, _)| o[0] * o[0]).sum();
        let lap_den = h * h * R::of(c_probe * 0.5);
        let mut d_laplacian = d_laplacian;
        for i in 0..n {
            let mut lap = -R::of(np as f64) * sdf[i];
            for j in 0..np {
                lap += probe(i, j);
            }
            lap = lap / lap_den;
            *loss += curv_w * lap.abs();
            if let Some(d) = d_laplacian.as_deref_mut() {
                d[i] = sign(lap) * curv_w / lap_den * inv_m;
            }
        }
    }

    /// The eikonal term `mean (|nᵢ| − 1)²` and the normal smoothness `mean |nᵢ₊₁ − nᵢ|²` of a ray
    /// (over the pairs its region takes, by the samples' SDF `sdf`; the mean's count is every
    /// pair's); their adjoints of the normals into `d_normals` (already divided by the batch).
    pub(super) fn normal_terms<R: Real>(&self, nrms: &[[R; 3]], sdf: &[R], d_normals: Option<&mut [[R; 3]]>, inv_m: R, loss: &mut R) {
        let n = nrms.len();
        let mut d_normals = d_normals;
        let eik_w = R::of(self.config.eikonal_weight) / R::of(n as f64);
        for i in 0..n {
            let nv = nrms[i];
            let len = (nv[0] * nv[0] + nv[1] * nv[1] + nv[2] * nv[2]).sqrt();
            let e = len - R::ONE;
            *loss += eik_w * e * e;
            if let Some(d) = d_normals.as_deref_mut().filter(|_| len > R::ZERO) {
                for k in 0..3 {
                    d[i][k] = eik_w * (e + e) * nv[k] / len * inv_m;
                }
            }
        }
        if self.config.normal_smoothness > 0.0 && n > 1 {
            let w = R::of(self.config.normal_smoothness) / R::of((n - 1) as f64);
            let floor = match self.config.normal_smoothness_region {
                SmoothnessRegion::Everywhere => None,
                SmoothnessRegion::Outside { depth } => Some(-R::of(depth)),
            };
            for i in (0..n - 1).filter(|&i| floor.is_none_or(|floor| sdf[i] > floor || sdf[i + 1] > floor)) {
                let change = [0, 1, 2].map(|k| nrms[i + 1][k] - nrms[i][k]);
                *loss += w * (change[0] * change[0] + change[1] * change[1] + change[2] * change[2]);
                if let Some(d_normals) = d_normals.as_deref_mut() {
                    for k in 0..3 {
                        let d = w * (change[k] + change[k]) * inv_m;
                        d_normals[i + 1][k] += d;
                        d_normals[i][k] -= d;
                    }
                }
            }
        }
    }

    /// The terms on a ray's opacity: the entropy and the L1 of rays without a mask — the L1's
    /// weight the sparsity's plus `guard`, the guard's weight where it applies to this ray
    /// ([`Self::background_explains`]; 0 where not) —, the mask's BCE (entropy and BCE with the
    /// opacity clamped away from 0 and 1, as NeuS clips to [1e-3, 1 − 1e-3]).
    pub(super) fn opacity_terms<R: Real>(&self, ray: &RayInput<R>, opacity: R, guard: f64, loss: &mut R, d_opacity: &mut R) {
        let eps = R::of(1e-3);
        let o = opacity.max(eps).min(R::ONE - eps);
        let inside = opacity > eps && opacity < R::ONE - eps;
        if ray.mask.is_none() && self.config.opacity_entropy > 0.0 {
            let w = R::of(self.config.opacity_entropy) * ray.weight;
            *loss += -w * (o * o.ln() + (R::ONE - o) * (R::ONE - o).ln());
            if inside {
                *d_opacity += w * ((R::ONE - o) / o).ln();
            }
        }
        let l1 = self.config.opacity_sparsity + guard;
        if ray.mask.is_none() && l1 > 0.0 {
            let w = R::of(l1) * ray.weight;
            *loss += w * opacity;
            *d_opacity += w;
        }
        if let Some(mask) = ray.mask {
            let w = R::of(self.config.mask_weight) * ray.weight;
            *loss += -w * (mask * o.ln() + (R::ONE - mask) * (R::ONE - o).ln());
            if inside {
                *d_opacity += -w * (mask / o - (R::ONE - mask) / (R::ONE - o));
            }
        }
    }
}

impl<S, C> Pipeline<S, C> {
    /// Whether a ray's learned background alone (`background`, `None` without one) paints its
    /// pixel: at least as close to the target as the composite, by squared error, and within
    /// `tolerance` (RMS per channel) of it where one is given — the foreground adds nothing there
    /// that the background does not paint. A constant of the step for the guard.
    pub(super) fn background_explains<R: Real>(ray: &RayInput<R>, composited: [R; 3], background: Option<[R; 3]>, tolerance: Option<f64>) -> bool {
        background.is_some_and(|b| {
            let err = |c: [R; 3]| (0..3).fold(R::ZERO, |acc, k| acc + (c[k] - ray.target[k]) * (c[k] - ray.target[k]));
            let own = err(b);
            tolerance.is_none_or(|t| own <= R::of(3.0 * t * t)) && own <= err(composited)
        })
    }
}

/// −1, 0 or 1 by the sign of `x`.
fn sign<R: Real>(x: R) -> R {
    if x > R::ZERO {
        R::ONE
    } else if x < R::ZERO {
        -R::ONE
    } else {
        R::ZERO
    }
}
