//! Evaluation on plain slices: image metrics (PSNR whole and masked, SSIM) and geometry metrics
//! (Chamfer distance by the DTU protocol, F-score, normal consistency).
//!
//! # Invariants
//! - Takes plain data (`[f32; 3]` points and colours, `bool` masks): knows nothing of cameras,
//!   datasets or backbones. Culling by masks is the caller's predicate ([`cull`]).
//! - Deterministic: mesh sampling takes a seed; nearest neighbours are exact (k-d tree).
//!
//! # The DTU protocol ([`chamfer`])
//! As the DTU evaluation script used by NeuS/Neuralangelo (`eval.py`): the predicted mesh is
//! sampled at a fixed density ([`sample_mesh`], spacing d: ≈ one point per d² of area); accuracy
//! is the mean distance from predicted points to the ground-truth points, completeness from
//! ground-truth points to predicted points, each over the distances below `max_dist` (DTU: 20 mm;
//! larger ones are outliers and are left out of the mean, not clamped); Chamfer = their mean.
//! DTU's truth is what its scanner observed, and its script counts the mesh only inside that
//! observed volume; [`chamfer_observed`] does the same for a truth that is a whole surface, given
//! which of its points were observed (the caller's flags).
#![deny(missing_docs)]

pub mod align;
mod ssim;
pub use ssim::ssim;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use rayon::prelude::*;

/// Errors of the metrics.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    /// Inputs that must match in size do not.
    #[error("{what}: sizes differ ({a} vs {b})")]
    SizeMismatch {
        /// What was compared.
        what: &'static str,
        /// First size.
        a: usize,
        /// Second size.
        b: usize,
    },
    /// An input is empty (no pixels in the mask, no points).
    #[error("{0} is empty")]
    Empty(&'static str),
    /// Sampling a mesh at this spacing would make more points than [`MAX_MESH_SAMPLES`].
    #[error(
        "sampling the mesh (area {area:.4e}) every {spacing:.4e} would make {points:.3e} points, more than the limit of {limit}: \
         give a larger spacing (or check the mesh's units)"
    )]
    TooManySamples {
        /// The mesh's area.
        area: f64,
        /// The spacing asked for.
        spacing: f64,
        /// The points it would make.
        points: f64,
        /// [`MAX_MESH_SAMPLES`].
        limit: usize,
    },
    /// A value out of its range (a spacing that is not positive, non-finite coordinates).
    #[error("{what}: {value} is out of range ({expected})")]
    OutOfRange {
        /// The value's name.
        what: &'static str,
        /// The value.
        value: f64,
        /// Its range.
        expected: &'static str,
    },
}

/// The most points [`sample_mesh`] makes (20 M points: 240 MB; a DTU mesh at the protocol's
/// 0.2 mm spacing makes a few million).
pub const MAX_MESH_SAMPLES: usize = 20_000_000;

/// PSNR in dB of colours in [0, 1] over the pixels where `mask` is true (all pixels without a
/// mask). Identical images give `f64::INFINITY`.
pub fn psnr(pred: &[[f32; 3]], target: &[[f32; 3]], mask: Option<&[bool]>) -> Result<f64, MetricsError> {
    if pred.len() != target.len() {
        return Err(MetricsError::SizeMismatch { what: "psnr images", a: pred.len(), b: target.len() });
    }
    if let Some(m) = mask
        && m.len() != pred.len()
    {
        return Err(MetricsError::SizeMismatch { what: "psnr mask", a: m.len(), b: pred.len() });
    }
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (i, (p, t)) in pred.iter().zip(target).enumerate() {
        if mask.is_some_and(|m| !m[i]) {
            continue;
        }
        for k in 0..3 {
            sum += f64::from(p[k] - t[k]).powi(2);
        }
        count += 3;
    }
    if count == 0 {
        return Err(MetricsError::Empty("psnr mask"));
    }
    Ok(-10.0 * (sum / count as f64).log10())
}

/// Points on a triangle mesh at a fixed density: `⌈area / spacing²⌉` points per unit of area in
/// total, each triangle getting its share (stratified by area: the expected count is exact and
/// every triangle with area ≥ spacing² gets at least one point). Deterministic in `seed`.
///
/// Errors: a spacing that is not positive and finite, a vertex index out of range, non-finite
/// coordinates, or more than [`MAX_MESH_SAMPLES`] points (the count is known before any is made).
pub fn sample_mesh(vertices: &[[f32; 3]], triangles: &[[u32; 3]], spacing: f64, seed: u64) -> Result<Vec<[f32; 3]>, MetricsError> {
    sample_mesh_into(vertices, triangles, spacing, seed, None)
}

