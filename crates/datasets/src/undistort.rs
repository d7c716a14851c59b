//! Lens undistortion to a pinhole camera by bilinear remapping.
//!
//! psneus models pinhole cameras only; real captures (COLMAP's SIMPLE_RADIAL, RADIAL, OPENCV
//! models) have lens distortion. [`Undistortion`] resamples such an image into a pinhole image of
//! the same size: the principal point stays, the focal length is scaled by one factor (both axes)
//! chosen as the widest view for which **every output pixel samples inside the source image**, so
//! the result has no blank border. The plan is computed from the intrinsics alone (no pixels), so
//! that cameras can be read without decoding images.
//!
//! # Conventions
//! - Continuous pixel coordinates put the centre of pixel (i, j) at (i + ½, j + ½)
//!   ([`camera_geom::PixelCenters::HalfInteger`], COLMAP's and OpenCV-remap's convention after
//!   the half-pixel shift). A bilinear sample at `q` reads the four pixels around it, so it stays
//!   inside the image exactly when `q ∈ [½, w − ½] × [½, h − ½]`.
//! - Distortion acts on normalised image coordinates `(x, y) = (X/Z, Y/Z)` of the camera frame,
//!   as in COLMAP (`src/colmap/sensor/models.h`, `OpenCVCameraModel::Distortion`) and OpenCV:
//!   `r² = x² + y²`, `x_d = x (1 + k1 r² + k2 r⁴) + 2 p1 x y + p2 (r² + 2 x²)`,
//!   `y_d = y (1 + k1 r² + k2 r⁴) + 2 p2 x y + p1 (r² + 2 y²)`; then `pixel = K_source · (x_d, y_d, 1)`.

use crate::images::{Mask, RgbImage};
use camera_geom::Intrinsics;
use glam::DVec2;
use rayon::prelude::*;

/// Brown–Conrady lens distortion with two radial (`k1`, `k2`) and two tangential (`p1`, `p2`)
/// coefficients: OpenCV's first four and COLMAP's OPENCV model. SIMPLE_RADIAL is `k1` alone,
/// RADIAL `k1` and `k2`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Distortion {
    /// Radial coefficient of r².
    pub k1: f64,
    /// Radial coefficient of r⁴.
    pub k2: f64,
    /// Tangential coefficient p1.
    pub p1: f64,
    /// Tangential coefficient p2.
    pub p2: f64,
}

impl Distortion {
    /// No distortion (a pinhole camera).
    pub const NONE: Distortion = Distortion { k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0 };

    /// Whether every coefficient is exactly zero (the camera is a pinhole: no resampling).
    pub fn is_none(&self) -> bool {
        *self == Distortion::NONE
    }

    /// Whether every coefficient is finite.
    pub fn is_finite(&self) -> bool {
        [self.k1, self.k2, self.p1, self.p2].iter().all(|v| v.is_finite())
    }

    /// Distorts normalised image coordinates (undistorted → distorted).
    pub fn distort(&self, undistorted: DVec2) -> DVec2 {
        let DVec2 { x, y } = undistorted;
        let (x2, y2, xy) = (x * x, y * y, x * y);
        let r2 = x2 + y2;
        let radial = 1.0 + r2 * (self.k1 + self.k2 * r2);
        DVec2::new(x * radial + 2.0 * self.p1 * xy + self.p2 * (r2 + 2.0 * x2), y * radial + 2.0 * self.p2 * xy + self.p1 * (r2 + 2.0 * y2))
    }

    /// Undistorts normalised image coordinates (distorted → undistorted) by Newton's method from
    /// the distorted point; exact to ~1e-14 inside the region where the distortion is monotone.
    pub fn undistort(&self, distorted: DVec2) -> DVec2 {
        let mut p = distorted;
        for _ in 0..50 {
            let residual = self.distort(p) - distorted;
            if residual.length_squared() < 1e-30 {
                break;
            }
            // Jacobian of `distort` at p.
            let DVec2 { x, y } = p;
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (self.k1 + self.k2 * r2);
            let d_radial = 2.0 * self.k1 + 4.0 * self.k2 * r2; // ∂radial/∂x = x·d_radial
            let j00 = radial + x * x * d_radial + 2.0 * self.p1 * y + 6.0 * self.p2 * x;
            let j01 = x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y;
            let j10 = x * y * d_radial + 2.0 * self.p2 * y + 2.0 * self.p1 * x;
            let j11 = radial + y * y * d_radial + 2.0 * self.p2 * x + 6.0 * self.p1 * y;
            let det = j00 * j11 - j01 * j10;
            if det.abs() < 1e-300 || !det.is_finite() {
                break;
            }
            p -= DVec2::new(j11 * residual.x - j01 * residual.y, -j10 * residual.x + j00 * residual.y) / det;
        }
        p
    }

