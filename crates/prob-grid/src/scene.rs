//! The scene grid: p(x) = φ_s(S(x)) on R³ cells over the scene bound, partitioned by F, as a
//! list of the (sub-)cells that hold mass.
//!
//! **Dense** evaluation (the reference) queries the field at every cell centre. **Sparse**
//! evaluation descends an octree of blocks: a block whose centre value satisfies
//! `|S(c)| − L·r > d` (L the field's Lipschitz bound, r the block's half-diagonal) cannot hold a
//! cell with |S| < d, so it is skipped whole; `d` is the distance beyond which the density is
//! negligible ([`crate::density::negligible_distance`]). For large s the work is proportional to
//! the surface, not the volume.
//!
//! **Neglected mass.** The cells of least mass are dropped as long as their total stays within
//! `mass_tolerance` (relative, default 1e-5) of the grid's mass; the logistic's long tails then
//! cost nothing. The sparse descent skips blocks whose density is below
//! `0.1 · mass_tolerance / V` everywhere (V the volume of the scene bound), which is within the
//! same relative tolerance for any surface of area ≥ 0.1 (the density integrates to 1 across a
//! surface, so the total mass ≈ the area; a sphere of radius 0.09 has area 0.1).

use crate::density::{CellDensity, cell_density, negligible_distance};
use crate::field::SdfField;
use glam::{UVec3, Vec3};
use rayon::prelude::*;

/// Errors in a grid configuration or update input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    /// A configuration value is out of range.
    #[error("invalid {what}: {message}")]
    InvalidConfig {
        /// The option.
        what: &'static str,
        /// Why.
        message: String,
    },
}

/// How the mass of a cell is split among its F³ sub-cells.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SubcellMass {
    /// Each sub-cell carries the parent's mass / F³ (the paper; no extra field queries).
    #[default]
    Split,
    /// The field is re-evaluated at each sub-cell centre (F³ times the queries; more accurate).
    Reevaluate,
}

/// Dense (reference) or sparse (coarse-to-fine) field evaluation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Evaluation {
    /// Every cell centre is queried.
    Dense,
    /// Octree descent with the Lipschitz bound: only blocks that can hold mass are refined.
    #[default]
    Sparse,
}

/// The scene grid's configuration. Defaults: 128³ over [−1, 1]³, F = 2, split masses,
/// cell-averaged density, sparse evaluation, mass tolerance 1e-5. In a configuration file every
/// key is optional and unknown keys are errors.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneGridConfig {
    /// Cells per axis (the paper: 128).
    pub resolution: usize,
    /// Lower corner of the scene bound.
    pub bound_min: Vec3,
    /// Upper corner of the scene bound (a cube: cells are cubes).
    pub bound_max: Vec3,
    /// Partition factor F, 1..=8 (the paper: 2).
    pub partition: u32,
    /// How sub-cells get their mass.
    pub subcell_mass: SubcellMass,
    /// Point or cell-averaged density.
    pub cell_density: CellDensity,
    /// Dense or sparse evaluation.
    pub evaluation: Evaluation,
    /// Fraction of the total mass that may be neglected (see the module docs).
    pub mass_tolerance: f64,
}

impl Default for SceneGridConfig {
    fn default() -> Self {
        SceneGridConfig {
            resolution: 128,
            bound_min: Vec3::splat(-1.0),
            bound_max: Vec3::splat(1.0),
            partition: 2,
            subcell_mass: SubcellMass::Split,
            cell_density: CellDensity::CellAverage,
            evaluation: Evaluation::Sparse,
            mass_tolerance: 1e-5,
        }
    }
}

