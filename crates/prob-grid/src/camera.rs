//! Reprojection of the scene's mass into each camera's 3D image space, and view dependency.
//!
//! A camera grid spans the camera's pixel space: u, v over the image (corner to corner, R_u × R_v
//! cells) and depth λ over [`camera_geom::ImageSpaceBounds::depth`] (R_λ cells). Each active
//! sub-cell centre is projected with `f` and its mass added to the cell it lands in (the paper's
//! Riemann sum, supp. C.2).
//!
//! **Weighting (docs/DECISIONS.md §1).** The change of variables gives `p_U = p_X·λ²` for densities, so *mass*
//! is invariant. The paper sums `η⁻²·p` instead ([`Weighting::InverseSquareDepth`], default, as
//! printed): that is proportional to the average *world density* in the U-cell (depth-neutral).
//! [`Weighting::MassPreserving`] sums the masses: the U-cell's true probability, which favours far
//! pixels (a far pixel's frustum holds more world volume).
//!
//! **View dependency (Sec. 4.3; docs/DECISIONS.md §3).** Along each (u, v) column, sorted by depth, with
//! `σ̄_i` the average world density (NeuS's naive σ = φ_s(S), 1/length) of cell i and `δ_i` the
//! ray length through it:
//! - [`ViewDependency::Quadrature`] (default): `p̃_i = p_i · T_i · (1 − e^{−τ_i})/τ_i` with
//!   `τ_i = σ̄_i δ_i`, `T_i = exp(−Σ_{k<i} τ_k)`: p times the exact average transmittance inside
//!   the cell for piecewise-constant σ. A surface crossed head-on has optical depth 1, so the
//!   mass behind it is weighted by e⁻¹ (occlusion-aware, but weakly, as the paper says).
//! - [`ViewDependency::Opaque`]: NeuS's unbiased density `ρ = φ_s/Φ_s` instead of σ; for a
//!   crossing, `∫ρ = −ln(1 − τ)`, so the transmittance is `max(0, 1 − τ_cum)`: a surface crossed
//!   head-on occludes fully.
//! - [`ViewDependency::PaperSum`]: the equation as printed, `p̃_i = p_i · exp(−Σ_{k=0}^{i} p_k)`
//!   with the grid values p as they are (no δ): its strength depends on the grid's units and
//!   resolution.
//! - [`ViewDependency::Off`]: ablation A3.

use crate::scene::ActiveCells;
use camera_geom::{DepthBounds, ImageSpaceBounds, PinholeCamera};
use glam::{DVec3, Mat3, Vec3};
use wide::f32x8;

/// How a projected sub-cell's mass is weighted (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Weighting {
    /// The paper: mass · λ⁻² (∝ average world density of the U-cell).
    #[default]
    InverseSquareDepth,
    /// The exact probability of the U-cell: the sum of masses.
    MassPreserving,
}

/// View dependency along λ (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ViewDependency {
    /// No occlusion (ablation A3).
    Off,
    /// The paper's equation as printed (no cell length, sum includes the current cell).
    #[serde(rename = "paper")]
    PaperSum,
    /// Naive NeuS density with exact piecewise-constant quadrature.
    Quadrature,
    /// NeuS's unbiased (opaque) density: transmittance `max(0, 1 − τ)`. Default.
    #[default]
    Opaque,
}

/// Camera grid configuration. Defaults: 64 × 64 × 128, central-ray depth bounds against the unit
/// sphere, minimum depth 1e-3, the paper's weighting, opaque view dependency. In a
/// configuration file every key is optional and unknown keys are errors.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraGridConfig {
    /// Cells along u (the paper: 64).
    pub ru: usize,
    /// Cells along v (the paper: 64).
    pub rv: usize,
    /// Cells along λ (the paper: 128).
    pub rl: usize,
    /// Depth range rule.
    pub depth_bounds: DepthBounds,
    /// Centre of the bound sphere used for depth bounds.
    pub bound_center: DVec3,
    /// Radius of the bound sphere used for depth bounds.
    pub bound_radius: f64,
    /// Smallest depth (cameras inside the bound).
    pub min_depth: f64,
    /// Mass weighting.
    pub weighting: Weighting,
    /// View dependency.
    pub view_dependency: ViewDependency,
}

