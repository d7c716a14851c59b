//! The similarity that best maps one point set onto another: to compare a reconstruction made
//! in one frame (e.g. COLMAP's) with ground truth in another, align the two sets of camera
//! centres and carry the mesh across ([`similarity`]), then optionally refine by ICP on the
//! surfaces themselves ([`refine_icp`]), as the Tanks and Temples evaluation does after its
//! trajectory alignment: camera centres estimated by structure from motion carry their own
//! error (a few tenths of a degree, a fraction of a percent of the rig), which would otherwise
//! be charged to the reconstruction.

/// `b ≈ scale · rotation · a + translation`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Uniform scale.
    pub scale: f64,
    /// Rotation, row-major.
    pub rotation: [[f64; 3]; 3],
    /// Translation.
    pub translation: [f64; 3],
}

impl Similarity {
    /// The identity.
    pub const IDENTITY: Similarity = Similarity { scale: 1.0, rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], translation: [0.0; 3] };

    /// `self ∘ first`: applies `first`, then `self`.
    pub fn after(&self, first: &Similarity) -> Similarity {
        let (a, b) = (&self.rotation, &first.rotation);
        let rotation = std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| a[i][k] * b[k][j]).sum()));
        Similarity { scale: self.scale * first.scale, rotation, translation: self.apply(first.translation) }
    }

    /// Applies the similarity to a point.
    pub fn apply(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotate(p);
        std::array::from_fn(|i| self.scale * r[i] + self.translation[i])
    }

    /// Applies its rotation alone (a direction: a normal keeps its length).
    pub fn rotate(&self, v: [f64; 3]) -> [f64; 3] {
        let r = &self.rotation;
        std::array::from_fn(|i| r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2])
    }
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn mean(points: &[[f64; 3]]) -> [f64; 3] {
    let n = points.len() as f64;
    let s = points.iter().fold([0.0; 3], |acc, p| [acc[0] + p[0], acc[1] + p[1], acc[2] + p[2]]);
    s.map(|v| v / n)
}

/// The rotation of a quaternion `[w, x, y, z]` (normalised first), row-major.
pub fn rotation_from_quaternion(q: [f64; 4]) -> [[f64; 3]; 3] {
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let [w, x, y, z] = q.map(|v| v / n);
    [
        [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y)],
        [2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x)],
        [2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y)],
    ]
}

/// The similarity minimising Σ |s R aᵢ + t − bᵢ|² (Umeyama; the rotation by Horn's quaternion
/// method, the largest eigenvector of his 4 × 4 matrix by Jacobi sweeps). `None` when the sets
/// differ in size, have fewer than 3 points, either has no spread, or the points are collinear
/// (the rotation about their line is then undetermined).
pub fn similarity(a: &[[f64; 3]], b: &[[f64; 3]]) -> Option<Similarity> {
    if a.len() != b.len() || a.len() < 3 {
        return None;
    }
    let (ma, mb) = (mean(a), mean(b));
    let mut s = [[0.0; 3]; 3];
    for (p, q) in a.iter().zip(b) {
        let (p, q) = (sub(*p, ma), sub(*q, mb));
        for i in 0..3 {
            for j in 0..3 {
                s[i][j] += p[i] * q[j];
            }
        }
    }
    let [[sxx, sxy, sxz], [syx, syy, syz], [szx, szy, szz]] = s;
    let mut m = [
        [sxx + syy + szz, syz - szy, szx - sxz, sxy - syx],
        [syz - szy, sxx - syy - szz, sxy + syx, szx + sxz],
        [szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy],
        [sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz],
    ];
    let mut v = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]];
    for _ in 0..100 {
        for p in 0..4 {
            for q in p + 1..4 {
                if m[p][q].abs() < 1e-300 {
                    continue;
                }
                let theta = (m[q][q] - m[p][p]) / (2.0 * m[p][q]);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let (c, s) = (1.0 / (t * t + 1.0).sqrt(), t / (t * t + 1.0).sqrt());
                for k in 0..4 {
                    let (kp, kq) = (m[k][p], m[k][q]);
                    m[k][p] = c * kp - s * kq;
                    m[k][q] = s * kp + c * kq;
                }
                for k in 0..4 {
                    let (pk, qk) = (m[p][k], m[q][k]);
                    m[p][k] = c * pk - s * qk;
                    m[q][k] = s * pk + c * qk;
                }
                for k in 0..4 {
                    let (kp, kq) = (v[k][p], v[k][q]);
                    v[k][p] = c * kp - s * kq;
                    v[k][q] = s * kp + c * kq;
                }
            }
        }
    }
    let mut order = [0usize, 1, 2, 3];
    order.sort_by(|&i, &j| m[j][j].total_cmp(&m[i][i]));
    let best = order[0];
    // Points on a line leave the rotation about it free: the top two eigenvalues then agree.
    let (top, second, spread) = (m[order[0]][order[0]], m[order[1]][order[1]], (0..4).map(|i| m[i][i].abs()).fold(0.0, f64::max));
    if !(top - second > 1e-9 * spread) {
        return None;
    }
    let rotation = rotation_from_quaternion([v[0][best], v[1][best], v[2][best], v[3][best]]);
    let rotated = |p: [f64; 3]| -> [f64; 3] { std::array::from_fn(|i| rotation[i][0] * p[0] + rotation[i][1] * p[1] + rotation[i][2] * p[2]) };
    let dot = |x: [f64; 3], y: [f64; 3]| x[0] * y[0] + x[1] * y[1] + x[2] * y[2];
    let num: f64 = a.iter().zip(b).map(|(p, q)| dot(sub(*q, mb), rotated(sub(*p, ma)))).sum();
    let den: f64 = a.iter().map(|p| dot(sub(*p, ma), sub(*p, ma))).sum();
    let scale = num / den;
    if !(den > 0.0 && scale > 0.0 && scale.is_finite()) {
        return None;
    }
    let rma = rotated(ma);
    Some(Similarity { scale, rotation, translation: std::array::from_fn(|i| mb[i] - scale * rma[i]) })
}