/// Points on a triangle mesh with the unit normals of their triangles ([`sample_mesh`]'s points,
/// the same for the same seed), for [`Nearest::normal_consistency`].
#[derive(Debug, Clone, PartialEq)]
pub struct OrientedPoints {
    /// The points.
    pub points: Vec<[f32; 3]>,
    /// The unit normal of the triangle each point lies on (by the triangle's winding; zero for a
    /// triangle without area).
    pub normals: Vec<[f32; 3]>,
}

impl OrientedPoints {
    /// The points (each with its normal) for which `keep` is true ([`cull`]).
    pub fn culled(self, keep: impl Fn([f32; 3]) -> bool + Sync) -> OrientedPoints {
        let flags: Vec<bool> = self.points.par_iter().map(|&p| keep(p)).collect();
        let (points, normals) = self.points.into_iter().zip(self.normals).zip(flags).filter(|(_, kept)| *kept).map(|(pair, _)| pair).unzip();
        OrientedPoints { points, normals }
    }

    /// The points carried by `similarity`, their normals turned by its rotation.
    pub fn moved(self, similarity: &align::Similarity) -> OrientedPoints {
        let carry = |p: [f32; 3], f: &dyn Fn([f64; 3]) -> [f64; 3]| f(p.map(f64::from)).map(|c| c as f32);
        OrientedPoints {
            points: self.points.into_iter().map(|p| carry(p, &|p| similarity.apply(p))).collect(),
            normals: self.normals.into_iter().map(|n| carry(n, &|n| similarity.rotate(n))).collect(),
        }
    }
}

/// [`sample_mesh`] with each point's triangle normal.
pub fn sample_mesh_oriented(vertices: &[[f32; 3]], triangles: &[[u32; 3]], spacing: f64, seed: u64) -> Result<OrientedPoints, MetricsError> {
    let mut normals = Vec::new();
    let points = sample_mesh_into(vertices, triangles, spacing, seed, Some(&mut normals))?;
    Ok(OrientedPoints { points, normals })
}

/// [`sample_mesh`]; with `normals`, each point's triangle normal pushed there.
fn sample_mesh_into(
    vertices: &[[f32; 3]],
    triangles: &[[u32; 3]],
    spacing: f64,
    seed: u64,
    mut normals: Option<&mut Vec<[f32; 3]>>,
) -> Result<Vec<[f32; 3]>, MetricsError> {
    if !(spacing.is_finite() && spacing > 0.0) {
        return Err(MetricsError::OutOfRange { what: "mesh sampling spacing", value: spacing, expected: "positive and finite" });
    }
    let corners = |t: &[u32; 3]| -> Result<[[f64; 3]; 3], MetricsError> {
        let mut out = [[0.0; 3]; 3];
        for (k, &i) in t.iter().enumerate() {
            let v = vertices.get(i as usize).ok_or(MetricsError::SizeMismatch {
                what: "triangle index vs vertices",
                a: i as usize,
                b: vertices.len(),
            })?;
            out[k] = v.map(f64::from);
        }
        Ok(out)
    };
    let area_of = |[a, b, c]: [[f64; 3]; 3]| {
        let e1 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let e2 = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let cross = [e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]];
        let twice = (cross[0] * cross[0] + cross[1] * cross[1] + cross[2] * cross[2]).sqrt();
        let normal = if twice > 0.0 { cross.map(|c| (c / twice) as f32) } else { [0.0; 3] };
        (e1, e2, 0.5 * twice, normal)
    };
    let per_area = 1.0 / (spacing * spacing);
    let mut total = 0.0f64;
    for t in triangles {
        total += area_of(corners(t)?).2;
    }
    let points = total * per_area;
    if !points.is_finite() {
        return Err(MetricsError::OutOfRange { what: "mesh area", value: total, expected: "finite coordinates" });
    }
    if points > MAX_MESH_SAMPLES as f64 {
        return Err(MetricsError::TooManySamples { area: total, spacing, points, limit: MAX_MESH_SAMPLES });
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let mut carry = 0.0f64;
    let mut out = Vec::with_capacity(points.ceil() as usize);
    for t in triangles {
        let corners = corners(t)?;
        let a = corners[0];
        let (e1, e2, area, normal) = area_of(corners);
        carry += area * per_area;
        while carry >= 1.0 {
            carry -= 1.0;
            let (mut u, mut v): (f64, f64) = (rng.random(), rng.random());
            if u + v > 1.0 {
                (u, v) = (1.0 - u, 1.0 - v);
            }
            out.push([0, 1, 2].map(|k| (a[k] + u * e1[k] + v * e2[k]) as f32));
            if let Some(normals) = normals.as_deref_mut() {
                normals.push(normal);
            }
        }
    }
    Ok(out)
}