impl SceneGridConfig {
    /// Checks every value; the message names the option.
    pub fn validate(&self) -> Result<(), GridError> {
        let bad = |what, message: String| Err(GridError::InvalidConfig { what, message });
        if self.resolution == 0 || self.resolution > 2048 {
            return bad("scene grid resolution", format!("{} (1..=2048)", self.resolution));
        }
        if !(1..=8).contains(&self.partition) {
            return bad("partition factor F", format!("{} (1..=8)", self.partition));
        }
        let extent = self.bound_max - self.bound_min;
        if !(self.bound_min.is_finite() && self.bound_max.is_finite()) || extent.min_element() <= 0.0 {
            return bad("scene bound", format!("{} .. {}", self.bound_min, self.bound_max));
        }
        if (extent.x - extent.y).abs() > 1e-5 * extent.x || (extent.x - extent.z).abs() > 1e-5 * extent.x {
            return bad("scene bound", format!("must be a cube, got extent {extent}"));
        }
        if !(self.mass_tolerance.is_finite() && self.mass_tolerance > 0.0 && self.mass_tolerance < 1.0) {
            return bad("mass tolerance", format!("{}", self.mass_tolerance));
        }
        Ok(())
    }

    /// Side of a cell.
    pub fn cell_size(&self) -> f32 {
        (self.bound_max.x - self.bound_min.x) / self.resolution as f32
    }

    /// Centre of cell (i, j, k).
    pub fn cell_center(&self, cell: UVec3) -> Vec3 {
        self.bound_min + (cell.as_vec3() + 0.5) * self.cell_size()
    }

    fn volume(&self) -> f64 {
        let e = (self.bound_max - self.bound_min).as_dvec3();
        e.x * e.y * e.z
    }
}

/// The cells that hold mass, ready to reproject: each point carries a mass that is split equally
/// among the sub-cells at `point + offsets[k]` (F³ offsets for [`SubcellMass::Split`]; a single
/// zero offset when the sub-cells were evaluated themselves). Sub-cells are never materialised:
/// projecting F³ offsets costs three additions each in camera space.
#[derive(Debug, Clone, Default)]
pub struct ActiveCells {
    /// Cell (or evaluated sub-cell) centres in world.
    pub points: Vec<Vec3>,
    /// Their masses (density × volume).
    pub masses: Vec<f32>,
    /// Sub-cell centres relative to each point.
    pub offsets: Vec<Vec3>,
    /// Side of a sub-cell.
    pub subcell_size: f32,
    /// Σ masses.
    pub total_mass: f64,
    /// Number of field queries made.
    pub field_queries: usize,
    /// Number of field values that were NaN (treated as no mass).
    pub nan_values: usize,
    /// Number of parent cells kept.
    pub cells: usize,
    /// Cells per axis of the scene grid these came from.
    pub resolution: usize,
    /// The Lipschitz bound the field claimed, what its own values showed, and what was used.
    pub lipschitz: LipschitzCheck,
}

/// A field's Lipschitz claim checked against its values: the largest slope |S(a) − S(b)| / |a − b|
/// between pairs of points the evaluation queried anyway (neighbouring cells, or a block and its
/// sub-blocks). The slope is a lower bound of the true constant, so a claim below it is wrong:
/// the evaluation is then redone with `used = measured × 1.5` (`retries` counts the redos).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LipschitzCheck {
    /// The field's [`SdfField::lipschitz_bound`].
    pub claimed: f32,
    /// The largest slope measured between evaluated points.
    pub measured: f32,
    /// The bound the final evaluation used (≥ `claimed`).
    pub used: f32,
    /// Evaluations redone because the claim was broken.
    pub retries: u32,
}

/// Margin over a measured slope when a Lipschitz claim is found broken.
pub const LIPSCHITZ_MARGIN: f32 = 1.5;

impl LipschitzCheck {
    /// Runs `pass(bound)` — an evaluation that trusts `bound` and returns its result with the
    /// largest slope it measured — with the field's `claimed` bound, and redoes it with the
    /// measured slope × [`LIPSCHITZ_MARGIN`] while the bound is found broken (at most 4 redos).
    /// The one place a Lipschitz claim is checked (the scene grid's descent, marching cubes).
    pub fn run<T, E>(claimed: f32, mut pass: impl FnMut(f32) -> Result<(T, f32), E>) -> Result<(T, LipschitzCheck), E> {
        let claimed = claimed.max(1e-6);
        let mut check = LipschitzCheck { claimed, used: claimed, ..Default::default() };
        loop {
            let (result, measured) = pass(check.used)?;
            check.measured = check.measured.max(measured);
            if !(measured > check.used * 1.0001) || check.retries >= 4 {
                return Ok((result, check));
            }
            check.retries += 1;
            check.used = measured * LIPSCHITZ_MARGIN;
        }
    }
}