    /// r² below which the radial part `r (1 + k1 r² + k2 r⁴)` grows with r (its derivative
    /// `1 + 3 k1 r² + 5 k2 r⁴` stays positive); beyond it the lens model folds back on itself and
    /// is meaningless. Infinite when it never folds.
    pub fn monotone_radius_squared(&self) -> f64 {
        let (a, b) = (5.0 * self.k2, 3.0 * self.k1);
        // Smallest positive root of a x² + b x + 1.
        if a == 0.0 {
            return if b < 0.0 { -1.0 / b } else { f64::INFINITY };
        }
        let disc = b * b - 4.0 * a;
        if disc < 0.0 {
            return f64::INFINITY;
        }
        let s = disc.sqrt();
        [(-b - s) / (2.0 * a), (-b + s) / (2.0 * a)].into_iter().filter(|x| *x > 0.0).fold(f64::INFINITY, f64::min)
    }
}

/// A resampling plan from a distorted camera to a pinhole camera of the same size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Undistortion {
    /// The source camera's intrinsics (continuous pixels, half-integer centres).
    pub source: Intrinsics,
    /// The source camera's lens distortion.
    pub distortion: Distortion,
    /// The pinhole intrinsics of the output: the source's principal point, focal lengths scaled
    /// by [`Undistortion::focal_scale`].
    pub target: Intrinsics,
    /// Image width (source and output).
    pub width: u32,
    /// Image height (source and output).
    pub height: u32,
}

impl Undistortion {
    /// Plans the undistortion of a `width`×`height` image taken with `source` and `distortion`.
    ///
    /// The output keeps the principal point and scales both focal lengths by the smallest factor
    /// `s` (the widest view) for which every output pixel centre maps inside the source's bilinear
    /// footprint `[½, w − ½] × [½, h − ½]` and inside the lens model's monotone region. The test
    /// runs on the output's border pixels (the map is a homeomorphism there, so the inside
    /// follows) and `s` is found by bisection to ~1e-12. `None` when no factor works (the
    /// principal point outside the image, non-finite values, absurd distortion).
    pub fn new(source: Intrinsics, distortion: Distortion, width: u32, height: u32) -> Option<Undistortion> {
        let finite = [source.fx, source.fy, source.cx, source.cy, source.skew].iter().all(|v| v.is_finite());
        if !finite || !distortion.is_finite() || source.fx <= 0.0 || source.fy <= 0.0 || width < 2 || height < 2 {
            return None;
        }
        let plan = |s: f64| Undistortion {
            source,
            distortion,
            target: Intrinsics { fx: source.fx * s, fy: source.fy * s, skew: source.skew * s, ..source },
            width,
            height,
        };
        let valid = |s: f64| plan(s).border_inside();
        let mut hi = 1.0;
        let mut steps = 0;
        while !valid(hi) {
            hi *= 2.0;
            steps += 1;
            if steps > 40 {
                return None;
            }
        }
        let mut lo = hi;
        steps = 0;
        while valid(lo) {
            lo *= 0.5;
            steps += 1;
            if steps > 40 {
                return None;
            }
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if valid(mid) {
                hi = mid;
            } else {
                lo = mid;
            }
            if hi - lo <= 1e-12 * hi {
                break;
            }
        }
        Some(plan(hi))
    }

    /// The factor applied to the focal lengths (> 1 zooms in: pincushion or inward-bending
    /// border; < 1 zooms out: barrel distortion).
    pub fn focal_scale(&self) -> f64 {
        self.target.fx / self.source.fx
    }

    /// Where the output's continuous pixel `target_pixel` samples the source image.
    pub fn source_pixel(&self, target_pixel: DVec2) -> DVec2 {
        let normalized = self.target.normalized_from_pixel(target_pixel);
        self.source.pixel_from_normalized(self.distortion.distort(normalized))
    }

    /// Where the source's continuous pixel `source_pixel` lands in the output (the inverse of
    /// [`Undistortion::source_pixel`]).
    pub fn target_pixel(&self, source_pixel: DVec2) -> DVec2 {
        let distorted = self.source.normalized_from_pixel(source_pixel);
        self.target.pixel_from_normalized(self.distortion.undistort(distorted))
    }

    /// Whether `q` is inside the source's bilinear footprint.
    fn inside(&self, q: DVec2) -> bool {
        let (w, h) = (self.width as f64, self.height as f64);
        q.x >= 0.5 && q.x <= w - 0.5 && q.y >= 0.5 && q.y <= h - 0.5
    }