impl Default for CameraGridConfig {
    fn default() -> Self {
        CameraGridConfig {
            ru: 64,
            rv: 64,
            rl: 128,
            depth_bounds: DepthBounds::CentralRay,
            bound_center: DVec3::ZERO,
            bound_radius: 1.0,
            min_depth: 1e-3,
            weighting: Weighting::InverseSquareDepth,
            view_dependency: ViewDependency::Opaque,
        }
    }
}

impl CameraGridConfig {
    /// Checks every value; the message names the option.
    pub fn validate(&self) -> Result<(), crate::GridError> {
        let bad = |what, message: String| Err(crate::GridError::InvalidConfig { what, message });
        for (what, r) in [("camera grid R_u", self.ru), ("camera grid R_v", self.rv), ("camera grid R_λ", self.rl)] {
            if r == 0 || r > 4096 {
                return bad(what, format!("{r} (1..=4096)"));
            }
        }
        if (self.ru * self.rv * self.rl) > (1 << 28) {
            return bad("camera grid size", format!("{}×{}×{} cells is too many", self.ru, self.rv, self.rl));
        }
        if !(self.bound_radius.is_finite() && self.bound_radius > 0.0 && self.bound_center.is_finite()) {
            return bad("bound sphere", format!("centre {}, radius {}", self.bound_center, self.bound_radius));
        }
        if !(self.min_depth.is_finite() && self.min_depth > 0.0) {
            return bad("minimum depth", format!("{}", self.min_depth));
        }
        Ok(())
    }
}

/// One camera's view-dependent probability grid p̃(u, v, λ) (unnormalised, ≥ 0, finite).
/// Layout: `values[(iu · rv + iv) · rl + il]`, so each (u, v) column is contiguous in λ.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraGrid {
    /// The camera.
    pub camera: PinholeCamera,
    /// The pixel-space bounds the grid spans.
    pub bounds: ImageSpaceBounds,
    /// Cells along u.
    pub ru: usize,
    /// Cells along v.
    pub rv: usize,
    /// Cells along λ.
    pub rl: usize,
    /// p̃ per cell.
    pub values: Vec<f32>,
    /// Mass that projected outside the grid (behind the camera, outside the image or depth range).
    pub mass_outside: f64,
}

impl CameraGrid {
    /// A grid of zeros for `camera` with `config`'s resolution and bounds.
    pub fn empty(camera: &PinholeCamera, config: &CameraGridConfig) -> CameraGrid {
        let bounds = camera.image_space_bounds(config.bound_center, config.bound_radius, config.depth_bounds, config.min_depth);
        let (ru, rv, rl) = (config.ru, config.rv, config.rl);
        CameraGrid { camera: *camera, bounds, ru, rv, rl, values: vec![0.0; ru * rv * rl], mass_outside: 0.0 }
    }

    /// Index of cell (iu, iv, il).
    pub fn index(&self, iu: usize, iv: usize, il: usize) -> usize {
        (iu * self.rv + iv) * self.rl + il
    }

    /// Cell sizes (Δu, Δv in pixels, Δλ).
    pub fn cell_sizes(&self) -> (f64, f64, f64) {
        let b = &self.bounds;
        ((b.u[1] - b.u[0]) / self.ru as f64, (b.v[1] - b.v[0]) / self.rv as f64, (b.depth[1] - b.depth[0]) / self.rl as f64)
    }

    /// Σ p̃ over the grid.
    pub fn total(&self) -> f64 {
        self.values.iter().map(|v| *v as f64).sum()
    }

    /// The pixel marginal Σ_λ p̃, R_u × R_v, row-major in v (`[iv · ru + iu]`), for pictures.
    pub fn pixel_marginal(&self) -> Vec<f32> {
        let mut out = vec![0.0; self.ru * self.rv];
        for iu in 0..self.ru {
            for iv in 0..self.rv {
                let col = &self.values[self.index(iu, iv, 0)..self.index(iu, iv, 0) + self.rl];
                out[iv * self.ru + iu] = col.iter().sum();
            }
        }
        out
    }
}