/// The largest slope `|v_a − v_b| / distance(a, b)` between axis neighbours `a`, `b` (flat
/// indices) of a dense `r³` grid of values (x fastest); non-finite slopes (a NaN value, two
/// points at one place) are ignored. The one measurement behind every Lipschitz check: the
/// scene grid's dense and sparse evaluations and the marching cubes' block culling.
pub(crate) fn neighbour_slope(values: &[f32], r: usize, distance: impl Fn(usize, usize) -> f32 + Sync) -> f32 {
    let at = |i: usize, j: usize, k: usize| (k * r + j) * r + i;
    (0..r)
        .into_par_iter()
        .map(|k| {
            let mut worst = 0.0f32;
            for j in 0..r {
                for i in 0..r {
                    for (di, dj, dk) in [(1, 0, 0), (0, 1, 0), (0, 0, 1)] {
                        if i + di < r && j + dj < r && k + dk < r {
                            let (a, b) = (at(i, j, k), at(i + di, j + dj, k + dk));
                            let slope = (values[a] - values[b]).abs() / distance(a, b);
                            if slope.is_finite() && slope > worst {
                                worst = slope;
                            }
                        }
                    }
                }
            }
            worst
        })
        .reduce(|| 0.0, f32::max)
}

/// The octree descent of the sparse evaluation with Lipschitz bound `lipschitz`: the leaf cells
/// (size 1) with their centre values, and the largest slope measured between a block's centre
/// and its sub-blocks' centres (and between neighbouring top-level blocks).
fn sparse_descent(
    field: &dyn SdfField,
    config: &SceneGridConfig,
    lipschitz: f32,
    keep_distance: f32,
    queries: &mut usize,
) -> (Vec<UVec3>, Vec<f32>, f32) {
    let r = config.resolution as u32;
    let cell = config.cell_size();
    // Blocks are (origin, size) in cells; start from blocks of up to 16³ cells.
    let mut size = 16u32.min(r.next_power_of_two());
    let top = r.div_ceil(size);
    let mut blocks: Vec<UVec3> = Vec::new();
    for k in 0..top {
        for j in 0..top {
            for i in 0..top {
                blocks.push(UVec3::new(i, j, k) * size);
            }
        }
    }
    // Each block's parent centre and value (none at the top level).
    let mut parents: Vec<(Vec3, f32)> = vec![(Vec3::NAN, f32::NAN); blocks.len()];
    let mut measured = 0.0f32;
    let mut first = true;
    loop {
        // A block's true extent may be clipped by the grid's end.
        let extent = |o: UVec3| (o + UVec3::splat(size)).min(UVec3::splat(r)) - o;
        let centers: Vec<Vec3> = blocks.par_iter().map(|o| config.bound_min + (o.as_vec3() + extent(*o).as_vec3() * 0.5) * cell).collect();
        let values = query(field, &centers);
        *queries += blocks.len();
        // Slopes: child against parent, and (top level) neighbouring blocks.
        let level_slope = centers
            .par_iter()
            .zip(values.par_iter())
            .zip(parents.par_iter())
            .map(|((c, v), (pc, pv))| {
                let d = c.distance(*pc);
                if d > 0.0 { (v - pv).abs() / d } else { 0.0 }
            })
            .filter(|x| x.is_finite())
            .reduce(|| 0.0, f32::max);
        measured = measured.max(level_slope);
        if first {
            // Top-level blocks are full-size except at the far edge: their centres are about a
            // block apart; the exact distance is used.
            measured = measured.max(neighbour_slope(&values, top as usize, |a, b| centers[a].distance(centers[b])));
            first = false;
        }
        if size == 1 {
            return (blocks, values, measured);
        }
        let half = size / 2;
        let (next, next_parents): (Vec<UVec3>, Vec<(Vec3, f32)>) = blocks
            .par_iter()
            .zip(values.par_iter())
            .zip(centers.par_iter())
            .flat_map_iter(|((o, v), c)| {
                let radius = 0.5 * extent(*o).as_vec3().length() * cell;
                // NaN compares false: a NaN block is refined, never silently dropped.
                let skip = v.abs() - lipschitz * radius > keep_distance;
                let e = extent(*o);
                let children: Vec<(UVec3, (Vec3, f32))> = if skip {
                    Vec::new()
                } else {
                    (0..8u32)
                        .map(|c| UVec3::new(c & 1, (c >> 1) & 1, (c >> 2) & 1) * half)
                        .filter(|d| d.x < e.x && d.y < e.y && d.z < e.z)
                        .map(|d| (*o + d, (*c, *v)))
                        .collect()
                };
                children
            })
            .unzip();
        blocks = next;
        parents = next_parents;
        size = half;
    }
}