/// Keeps the points for which `keep` is true (e.g. NeuralWarp-style culling: inside the dilated
/// masks of at least two views; or inside an observation bound).
pub fn cull(points: &[[f32; 3]], keep: impl Fn([f32; 3]) -> bool + Sync) -> Vec<[f32; 3]> {
    points.par_iter().copied().filter(|&p| keep(p)).collect()
}

/// A k-d tree over a point set, for repeated nearest-neighbour distances.
///
/// The points are stored rotated by a fixed generic rotation (queries alike; distances do not
/// change): points sampled on an axis-aligned plane share one coordinate exactly, which a k-d
/// tree cannot split on, and its leaves then grow with the cloud (a flat face of a box made the
/// search run for minutes).
pub struct PointCloud {
    tree: ImmutableKdTree<f32, 3>,
    len: usize,
}

/// The rotation [`PointCloud`] stores its points in: about the axis (1, 2, 3)/√14 by 1 radian
/// (no coordinate axis or plane of it is parallel to a world axis or plane).
fn generic_rotation(p: &[f32; 3]) -> [f32; 3] {
    const R: [[f64; 3]; 3] = {
        // Rodrigues' formula, precomputed: R = cos θ I + sin θ [k]× + (1 − cos θ) k kᵀ.
        [
            [0.573_137_855_448_986_9, -0.609_006_642_137_393_3, 0.548_291_809_608_599_9],
            [0.740_348_840_460_782, 0.671_644_504_191_528_4, -0.027_879_282_947_946_3],
            [-0.351_278_512_123_517, 0.421_905_877_918_112_2, 0.835_822_252_095_764_2],
        ]
    };
    let v = p.map(f64::from);
    R.map(|row| (row[0] * v[0] + row[1] * v[1] + row[2] * v[2]) as f32)
}

impl PointCloud {
    /// Builds the tree.
    pub fn new(points: &[[f32; 3]]) -> Result<PointCloud, MetricsError> {
        if points.is_empty() {
            return Err(MetricsError::Empty("point cloud"));
        }
        let rotated: Vec<[f32; 3]> = points.iter().map(generic_rotation).collect();
        let tree = ImmutableKdTree::new_from_slice(&rotated).map_err(|_| MetricsError::Empty("point cloud (k-d tree construction)"))?;
        Ok(PointCloud { tree, len: points.len() })
    }

    /// Number of points.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Always false (empty clouds are rejected by [`PointCloud::new`]).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Distance to the nearest point, and its index, for every query point (in parallel).
    pub fn nearest(&self, queries: &[[f32; 3]]) -> Vec<(f32, usize)> {
        queries
            .par_iter()
            .map(|q| {
                let r = self.tree.query(&generic_rotation(q)).nearest_one::<SquaredEuclidean<f32>>().execute();
                (r.distance.max(0.0).sqrt(), r.item as usize)
            })
            .collect()
    }
}

/// Chamfer distance and F-score of a predicted point set against a ground-truth one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GeometryMetrics {
    /// Mean distance predicted → truth over distances < max_dist.
    pub accuracy: f64,
    /// Mean distance truth → predicted over distances < max_dist.
    pub completeness: f64,
    /// (accuracy + completeness) / 2.
    pub chamfer: f64,
    /// Fraction of predicted points within τ of the truth.
    pub precision: f64,
    /// Fraction of truth points within τ of the prediction.
    pub recall: f64,
    /// 2PR / (P + R) (0 when both are 0).
    pub f_score: f64,
    /// τ used.
    pub tau: f64,
    /// Predicted points.
    pub n_pred: usize,
    /// Ground-truth points.
    pub n_gt: usize,
}

/// How well a point cloud covers a set of query points (one direction of a Chamfer distance).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Coverage {
    /// Mean distance from a query to its nearest cloud point, over distances < `max_dist`
    /// (infinite when none is).
    pub mean: f64,
    /// Fraction of the queries within τ of the cloud.
    pub within: f64,
}

