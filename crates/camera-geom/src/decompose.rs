//! `P = K[R|t]` ↔ (K, R, t), with the conventions NeuS gets from OpenCV.

use crate::rigid::orthonormalize_rows;
use crate::{CameraError, Intrinsics, Rigid3};
use glam::{DMat3, DVec3};

/// Decomposes a 3×4 projection matrix (row-major) into intrinsics and `camera_from_world`.
///
/// Conventions (identical to `cv2.decomposeProjectionMatrix` followed by `K /= K[2,2]`, as NeuS
/// and IDR do, whenever det(P[:, :3]) > 0): K upper triangular with a positive diagonal,
/// normalised so K₃₃ = 1; R a proper rotation. P is defined up to scale, so a P with
/// det(P[:, :3]) < 0 is negated first (OpenCV would return a negative K₃₃ and NeuS then a
/// negative focal length; we return the same camera with positive focals).
///
/// The RQ factorisation is Gram–Schmidt from the bottom row of M = P[:, :3]:
/// r₃ = m₃/‖m₃‖, then m₂ and m₁ are orthogonalised against the rows already found.
pub fn decompose_projection(p: &[[f64; 4]; 3]) -> Result<(Intrinsics, Rigid3), CameraError> {
    if !p.iter().flatten().all(|v| v.is_finite()) {
        return Err(CameraError::NonFinite { what: "projection matrix" });
    }
    let mut m = [DVec3::new(p[0][0], p[0][1], p[0][2]), DVec3::new(p[1][0], p[1][1], p[1][2]), DVec3::new(p[2][0], p[2][1], p[2][2])];
    let mut p4 = DVec3::new(p[0][3], p[1][3], p[2][3]);
    let det = m[0].dot(m[1].cross(m[2]));
    let scale = m[0].length() * m[1].length() * m[2].length();
    if scale == 0.0 || (det / scale).abs() < 1e-12 {
        return Err(CameraError::SingularProjection { det: if scale == 0.0 { 0.0 } else { det / scale } });
    }
    if det < 0.0 {
        m = [-m[0], -m[1], -m[2]];
        p4 = -p4;
    }
    let k33 = m[2].length();
    let r3 = m[2] / k33;
    let k23 = m[1].dot(r3);
    let w2 = m[1] - k23 * r3;
    let k22 = w2.length();
    let r2 = w2 / k22;
    let k13 = m[0].dot(r3);
    let k12 = m[0].dot(r2);
    let w1 = m[0] - k13 * r3 - k12 * r2;
    let k11 = w1.length();
    let r1 = w1 / k11;
    // Rows r1, r2, r3 → glam column-major matrix.
    let rotation = orthonormalize_rows(&DMat3::from_cols(r1, r2, r3).transpose());
    let intrinsics = Intrinsics { fx: k11 / k33, fy: k22 / k33, cx: k13 / k33, cy: k23 / k33, skew: k12 / k33 };
    // p4 = k33·K·t  ⇒  t = K⁻¹ p4 / k33.
    let k = intrinsics.matrix();
    let translation = k.inverse() * (p4 / k33);
    let camera_from_world = Rigid3 { rotation, translation };
    Ok((intrinsics, camera_from_world))
}

/// `P = K[R|t]` (3×4, row-major).
pub fn projection_from_parts(intrinsics: &Intrinsics, camera_from_world: &Rigid3) -> [[f64; 4]; 3] {
    let k = intrinsics.matrix();
    let kr = k * camera_from_world.rotation;
    let kt = k * camera_from_world.translation;
    let mut out = [[0.0; 4]; 3];
    for (i, row) in out.iter_mut().enumerate() {
        let r = kr.row(i);
        *row = [r.x, r.y, r.z, kt[i]];
    }
    out
}