    /// Every border pixel centre of the output samples inside the source, within the monotone
    /// region of the lens model.
    fn border_inside(&self) -> bool {
        let r2_max = self.distortion.monotone_radius_squared();
        let ok = |column: u32, row: u32| {
            let p = DVec2::new(column as f64 + 0.5, row as f64 + 0.5);
            let n = self.target.normalized_from_pixel(p);
            n.length_squared() < r2_max && self.inside(self.source.pixel_from_normalized(self.distortion.distort(n)))
        };
        let (w, h) = (self.width, self.height);
        (0..w).all(|c| ok(c, 0) && ok(c, h - 1)) && (0..h).all(|r| ok(0, r) && ok(w - 1, r))
    }

    /// Bilinear sampling position of output pixel (column, row): the top-left source pixel index
    /// and the weights of its right and lower neighbours, clamped into the footprint (the plan
    /// keeps every sample inside; the clamp only absorbs rounding).
    fn sample_at(&self, column: u32, row: u32) -> (usize, usize, f64, f64) {
        let q = self.source_pixel(DVec2::new(column as f64 + 0.5, row as f64 + 0.5));
        let x = (q.x - 0.5).clamp(0.0, (self.width - 1) as f64);
        let y = (q.y - 0.5).clamp(0.0, (self.height - 1) as f64);
        let x0 = (x.floor() as usize).min(self.width as usize - 2);
        let y0 = (y.floor() as usize).min(self.height as usize - 2);
        (x0, y0, x - x0 as f64, y - y0 as f64)
    }

    /// Remaps an image (bilinear, rounded to u8).
    ///
    /// # Panics
    /// If the image does not have the plan's size (the loaders check it first).
    pub fn remap_rgb(&self, source: &RgbImage) -> RgbImage {
        assert_eq!((source.width, source.height), (self.width, self.height), "remap_rgb: image size differs from the plan");
        let w = self.width as usize;
        let mut out = RgbImage::new(self.width, self.height);
        out.data.par_chunks_mut(3 * w).enumerate().for_each(|(row, line)| {
            for column in 0..w {
                let (x0, y0, fx, fy) = self.sample_at(column as u32, row as u32);
                let i00 = 3 * (y0 * w + x0);
                let i10 = i00 + 3;
                let i01 = i00 + 3 * w;
                let i11 = i01 + 3;
                for c in 0..3 {
                    let v = |i: usize| source.data[i + c] as f64;
                    let top = v(i00) + fx * (v(i10) - v(i00));
                    let bottom = v(i01) + fx * (v(i11) - v(i01));
                    line[3 * column + c] = (top + fy * (bottom - top)).round().clamp(0.0, 255.0) as u8;
                }
            }
        });
        out
    }

    /// Remaps a mask: bilinear interpolation of 0/1, foreground where ≥ ½.
    ///
    /// # Panics
    /// If the mask does not have the plan's size (the loaders check it first).
    pub fn remap_mask(&self, source: &Mask) -> Mask {
        assert_eq!((source.width, source.height), (self.width, self.height), "remap_mask: mask size differs from the plan");
        let mut out = Mask::new(self.width, self.height);
        for row in 0..self.height {
            for column in 0..self.width {
                let (x0, y0, fx, fy) = self.sample_at(column, row);
                let v = |dx: usize, dy: usize| source.get((x0 + dx) as u32, (y0 + dy) as u32) as u8 as f64;
                let top = v(0, 0) + fx * (v(1, 0) - v(0, 0));
                let bottom = v(0, 1) + fx * (v(1, 1) - v(0, 1));
                if top + fy * (bottom - top) >= 0.5 {
                    out.set(column, row, true);
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn undistort_inverts_distort() {
        let d = Distortion { k1: -0.2, k2: 0.05, p1: 0.001, p2: -0.002 };
        for p in [DVec2::new(0.3, -0.2), DVec2::new(-0.5, 0.4), DVec2::ZERO] {
            assert!((d.undistort(d.distort(p)) - p).length() < 1e-12);
        }
    }

    #[test]
    fn monotone_radius_of_barrel_distortion() {
        let d = Distortion { k1: -0.3, ..Distortion::NONE };
        assert!((d.monotone_radius_squared() - 1.0 / 0.9).abs() < 1e-12);
        assert_eq!(Distortion { k1: 0.1, k2: 0.01, ..Distortion::NONE }.monotone_radius_squared(), f64::INFINITY);
    }

    #[test]
    fn no_distortion_keeps_the_focal_length() {
        let k = Intrinsics { fx: 300.0, fy: 310.0, cx: 160.0, cy: 120.0, skew: 0.0 };
        let u = Undistortion::new(k, Distortion::NONE, 320, 240).unwrap();
        // Pixel centres sit ½ inside the image edge: the widest valid view is the source's.
        assert!((u.focal_scale() - 1.0).abs() < 1e-9, "{}", u.focal_scale());
    }
}