/// How well `cloud` covers `queries`: [`Coverage`] at `max_dist` and `tau`. `chamfer`'s
/// completeness and recall are `coverage(pred, gt)`; a subset of the truth (one part of a shape)
/// gives that part's.
pub fn coverage(cloud: &PointCloud, queries: &[[f32; 3]], max_dist: f64, tau: f64) -> Coverage {
    coverage_of(cloud.nearest(queries).iter().map(|(d, _)| *d), max_dist, tau)
}

/// [`Coverage`] of nearest distances: their mean below `max_dist`, the share below `tau` (a
/// part of a [`Nearest`]'s distances gives that part's).
pub fn coverage_of(distances: impl Iterator<Item = f32>, max_dist: f64, tau: f64) -> Coverage {
    let (mut sum, mut kept, mut within, mut count) = (0.0, 0usize, 0usize, 0usize);
    for d in distances.map(f64::from) {
        count += 1;
        if d < max_dist {
            (sum, kept) = (sum + d, kept + 1);
        }
        within += usize::from(d < tau);
    }
    Coverage { mean: if kept == 0 { f64::INFINITY } else { sum / kept as f64 }, within: within as f64 / count.max(1) as f64 }
}

/// The metrics of both directions.
fn geometry(accuracy: Coverage, completeness: Coverage, tau: f64, n_pred: usize, n_gt: usize) -> GeometryMetrics {
    let (precision, recall) = (accuracy.within, completeness.within);
    let f_score = if precision + recall > 0.0 { 2.0 * precision * recall / (precision + recall) } else { 0.0 };
    GeometryMetrics {
        accuracy: accuracy.mean,
        completeness: completeness.mean,
        chamfer: 0.5 * (accuracy.mean + completeness.mean),
        precision,
        recall,
        f_score,
        tau,
        n_pred,
        n_gt,
    }
}

/// The DTU-protocol Chamfer distance and the F-score at `tau` between point sets (sample a mesh
/// with [`sample_mesh`] first).
pub fn chamfer(pred: &[[f32; 3]], gt: &[[f32; 3]], max_dist: f64, tau: f64) -> Result<GeometryMetrics, MetricsError> {
    Ok(Nearest::new(pred, gt)?.chamfer(max_dist, tau))
}

/// The nearest neighbours between predicted and truth points, both ways (one k-d tree over each
/// set): everything a Chamfer distance reads, so that the whole figure, the figure over what the
/// views observed and one per part are made from one search.
#[derive(Debug, Clone, PartialEq)]
pub struct Nearest {
    /// For each predicted point, the distance to its nearest truth point and that point's index.
    pub pred_to_gt: Vec<(f32, usize)>,
    /// For each truth point, the distance to its nearest predicted point and that point's index.
    pub gt_to_pred: Vec<(f32, usize)>,
}

impl Nearest {
    /// Both searches.
    pub fn new(pred: &[[f32; 3]], gt: &[[f32; 3]]) -> Result<Nearest, MetricsError> {
        let (pred_cloud, gt_cloud) = (PointCloud::new(pred)?, PointCloud::new(gt)?);
        Ok(Nearest { pred_to_gt: gt_cloud.nearest(pred), gt_to_pred: pred_cloud.nearest(gt) })
    }

    /// [`chamfer`].
    pub fn chamfer(&self, max_dist: f64, tau: f64) -> GeometryMetrics {
        let distances = |n: &[(f32, usize)]| coverage_of(n.iter().map(|(d, _)| *d), max_dist, tau);
        geometry(distances(&self.pred_to_gt), distances(&self.gt_to_pred), tau, self.pred_to_gt.len(), self.gt_to_pred.len())
    }

    /// [`chamfer_observed`].
    pub fn chamfer_observed(&self, observed: &[bool], max_dist: f64, tau: f64) -> Result<GeometryMetrics, MetricsError> {
        if observed.len() != self.gt_to_pred.len() {
            return Err(MetricsError::SizeMismatch { what: "observation flags against truth points", a: observed.len(), b: self.gt_to_pred.len() });
        }
        let seen: Vec<f32> = self.gt_to_pred.iter().zip(observed).filter(|(_, o)| **o).map(|((d, _), _)| *d).collect();
        if seen.is_empty() {
            return Err(MetricsError::Empty("the observed truth"));
        }
        let measured: Vec<f32> = self.pred_to_gt.iter().filter(|(_, i)| observed[*i]).map(|(d, _)| *d).collect();
        let n_pred = measured.len();
        Ok(geometry(coverage_of(measured.into_iter(), max_dist, tau), coverage_of(seen.iter().copied(), max_dist, tau), tau, n_pred, seen.len()))
    }