/// Projects the active cells into `camera`'s 3D image space and applies view dependency.
pub fn reproject(active: &ActiveCells, camera: &PinholeCamera, config: &CameraGridConfig) -> CameraGrid {
    let mut grid = CameraGrid::empty(camera, config);
    let bounds = grid.bounds;
    let (ru, rv, rl) = (config.ru, config.rv, config.rl);
    let (du, dv, dl) = grid.cell_sizes();

    // f32 projection: R, t, K as f32; offsets relative to the grid origin.
    let r64 = camera.camera_from_world.rotation;
    let rotation = Mat3::from_cols(r64.col(0).as_vec3(), r64.col(1).as_vec3(), r64.col(2).as_vec3());
    let translation: Vec3 = camera.camera_from_world.translation.as_vec3();
    let k = camera.intrinsics;
    let (fx, fy, skew) = (k.fx as f32, k.fy as f32, k.skew as f32);
    // Fold cx, cy and the grid origin together: fu = (u − u0)/Δu.
    let (u0, v0, l0) = ((bounds.u[0] - k.cx) as f32, (bounds.v[0] - k.cy) as f32, bounds.depth[0] as f32);
    let (inv_du, inv_dv, inv_dl) = ((1.0 / du) as f32, (1.0 / dv) as f32, (1.0 / dl) as f32);
    let (fru, frv, frl) = (ru as f32, rv as f32, rl as f32);
    let inverse_square = config.weighting == Weighting::InverseSquareDepth;
    // Sub-cell offsets in camera axes, once per camera, in lanes of 8 (F = 2 fills one exactly);
    // padding lanes are masked out.
    let offsets: Vec<Vec3> = active.offsets.iter().map(|o| rotation * *o).collect();
    let share = 1.0 / offsets.len().max(1) as f32;
    let lanes: Vec<(f32x8, f32x8, f32x8, f32x8)> = offsets
        .chunks(8)
        .map(|c| {
            let pick = |f: fn(&Vec3) -> f32| f32x8::from(std::array::from_fn::<f32, 8, _>(|l| c.get(l).map_or(0.0, f)));
            let valid = f32x8::from(std::array::from_fn::<f32, 8, _>(|l| if l < c.len() { 1.0 } else { 0.0 }));
            (pick(|o| o.x), pick(|o| o.y), pick(|o| o.z), valid)
        })
        .collect();
    // Lanes outside the grid scatter zero into a spare cell at index `cells`: no branches.
    let cells = ru * rv * rl;
    grid.values.push(0.0);
    let zero = f32x8::ZERO;
    let (sfx, sfy, sskew) = (f32x8::splat(fx), f32x8::splat(fy), f32x8::splat(skew));
    let (su0, sv0, sl0) = (f32x8::splat(u0), f32x8::splat(v0), f32x8::splat(l0));
    let (sdu, sdv, sdl) = (f32x8::splat(inv_du), f32x8::splat(inv_dv), f32x8::splat(inv_dl));
    let (sru, srv, srl) = (f32x8::splat(fru), f32x8::splat(frv), f32x8::splat(frl));
    let mut inside = 0.0f64;
    if offsets.len() < 8 {
        // F = 1 (one offset): lanes would be mostly padding; the scalar loop is faster.
        for (p, &mass) in active.points.iter().zip(&active.masses) {
            let center = rotation * *p + translation;
            let m = mass * share;
            for o in &offsets {
                let x = center + *o;
                let inv_z = 1.0 / x.z;
                let fu = ((fx * x.x + skew * x.y) * inv_z - u0) * inv_du;
                let fv = (fy * x.y * inv_z - v0) * inv_dv;
                let fl = (x.z - l0) * inv_dl;
                // x.z ≤ 0 (behind the camera) gives fl < 0; NaN fails every comparison.
                if fu >= 0.0 && fu < fru && fv >= 0.0 && fv < frv && fl >= 0.0 && fl < frl {
                    let idx = ((fu as usize) * rv + fv as usize) * rl + fl as usize;
                    grid.values[idx] += if inverse_square { m * inv_z * inv_z } else { m };
                    inside += m as f64;
                }
            }
        }
    } else {
        for (p, &mass) in active.points.iter().zip(&active.masses) {
            let center = rotation * *p + translation;
            let m = f32x8::splat(mass * share);
            let (cx, cy, cz) = (f32x8::splat(center.x), f32x8::splat(center.y), f32x8::splat(center.z));
            for &(ox, oy, oz, valid) in &lanes {
                let (x, y, z) = (cx + ox, cy + oy, cz + oz);
                let inv_z = f32x8::ONE / z;
                let fu = ((sfx * x + sskew * y) * inv_z - su0) * sdu;
                let fv = (sfy * y * inv_z - sv0) * sdv;
                let fl = (z - sl0) * sdl;
                // NaN fails every comparison; z ≤ 0 (behind the camera) gives fl < 0.
                let ok = fu.simd_ge(zero)
                    & fu.simd_lt(sru)
                    & fv.simd_ge(zero)
                    & fv.simd_lt(srv)
                    & fl.simd_ge(zero)
                    & fl.simd_lt(srl)
                    & valid.simd_gt(zero);
                // Per-axis cell coordinates as integers (exact: each < 4096), combined in usize
                // so that grids of any size index correctly (a flat index in f32 is exact only
                // below 2²⁴ cells). Truncation is floor for the lanes kept; the others go to the
                // spare cell.
                let (iu, iv, il) = (
                    ok.bitselect(fu, zero).fast_trunc_int().to_array(),
                    ok.bitselect(fv, zero).fast_trunc_int().to_array(),
                    ok.bitselect(fl, zero).fast_trunc_int().to_array(),
                );
                let kept = ok.to_bitmask();
                let w = if inverse_square { m * inv_z * inv_z } else { m };
                let weight = ok.bitselect(w, zero).to_array();
                for l in 0..8 {
                    let index = if kept & (1 << l) != 0 { (iu[l] as usize * rv + iv[l] as usize) * rl + il[l] as usize } else { cells };
                    grid.values[index] += weight[l];
                }
                inside += ok.bitselect(m, zero).reduce_add() as f64;
            }
        }
    }
    grid.values.truncate(cells);
    let outside = (active.total_mass - inside).max(0.0);
    grid.mass_outside = outside;
    apply_view_dependency(&mut grid, config);
    grid
}