/// Queries the field at `points` in parallel chunks.
fn query(field: &dyn SdfField, points: &[Vec3]) -> Vec<f32> {
    let mut out = vec![0.0f32; points.len()];
    out.par_chunks_mut(4096).zip(points.par_chunks(4096)).for_each(|(o, p)| field.sdf_batch(p, o));
    out
}

/// Evaluates p(x) = φ_s(S(x)) on the scene grid and returns the sub-cells holding mass.
pub fn evaluate(field: &dyn SdfField, s: f32, config: &SceneGridConfig) -> Result<ActiveCells, GridError> {
    config.validate()?;
    if !(s.is_finite() && s > 0.0) {
        return Err(GridError::InvalidConfig { what: "logistic scale s", message: format!("{s} (must be finite and > 0)") });
    }
    let r = config.resolution as u32;
    let cell = config.cell_size();
    // Densities below this are dropped before the relative pruning (see the module docs).
    let threshold = 0.1 * config.mass_tolerance / config.volume();
    let mut queries = 0usize;
    let lipschitz_claimed = field.lipschitz_bound().max(1e-6);

    // Candidate cells: all of them (dense) or the leaves of the octree descent (sparse), with
    // their centre SDF values.
    let (cells, values, lipschitz): (Vec<UVec3>, Vec<f32>, LipschitzCheck) = match config.evaluation {
        Evaluation::Dense => {
            let cells: Vec<UVec3> = (0..r).flat_map(|k| (0..r).flat_map(move |j| (0..r).map(move |i| UVec3::new(i, j, k)))).collect();
            let centers: Vec<Vec3> = cells.par_iter().map(|c| config.cell_center(*c)).collect();
            let values = query(field, &centers);
            queries += cells.len();
            let measured = neighbour_slope(&values, r as usize, |_, _| cell);
            (cells, values, LipschitzCheck { claimed: lipschitz_claimed, measured, used: lipschitz_claimed, retries: 0 })
        }
        Evaluation::Sparse => {
            let keep_distance = negligible_distance(config.cell_density, s, threshold, cell);
            // The descent trusts L only as far as the field's own values allow: a slope measured
            // between two evaluated points that exceeds L proves the claim wrong, and the
            // descent is redone with the measured slope and a margin (never silently truncated).
            let ((cells, values), check) = LipschitzCheck::run(lipschitz_claimed, |bound| {
                let (cells, values, measured) = sparse_descent(field, config, bound, keep_distance, &mut queries);
                Ok::<_, std::convert::Infallible>(((cells, values), measured))
            })
            .unwrap_or_else(|never| match never {});
            (cells, values, check)
        }
    };
    let f = config.partition;
    let subcell = cell / f as f32;
    let offsets: Vec<Vec3> =
        (0..f * f * f).map(|n| (UVec3::new(n % f, (n / f) % f, n / (f * f)).as_vec3() + 0.5) * subcell - Vec3::splat(0.5 * cell)).collect();
    let cell_volume = (cell as f64).powi(3);
    let nan_values = values.iter().filter(|v| v.is_nan()).count();

    let mut out =
        ActiveCells { subcell_size: subcell, field_queries: queries, nan_values, lipschitz, resolution: config.resolution, ..Default::default() };
    match config.subcell_mass {
        SubcellMass::Split => {
            let kept: Vec<(Vec3, f32)> = cells
                .par_iter()
                .zip(values.par_iter())
                .filter_map(|(c, v)| {
                    let density = cell_density(config.cell_density, s, *v, cell) as f64;
                    (density > threshold).then(|| (config.cell_center(*c), (density * cell_volume) as f32))
                })
                .collect();
            (out.points, out.masses) = kept.into_iter().unzip();
            prune_lightest(&mut out.points, &mut out.masses, config.mass_tolerance);
            out.cells = out.points.len();
            out.offsets = offsets;
        }
        SubcellMass::Reevaluate => {
            // Parents that may hold mass at sub-cell level: |S| within reach of a sub-cell.
            let reach = negligible_distance(config.cell_density, s, threshold, subcell) + 0.87 * cell * lipschitz.used;
            let parents: Vec<Vec3> = cells.iter().zip(&values).filter(|(_, v)| !(v.abs() > reach)).map(|(c, _)| config.cell_center(*c)).collect();
            out.cells = parents.len();
            let points: Vec<Vec3> = parents.iter().flat_map(|c| offsets.iter().map(move |o| *c + *o)).collect();
            let sub_values = query(field, &points);
            out.field_queries += points.len();
            out.nan_values += sub_values.iter().filter(|v| v.is_nan()).count();
            let sub_volume = (subcell as f64).powi(3);
            out.offsets = vec![Vec3::ZERO];
            for (p, v) in points.into_iter().zip(sub_values) {
                let density = cell_density(config.cell_density, s, v, subcell) as f64;
                if density > threshold {
                    out.points.push(p);
                    out.masses.push((density * sub_volume) as f32);
                }
            }
            prune_lightest(&mut out.points, &mut out.masses, config.mass_tolerance);
        }
    }
    out.total_mass = out.masses.iter().map(|m| *m as f64).sum();
    Ok(out)
}