    /// Normal consistency over the pairs the Chamfer distance counts: the mean of |n · n'| over
    /// each predicted point and its nearest truth point closer than `max_dist`, the same over
    /// each truth point and its nearest predicted one, and the mean of the two (1: every normal
    /// parallel to its neighbour's; bumps on a smooth surface lower it where the Chamfer
    /// distance hardly moves). With `observed` (one flag per truth point), over what the views
    /// observed as [`Self::chamfer_observed`] counts it. `None`: a direction has no pair.
    pub fn normal_consistency(
        &self,
        pred_normals: &[[f32; 3]],
        gt_normals: &[[f32; 3]],
        max_dist: f64,
        observed: Option<&[bool]>,
    ) -> Result<Option<f64>, MetricsError> {
        let (n_pred, n_gt) = (self.pred_to_gt.len(), self.gt_to_pred.len());
        for (what, a, b) in [
            ("the mesh's normals against its points", pred_normals.len(), n_pred),
            ("the truth's normals against its points", gt_normals.len(), n_gt),
            ("observation flags against truth points", observed.map_or(n_gt, <[bool]>::len), n_gt),
        ] {
            if a != b {
                return Err(MetricsError::SizeMismatch { what, a, b });
            }
        }
        let seen = |i: usize| observed.is_none_or(|o| o[i]);
        // One direction: each point of `from` and its nearest of `to`, counted within the
        // outlier distance where the truth point of the pair (`truth(i, j)`) was seen.
        let one_way = |pairs: &[(f32, usize)], from: &[[f32; 3]], to: &[[f32; 3]], truth: &dyn Fn(usize, usize) -> usize| {
            let (sum, count) = pairs
                .iter()
                .enumerate()
                .filter(|&(i, &(d, j))| f64::from(d) < max_dist && seen(truth(i, j)))
                .fold((0.0, 0usize), |(sum, count), (i, &(_, j))| (sum + unsigned_cosine(from[i], to[j]), count + 1));
            (count > 0).then(|| sum / count as f64)
        };
        let accuracy = one_way(&self.pred_to_gt, pred_normals, gt_normals, &|_, j| j);
        let completeness = one_way(&self.gt_to_pred, gt_normals, pred_normals, &|i, _| i);
        Ok(accuracy.zip(completeness).map(|(a, c)| 0.5 * (a + c)))
    }
}

/// [`chamfer`] over what the views observed, as the DTU evaluation's observation mask restricts
/// it: completeness and recall over the truth points flagged in `observed` (one flag per point of
/// `gt`), accuracy and precision over the predicted points whose nearest truth point is observed
/// (a predicted point nearest a part no view saw, such as the underside of an object on a
/// table, is neither right nor wrong). `n_pred` and `n_gt` count the points measured.
pub fn chamfer_observed(pred: &[[f32; 3]], gt: &[[f32; 3]], observed: &[bool], max_dist: f64, tau: f64) -> Result<GeometryMetrics, MetricsError> {
    if observed.len() != gt.len() {
        return Err(MetricsError::SizeMismatch { what: "observation flags against truth points", a: observed.len(), b: gt.len() });
    }
    Nearest::new(pred, gt)?.chamfer_observed(observed, max_dist, tau)
}

/// Normal consistency: mean over both directions of |n_a · n_b| between each point's normal and
/// its nearest neighbour's in the other set (1 = identical orientation up to sign), every pair
/// counted ([`Nearest::normal_consistency`] with no outlier distance).
pub fn normal_consistency(a: &[[f32; 3]], na: &[[f32; 3]], b: &[[f32; 3]], nb: &[[f32; 3]]) -> Result<f64, MetricsError> {
    Nearest::new(a, b)?.normal_consistency(na, nb, f64::INFINITY, None)?.ok_or(MetricsError::Empty("normal consistency pairs"))
}