/// Applies view dependency to every (u, v) column of a grid holding p (see the module docs).
pub fn apply_view_dependency(grid: &mut CameraGrid, config: &CameraGridConfig) {
    if config.view_dependency == ViewDependency::Off {
        return;
    }
    let (du, dv, dl) = grid.cell_sizes();
    let k = grid.camera.intrinsics;
    let (ru, rv, rl) = (grid.ru, grid.rv, grid.rl);
    let l0 = grid.bounds.depth[0];
    for iu in 0..ru {
        for iv in 0..rv {
            let start = (iu * rv + iv) * rl;
            let column = &mut grid.values[start..start + rl];
            if column.iter().all(|v| *v == 0.0) {
                continue;
            }
            // Ray length per unit depth through this column's centre.
            let u = grid.bounds.u[0] + (iu as f64 + 0.5) * du;
            let v = grid.bounds.v[0] + (iv as f64 + 0.5) * dv;
            let n = k.normalized_from_pixel(glam::DVec2::new(u, v));
            let length_per_depth = (1.0 + n.x * n.x + n.y * n.y).sqrt();
            // σ̄ = value · to_density (· λ⁻² for masses): the U-cell's average world density.
            let to_density = k.fx * k.fy / (du * dv * dl);
            let mut tau_before = 0.0f64;
            for (il, value) in column.iter_mut().enumerate() {
                let p = *value as f64;
                let weight = match config.view_dependency {
                    ViewDependency::Off => 1.0,
                    ViewDependency::PaperSum => {
                        tau_before += p;
                        (-tau_before).exp()
                    }
                    ViewDependency::Quadrature | ViewDependency::Opaque => {
                        let depth = l0 + (il as f64 + 0.5) * dl;
                        let sigma = match config.weighting {
                            Weighting::InverseSquareDepth => p * to_density,
                            Weighting::MassPreserving => p * to_density / (depth * depth),
                        };
                        let tau = sigma * dl * length_per_depth;
                        let w = if config.view_dependency == ViewDependency::Quadrature {
                            // T_i · (1 − e^{−τ})/τ, with the ratio → 1 as τ → 0.
                            let ratio = if tau > 1e-12 { -(-tau).exp_m1() / tau } else { 1.0 };
                            (-tau_before).exp() * ratio
                        } else {
                            // Average of max(0, 1 − τ_before − x) over x ∈ [0, τ].
                            let a = 1.0 - tau_before;
                            if a <= 0.0 {
                                0.0
                            } else if tau <= a {
                                a - 0.5 * tau
                            } else {
                                a * a / (2.0 * tau)
                            }
                        };
                        tau_before += tau;
                        w
                    }
                };
                let out = p * weight;
                *value = if out.is_finite() { out as f32 } else { 0.0 };
            }
        }
    }
}
