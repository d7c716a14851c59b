//! Rigid transforms `x ↦ R·x + t` with a proper rotation R.

use crate::CameraError;
use glam::{DMat3, DVec3};
use serde::{Deserialize, Serialize};

/// A rigid transform `x ↦ rotation · x + translation`. Named by what it maps, e.g.
/// `camera_from_world: Rigid3` takes `point_in_world` to `point_in_camera`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rigid3 {
    /// A proper rotation (det = +1).
    pub rotation: DMat3,
    /// Translation, applied after the rotation.
    pub translation: DVec3,
}

impl Rigid3 {
    /// The identity.
    pub const IDENTITY: Rigid3 = Rigid3 { rotation: DMat3::IDENTITY, translation: DVec3::ZERO };

    /// Applies the transform to a point.
    pub fn transform_point(&self, p: DVec3) -> DVec3 {
        self.rotation * p + self.translation
    }

    /// Applies the inverse transform to a point (`Rᵀ(p − t)`), without forming the inverse.
    pub fn inverse_transform_point(&self, p: DVec3) -> DVec3 {
        self.rotation.transpose() * (p - self.translation)
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Rigid3 {
        let rt = self.rotation.transpose();
        Rigid3 { rotation: rt, translation: -(rt * self.translation) }
    }

    /// `self ∘ other` (apply `other` first).
    pub fn compose(&self, other: &Rigid3) -> Rigid3 {
        Rigid3 { rotation: self.rotation * other.rotation, translation: self.rotation * other.translation + self.translation }
    }

    /// Checks finiteness and that the rotation is proper within `tolerance`
    /// (max |RᵀR − I| ≤ tolerance, det > 0), then re-orthonormalises it.
    pub fn validated(&self, tolerance: f64) -> Result<Rigid3, CameraError> {
        let r = self.rotation;
        if !r.is_finite() {
            return Err(CameraError::NonFinite { what: "rotation" });
        }
        if !self.translation.is_finite() {
            return Err(CameraError::NonFinite { what: "translation" });
        }
        let err = orthogonality_error(&r);
        let det = r.determinant();
        if err > tolerance || det <= 0.0 {
            return Err(CameraError::NotARotation { orthogonality_error: err, det });
        }
        Ok(Rigid3 { rotation: orthonormalize_rows(&r), translation: self.translation })
    }
}

/// max |RᵀR − I| over the entries.
pub(crate) fn orthogonality_error(r: &DMat3) -> f64 {
    let e = r.transpose() * *r - DMat3::IDENTITY;
    e.to_cols_array().iter().fold(0.0f64, |m, v| m.max(v.abs()))
}

/// Nearest-rotation clean-up of an almost orthonormal matrix: two passes of
/// `R ← R(3I − RᵀR)/2` (Newton–Schulz), quadratically convergent from ‖RᵀR − I‖ ≪ 1.
pub(crate) fn orthonormalize_rows(r: &DMat3) -> DMat3 {
    let mut r = *r;
    for _ in 0..3 {
        r = r * (DMat3::from_diagonal(DVec3::splat(3.0)) - r.transpose() * r) * 0.5;
    }
    r
}