/// The outcome of [`refine_icp`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IcpRefinement {
    /// The refined similarity (applied to the moving points, after the starting one).
    pub similarity: Similarity,
    /// Iterations run.
    pub iterations: usize,
    /// RMS distance of the matched pairs (under the last threshold) before and after.
    pub rms_before: f64,
    /// See `rms_before`.
    pub rms_after: f64,
    /// Matched pairs at the last iteration.
    pub pairs: usize,
}

/// Similarity ICP (point to point, with scale, Umeyama per step) of `moving` onto `fixed`,
/// starting from `start`: each step matches every moving point (at most `max_points` of them,
/// taken evenly) to its nearest fixed point, keeps the pairs closer than the stage's threshold,
/// and solves for the similarity of those pairs. The thresholds fall from the first to the last
/// of `thresholds` (coarse to fine, as Tanks and Temples' evaluation does); each stage runs until
/// the update moves points by less than 1e-6 of the threshold, or 30 steps. `None` when a stage
/// has fewer than 3 usable pairs or the pairs do not determine a similarity.
pub fn refine_icp(
    moving: &[[f32; 3]],
    fixed: &crate::PointCloud,
    fixed_points: &[[f32; 3]],
    start: Similarity,
    thresholds: &[f64],
    max_points: usize,
) -> Option<IcpRefinement> {
    let stride = moving.len().div_ceil(max_points.max(1)).max(1);
    let sample: Vec<[f64; 3]> = moving.iter().step_by(stride).map(|p| p.map(f64::from)).collect();
    let mut current = start;
    let (mut iterations, mut rms_before, mut rms_after, mut pairs_used) = (0, f64::NAN, f64::NAN, 0);
    let last = thresholds.len().saturating_sub(1);
    for (stage, &threshold) in thresholds.iter().enumerate() {
        for _ in 0..30 {
            let moved: Vec<[f32; 3]> = sample.iter().map(|p| current.apply(*p).map(|c| c as f32)).collect();
            let nearest = fixed.nearest(&moved);
            let (mut a, mut b) = (Vec::new(), Vec::new());
            let mut sum_sq = 0.0;
            for (p, (d, i)) in moved.iter().zip(&nearest) {
                if f64::from(*d) < threshold {
                    a.push(p.map(f64::from));
                    b.push(fixed_points[*i].map(f64::from));
                    sum_sq += f64::from(*d).powi(2);
                }
            }
            if a.len() < 3 {
                return None;
            }
            let rms = (sum_sq / a.len() as f64).sqrt();
            if iterations == 0 {
                rms_before = rms;
            }
            let step = similarity(&a, &b)?;
            current = step.after(&current);
            iterations += 1;
            if stage == last {
                pairs_used = a.len();
                rms_after = (a.iter().zip(&b).map(|(p, q)| (0..3).map(|k| (step.apply(*p)[k] - q[k]).powi(2)).sum::<f64>()).sum::<f64>()
                    / a.len() as f64)
                    .sqrt();
            }
            // How far the step moved the matched points, at most.
            let moved_by = a.iter().map(|p| (0..3).map(|k| (step.apply(*p)[k] - p[k]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
            if moved_by < 1e-6 * threshold {
                break;
            }
        }
    }
    Some(IcpRefinement { similarity: current, iterations, rms_before, rms_after, pairs: pairs_used })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn similarity_recovers_a_known_scale_rotation_and_translation() {
        let truth = Similarity { scale: 2.5, rotation: rotation_from_quaternion([0.9, 0.1, -0.3, 0.2]), translation: [1.0, -2.0, 0.5] };
        let a: Vec<[f64; 3]> = (0..20).map(|i| [(i as f64 * 0.7).sin(), (i as f64 * 1.3).cos(), i as f64 * 0.1 - 1.0]).collect();
        let b: Vec<[f64; 3]> = a.iter().map(|p| truth.apply(*p)).collect();
        let s = similarity(&a, &b).unwrap();
        assert!((s.scale - truth.scale).abs() < 1e-9);
        for i in 0..3 {
            assert!((s.translation[i] - truth.translation[i]).abs() < 1e-9);
            for j in 0..3 {
                assert!((s.rotation[i][j] - truth.rotation[i][j]).abs() < 1e-9);
            }
        }
        assert!(similarity(&a[..2], &b[..2]).is_none());
        assert!(similarity(&[[1.0; 3]; 4], &b[..4]).is_none());
        assert!(similarity(&a[..4], &[[1.0; 3]; 4]).is_none(), "no spread in b: scale 0");
        let line: Vec<[f64; 3]> = (0..6).map(|i| [i as f64, 2.0 * i as f64, 1.0]).collect();
        let moved: Vec<[f64; 3]> = line.iter().map(|p| truth.apply(*p)).collect();
        assert!(similarity(&line, &moved).is_none(), "collinear points leave a rotation free");
    }

    #[test]
    fn icp_undoes_a_small_similarity_between_two_samplings_of_one_surface() {
        // Two different samplings of a bumpy sphere (no point in common); the moving one is
        // displaced by a small similarity, as a structure-from-motion frame would leave it.
        let surface = |u: f64, v: f64| -> [f64; 3] {
            let (theta, phi) = (u * std::f64::consts::PI, v * 2.0 * std::f64::consts::PI);
            let r = 1.0 + 0.15 * (3.0 * phi).sin() * (2.0 * theta).sin();
            [r * theta.sin() * phi.cos(), r * theta.sin() * phi.sin(), r * theta.cos()]
        };
        let grid = |n: usize, shift: f64| -> Vec<[f64; 3]> {
            (0..n)
                .flat_map(|i| (0..2 * n).map(move |j| ((i as f64 + shift) / n as f64, (j as f64 + shift) / (2 * n) as f64)))
                .map(|(u, v)| surface(u, v))
                .collect()
        };
        let fixed: Vec<[f32; 3]> = grid(120, 0.5).iter().map(|p| p.map(|c| c as f32)).collect();
        let offset = Similarity { scale: 1.01, rotation: rotation_from_quaternion([1.0, 0.01, -0.008, 0.012]), translation: [0.03, -0.02, 0.025] };
        let moving: Vec<[f32; 3]> = grid(100, 0.25).iter().map(|p| offset.apply(*p).map(|c| c as f32)).collect();
        let cloud = crate::PointCloud::new(&fixed).unwrap();
        let r = refine_icp(&moving, &cloud, &fixed, Similarity::IDENTITY, &[0.2, 0.05, 0.02], 5000).unwrap();
        // The refined similarity undoes the offset: a point of the surface comes back well
        // within the samplings' spacing (~0.026; point-to-point ICP between different samplings
        // keeps a fraction of it), and far closer than the offset had moved it (0.064).
        let worst = grid(20, 0.1)
            .iter()
            .map(|p| {
                let back = r.similarity.apply(offset.apply(*p));
                (0..3).map(|k| (back[k] - p[k]).powi(2)).sum::<f64>().sqrt()
            })
            .fold(0.0, f64::max);
        let displaced = grid(20, 0.1).iter().map(|p| (0..3).map(|k| (offset.apply(*p)[k] - p[k]).powi(2)).sum::<f64>().sqrt()).fold(0.0, f64::max);
        assert!(worst < 0.01 && worst < displaced / 5.0, "residual {worst} after ICP, {displaced} before");
        assert!(r.rms_after < r.rms_before, "{r:?}");
        // Composition: (a ∘ b)(p) = a(b(p)).
        let p = [0.3, -0.7, 1.1];
        let (ab, direct) = (offset.after(&r.similarity).apply(p), offset.apply(r.similarity.apply(p)));
        assert!((0..3).all(|k| (ab[k] - direct[k]).abs() < 1e-12));
    }
}