/// Drops the lightest entries while their total stays within `tolerance` of the whole: a
/// histogram over the masses' binary exponents picks the largest exponent below which the mass
/// adds up to at most `tolerance · total` (whole exponent buckets only, so it errs on keeping).
fn prune_lightest(points: &mut Vec<Vec3>, masses: &mut Vec<f32>, tolerance: f64) {
    let total: f64 = masses.iter().map(|m| *m as f64).sum();
    if !(total > 0.0) {
        return;
    }
    let mut buckets = [0.0f64; 256];
    for m in masses.iter() {
        buckets[(m.to_bits() >> 23) as usize & 0xff] += *m as f64;
    }
    let budget = tolerance * total;
    let (mut cut, mut dropped) = (0usize, 0.0f64);
    while cut < 256 && dropped + buckets[cut] <= budget {
        dropped += buckets[cut];
        cut += 1;
    }
    if cut == 0 {
        return;
    }
    let mut w = 0;
    for r in 0..masses.len() {
        if (masses[r].to_bits() >> 23) as usize & 0xff >= cut {
            points[w] = points[r];
            masses[w] = masses[r];
            w += 1;
        }
    }
    points.truncate(w);
    masses.truncate(w);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::Shape;
    use glam::DVec3;

    fn sphere() -> Shape {
        Shape::Sphere { center: DVec3::new(0.1, -0.05, 0.0), radius: 0.5 }
    }

    #[test]
    fn total_mass_is_the_surface_area_at_every_scale() {
        // ∫ φ_s(S) dV = area for a thin shell: 4π r² = π for r = 0.5.
        for s in [200.0f32, 2000.0, 1e5, 1e7] {
            let config = SceneGridConfig { resolution: 64, ..Default::default() };
            let a = evaluate(&sphere(), s, &config).unwrap();
            let area = std::f64::consts::PI;
            assert!((a.total_mass - area).abs() / area < 0.1, "s {s}: mass {}", a.total_mass);
        }
    }

    #[test]
    fn point_density_aliases_at_large_s() {
        // Why CellAverage is the default: at s = 1e5 on a 64³ grid, point samples lose the shell.
        let config = SceneGridConfig { resolution: 64, cell_density: CellDensity::Point, ..Default::default() };
        let a = evaluate(&sphere(), 1e5, &config).unwrap();
        assert!(a.total_mass < 0.5 * std::f64::consts::PI, "{}", a.total_mass);
    }

    #[test]
    fn sparse_equals_dense_within_tolerance() {
        for s in [20.0f32, 200.0, 2000.0] {
            for subcell_mass in [SubcellMass::Split, SubcellMass::Reevaluate] {
                let base = SceneGridConfig { resolution: 48, subcell_mass, ..Default::default() };
                let dense = evaluate(&sphere(), s, &SceneGridConfig { evaluation: Evaluation::Dense, ..base.clone() }).unwrap();
                let sparse = evaluate(&sphere(), s, &base).unwrap();
                let diff = (dense.total_mass - sparse.total_mass).abs();
                assert!(diff <= 1e-4 * dense.total_mass, "s {s} {subcell_mass:?}: {} vs {}", dense.total_mass, sparse.total_mass);
                if s >= 200.0 && subcell_mass == SubcellMass::Split {
                    assert!(sparse.field_queries * 2 < dense.field_queries, "s {s}: sparse made {} queries", sparse.field_queries);
                }
            }
        }
    }

    #[test]
    fn empty_field_gives_no_cells_and_nan_field_is_counted() {
        struct Constant(f32);
        impl SdfField for Constant {
            fn sdf_batch(&self, _: &[Vec3], out: &mut [f32]) {
                out.fill(self.0);
            }
        }
        let config = SceneGridConfig { resolution: 16, ..Default::default() };
        let a = evaluate(&Constant(5.0), 200.0, &config).unwrap();
        assert_eq!(a.points.len(), 0);
        assert_eq!(a.offsets.len(), 8, "F = 2 by default");
        assert_eq!(a.total_mass, 0.0);
        let a = evaluate(&Constant(f32::NAN), 200.0, &SceneGridConfig { evaluation: Evaluation::Dense, ..config.clone() }).unwrap();
        assert_eq!(a.nan_values, 16 * 16 * 16);
        assert_eq!(a.total_mass, 0.0);
        let one = SceneGridConfig { resolution: 1, ..Default::default() };
        let a = evaluate(&sphere(), 1e-3, &one).unwrap();
        assert_eq!(a.cells, 1);
        assert!(a.total_mass.is_finite() && a.total_mass > 0.0);
    }

    /// A field whose gradient is 4 while it claims a Lipschitz bound of 1 (a learnt SDF that
    /// is no distance yet).
    struct Steep;
    impl SdfField for Steep {
        fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
            for (p, o) in points.iter().zip(out) {
                *o = 4.0 * (p.length() - 0.5);
            }
        }
    }

    /// Regression: the sparse descent skipped blocks by the claimed bound without checking it;
    /// a steeper field lost its surface silently. Now the claim is checked against the values the
    /// descent queries and the descent is redone with the measured slope.
    #[test]
    fn field_breaking_its_lipschitz_claim_is_detected_not_truncated() {
        let base = SceneGridConfig { resolution: 64, ..Default::default() };
        let dense = evaluate(&Steep, 200.0, &SceneGridConfig { evaluation: Evaluation::Dense, ..base.clone() }).unwrap();
        let sparse = evaluate(&Steep, 200.0, &base).unwrap();
        assert!(sparse.lipschitz.retries >= 1, "{:?}", sparse.lipschitz);
        assert!(sparse.lipschitz.measured > 3.5 && sparse.lipschitz.used >= sparse.lipschitz.measured, "{:?}", sparse.lipschitz);
        let diff = (dense.total_mass - sparse.total_mass).abs();
        assert!(diff <= 1e-4 * dense.total_mass, "sparse {} vs dense {}", sparse.total_mass, dense.total_mass);
        // An honest field is not redone and its slope is measured near 1.
        let honest = evaluate(&sphere(), 200.0, &base).unwrap();
        assert_eq!(honest.lipschitz.retries, 0);
        assert!(honest.lipschitz.measured > 0.8 && honest.lipschitz.measured <= 1.0001, "{:?}", honest.lipschitz);
    }

    #[test]
    fn bad_configuration_names_the_option() {
        let c = SceneGridConfig { partition: 0, ..Default::default() };
        assert!(evaluate(&sphere(), 10.0, &c).unwrap_err().to_string().contains("partition factor F"));
        let err = evaluate(&sphere(), -1.0, &SceneGridConfig::default()).unwrap_err();
        assert!(err.to_string().contains("logistic scale s"));
    }
}