/// |x · y| / (|x| |y|); 0 when either is zero.
fn unsigned_cosine(x: [f32; 3], y: [f32; 3]) -> f64 {
    let (x, y) = (x.map(f64::from), y.map(f64::from));
    let (lx, ly) = ((x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt(), (y[0] * y[0] + y[1] * y[1] + y[2] * y[2]).sqrt());
    if lx > 0.0 && ly > 0.0 { (x[0] * y[0] + x[1] * y[1] + x[2] * y[2]).abs() / (lx * ly) } else { 0.0 }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_of_a_known_error() {
        // Every channel off by 0.1: MSE 0.01 → 20 dB; the mask picks the half that is off by 0.1.
        let t = vec![[0.5f32; 3]; 4];
        let p = vec![[0.6f32; 3]; 4];
        assert!((psnr(&p, &t, None).unwrap() - 20.0).abs() < 1e-4);
        let mut q = p.clone();
        q[2] = [0.5; 3];
        q[3] = [0.5; 3];
        let mask = [true, true, false, false];
        assert!((psnr(&q, &t, Some(&mask)).unwrap() - 20.0).abs() < 1e-4);
        assert!((psnr(&q, &t, None).unwrap() - 23.0103).abs() < 1e-3);
        assert_eq!(psnr(&t, &t, None).unwrap(), f64::INFINITY);
        assert!(matches!(psnr(&p, &t, Some(&[false; 4])), Err(MetricsError::Empty(_))));
        assert!(matches!(psnr(&p[..3], &t, None), Err(MetricsError::SizeMismatch { .. })));
    }

    fn sphere_points(r: f32, n: usize, seed: u64) -> Vec<[f32; 3]> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        (0..n)
            .map(|_| {
                let z: f32 = rng.random::<f32>() * 2.0 - 1.0;
                let a: f32 = rng.random::<f32>() * std::f32::consts::TAU;
                let s = (1.0 - z * z).sqrt();
                [r * s * a.cos(), r * s * a.sin(), r * z]
            })
            .collect()
    }

    #[test]
    fn nearest_distances_on_an_axis_aligned_plane_are_exact() {
        // 90 000 points with z = 0 exactly (a box face): the k-d tree stores them rotated.
        let plane: Vec<[f32; 3]> = (0..300).flat_map(|i| (0..300).map(move |j| [i as f32 / 300.0, j as f32 / 300.0, 0.0])).collect();
        let cloud = PointCloud::new(&plane).unwrap();
        let queries: Vec<[f32; 3]> = (0..200).map(|k| [(k % 17) as f32 / 17.0, (k % 13) as f32 / 13.0, 0.01 * (k % 5) as f32]).collect();
        for (q, (d, i)) in queries.iter().zip(cloud.nearest(&queries)) {
            let brute =
                plane.iter().map(|p| ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()).fold(f32::INFINITY, f32::min);
            assert!((d - brute).abs() < 1e-5, "{q:?}: {d} vs {brute}");
            let p = plane[i];
            assert!((((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt() - brute).abs() < 1e-5);
        }
    }

    #[test]
    fn sampling_a_mesh_is_bounded_before_any_point_is_made() {
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        for spacing in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(sample_mesh(&v, &[[0, 1, 2]], spacing, 1), Err(MetricsError::OutOfRange { .. })), "{spacing}");
        }
        // 1e-6 on a unit triangle: 5e11 points, refused at once.
        assert!(matches!(sample_mesh(&v, &[[0, 1, 2]], 1e-6, 1), Err(MetricsError::TooManySamples { .. })));
        // Coordinates of 1e30: an area of 1e60.
        let huge = [[0.0, 0.0, 0.0], [1e30, 0.0, 0.0], [0.0, 1e30, 0.0]];
        assert!(sample_mesh(&huge, &[[0, 1, 2]], 0.01, 1).is_err());
        // An index out of range is an error, not a panic.
        assert!(matches!(sample_mesh(&v, &[[0, 1, 7]], 0.1, 1), Err(MetricsError::SizeMismatch { .. })));
    }

    #[test]
    fn chamfer_of_concentric_spheres_is_their_gap() {
        // Dense samples of spheres of radius 1 and 1.05: every distance ≈ 0.05.
        let a = sphere_points(1.0, 40_000, 1);
        let b = sphere_points(1.05, 40_000, 2);
        let m = chamfer(&a, &b, 1.0, 0.06).unwrap();
        assert!((m.accuracy - 0.05).abs() < 0.006, "{m:?}");
        assert!((m.completeness - 0.05).abs() < 0.006, "{m:?}");
        assert!(m.f_score > 0.8, "{m:?}");
        let m = chamfer(&a, &b, 1.0, 0.04).unwrap();
        assert!(m.f_score < 0.05, "{m:?}");
        // Outliers beyond max_dist leave the mean.
        let mut c = a.clone();
        c.push([50.0, 0.0, 0.0]);
        let m2 = chamfer(&c, &b, 1.0, 0.06).unwrap();
        assert!((m2.accuracy - chamfer(&a, &b, 1.0, 0.06).unwrap().accuracy).abs() < 1e-6);
        assert!(matches!(chamfer(&[], &b, 1.0, 0.1), Err(MetricsError::Empty(_))));
    }

    /// The observed Chamfer measures only what the views saw: a prediction 0.01 off the seen
    /// upper half and 0.08 off the unseen lower half scores 0.01, where the whole measures both.
    #[test]
    fn the_observed_chamfer_leaves_out_what_no_view_saw() {
        let truth = sphere_points(1.0, 40_000, 1);
        let observed: Vec<bool> = truth.iter().map(|p| p[2] > 0.0).collect();
        let pred: Vec<[f32; 3]> = sphere_points(1.0, 40_000, 2)
            .into_iter()
            .map(|p| {
                let r = if p[2] > 0.0 { 1.01 } else { 1.08 };
                p.map(|c| c * r)
            })
            .collect();
        let m = chamfer_observed(&pred, &truth, &observed, 1.0, 0.03).unwrap();
        assert!((m.accuracy - 0.01).abs() < 0.006 && (m.completeness - 0.01).abs() < 0.006, "{m:?}");
        assert!(m.f_score > 0.95, "{m:?}");
        assert!((m.n_gt as f64 / truth.len() as f64 - 0.5).abs() < 0.02 && (m.n_pred as f64 / pred.len() as f64 - 0.5).abs() < 0.02, "{m:?}");
        let whole = chamfer(&pred, &truth, 1.0, 0.03).unwrap();
        assert!(whole.chamfer > 0.04 && whole.f_score < 0.6, "the whole counts the unseen half: {whole:?}");
        let all = vec![true; truth.len()];
        assert_eq!(chamfer_observed(&pred, &truth, &all, 1.0, 0.03).unwrap(), whole, "everything observed: the plain Chamfer");
        assert!(matches!(chamfer_observed(&pred, &truth, &observed[1..], 1.0, 0.03), Err(MetricsError::SizeMismatch { .. })));
        assert!(matches!(chamfer_observed(&pred, &truth, &vec![false; truth.len()], 1.0, 0.03), Err(MetricsError::Empty(_))));
    }

    #[test]
    fn mesh_sampling_has_the_requested_density() {
        // A unit square (two triangles) at spacing 0.01: 10 000 points, all inside.
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]];
        let p = sample_mesh(&v, &[[0, 1, 2], [0, 2, 3]], 0.01, 3).unwrap();
        assert!((p.len() as i64 - 10_000).abs() <= 1, "{}", p.len());
        assert!(p.iter().all(|q| (0.0..=1.0).contains(&q[0]) && (0.0..=1.0).contains(&q[1]) && q[2] == 0.0));
        let mean_x = p.iter().map(|q| f64::from(q[0])).sum::<f64>() / p.len() as f64;
        assert!((mean_x - 0.5).abs() < 0.01);
        assert_eq!(p, sample_mesh(&v, &[[0, 1, 2], [0, 2, 3]], 0.01, 3).unwrap());
    }

    #[test]
    fn normal_consistency_of_a_sphere_with_itself_and_with_random_normals() {
        let a = sphere_points(1.0, 5000, 4);
        let b = sphere_points(1.0, 5000, 5);
        assert!(normal_consistency(&a, &a, &b, &b).unwrap() > 0.99);
        let random = sphere_points(1.0, 5000, 6);
        let nc = normal_consistency(&a, &random, &b, &b).unwrap();
        assert!((nc - 0.5).abs() < 0.05, "{nc}");
    }

    /// Bumps: the same sphere 0.002 out, its normals radial, has a normal consistency of 1; with
    /// every normal tilted by 20° (the same points: the same Chamfer) cos 20°; a far outlier with a wrong normal is left out
    /// as the Chamfer leaves it out; over what the views observed, the unseen half's wrong
    /// normals do not count.
    #[test]
    fn normal_consistency_sees_tilted_normals_the_chamfer_does_not_and_counts_its_pairs() {
        let truth = sphere_points(1.0, 20_000, 1);
        let radial: Vec<[f32; 3]> = truth.clone();
        let tilt = 20f32.to_radians();
        let tilted = |p: [f32; 3]| {
            // Rotate the radial normal towards a tangent by `tilt`.
            let t = [-p[1], p[0], 0.0];
            let l = (t[0] * t[0] + t[1] * t[1]).sqrt().max(1e-6);
            [0, 1, 2].map(|k| p[k] * tilt.cos() + t[k] / l * tilt.sin())
        };
        let pred: Vec<[f32; 3]> = sphere_points(1.002, 20_000, 2);
        let pred_normals: Vec<[f32; 3]> = pred.iter().map(|&p| tilted(p.map(|c| c / 1.002))).collect();
        let nearest = Nearest::new(&pred, &truth).unwrap();
        let straight: Vec<[f32; 3]> = pred.iter().map(|p| p.map(|c| c / 1.002)).collect();
        assert!(nearest.normal_consistency(&straight, &radial, 1.0, None).unwrap() > Some(0.995));
        let nc = nearest.normal_consistency(&pred_normals, &radial, 1.0, None).unwrap().unwrap();
        assert!((nc - f64::from(tilt.cos())).abs() < 0.01, "{nc}");
        // A far outlier with a perpendicular normal: counted with no outlier distance only.
        let (mut far, mut far_normals) = (pred.clone(), pred_normals.clone());
        far.extend(std::iter::repeat_n([0.0, 0.0, 3.0], 2000));
        far_normals.extend(std::iter::repeat_n([1.0, 0.0, 0.0], 2000));
        let outlying = Nearest::new(&far, &truth).unwrap();
        assert_eq!(outlying.normal_consistency(&far_normals, &radial, 1.0, None).unwrap(), Some(nc));
        assert!(outlying.normal_consistency(&far_normals, &radial, f64::INFINITY, None).unwrap() < Some(nc - 0.02));
        // The lower half's normals perpendicular to the truth's; only the upper half observed.
        let half: Vec<[f32; 3]> = pred.iter().zip(&pred_normals).map(|(p, n)| if p[2] > 0.0 { *n } else { [-p[1], p[0], 0.0] }).collect();
        let observed: Vec<bool> = truth.iter().map(|p| p[2] > 0.0).collect();
        let seen = nearest.normal_consistency(&half, &radial, 1.0, Some(&observed)).unwrap().unwrap();
        assert!((seen - nc).abs() < 0.01, "{seen} against {nc}");
        assert!(nearest.normal_consistency(&half, &radial, 1.0, None).unwrap() < Some(nc - 0.2));
        // Nothing within the outlier distance: none; a wrong count of normals: an error.
        assert_eq!(nearest.normal_consistency(&pred_normals, &radial, 1e-9, None).unwrap(), None);
        assert!(nearest.normal_consistency(&pred_normals[1..], &radial, 1.0, None).is_err());
    }

    /// Culling keeps each normal with its point; a similarity carries the points and turns the
    /// normals by its rotation alone (a quarter turn about z: +x → +y, at any scale).
    #[test]
    fn culled_and_moved_oriented_points_keep_each_normal_with_its_point() {
        let points = OrientedPoints {
            points: vec![[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [3.0, 0.0, 0.0]],
            normals: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
        };
        let kept = points.clone().culled(|p| p[1] == 0.0);
        assert_eq!(kept.points, vec![[1.0, 0.0, 0.0], [3.0, 0.0, 0.0]]);
        assert_eq!(kept.normals, vec![[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]);
        let quarter = align::Similarity { scale: 2.0, rotation: [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0, 0.0, 5.0] };
        let moved = points.moved(&quarter);
        assert_eq!(moved.points[0], [0.0, 2.0, 5.0]);
        assert_eq!(moved.normals, vec![[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]);
    }

    /// An oriented sample is the plain sample's points, each with its triangle's unit normal.
    #[test]
    fn an_oriented_mesh_sample_has_the_plain_samples_points_and_its_triangles_normals() {
        // A unit square in z = 0 (normal +z) and one in x = 0 (normal +x by its winding).
        let v = [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 1.0]];
        let t = [[0, 1, 2], [0, 2, 3], [0, 3, 5], [0, 5, 4]];
        let oriented = sample_mesh_oriented(&v, &t, 0.02, 3).unwrap();
        assert_eq!(oriented.points, sample_mesh(&v, &t, 0.02, 3).unwrap());
        assert_eq!(oriented.normals.len(), oriented.points.len());
        for (p, n) in oriented.points.iter().zip(&oriented.normals) {
            let expected = if p[2] == 0.0 { [0.0, 0.0, 1.0] } else { [1.0, 0.0, 0.0] };
            assert!((0..3).all(|k| (n[k] - expected[k]).abs() < 1e-6), "{p:?}: {n:?}");
        }
    }
}
