//! Which points of an analytic truth the training views see: the observation mask of the DTU
//! evaluation, for the built-in scenes. DTU's truth is what its scanner saw and its evaluation
//! counts the mesh only inside that observed volume; a golden scene's truth is the whole surface,
//! so without a mask an underside that no photo shows (a plate on a table, a foot) weighs in the
//! Chamfer as much as what the photos show, and more training cannot reduce it.
//!
//! A truth point is observed when at least one training camera has it in front, inside its
//! image, and no surface in between (sphere tracing the analytic SDF from the camera's centre).
//! Points that share a cell of a 512³ grid over the bound and the octant of their normal share
//! one test (a cell is 0.004 across: the default protocol's spacing), so that the millions of
//! points of a fine protocol cost the tests of a few hundred thousand.

use camera_geom::PinholeCamera;
use glam::DVec3;
use prob_grid::Shape;
use rayon::prelude::*;
use std::collections::HashMap;

/// Cells per unit of the grid whose points share one test.
const CELLS_PER_UNIT: f64 = 256.0;
/// How far short of the point the tracing stops (normalised units): the point itself lies on
/// the surface.
const SLACK: f64 = 1e-3;
/// The SDF below which the tracing has hit a surface.
const HIT: f64 = 1e-5;

/// Whether `camera` sees `point` on the surface of `shape`: in front of it, inside its image, and
/// no surface of `shape` between its centre and `SLACK` short of the point.
pub fn sees(shape: &Shape, camera: &PinholeCamera, point: DVec3) -> bool {
    let pixel = camera.pixel_space_from_world(point);
    if pixel.z <= 0.0 || camera.nearest_pixel(pixel.truncate()).is_none() {
        return false;
    }
    let origin = camera.center_in_world();
    let length = (point - origin).length();
    shape.ray_hit(origin, (point - origin) / length, 0.0, length - SLACK, HIT).is_none()
}

/// One flag per point of `truth` (on the surface of `shape`): whether any of `cameras` sees it
/// ([`sees`]); points of one cell and normal octant share the test of the first of them.
pub fn observed(shape: &Shape, cameras: &[PinholeCamera], truth: &[[f32; 3]]) -> Vec<bool> {
    let key = |p: DVec3| {
        let cell = (p * CELLS_PER_UNIT).floor().as_ivec3();
        let n = shape.gradient(p);
        (cell, [n.x, n.y, n.z].map(|c| c >= 0.0))
    };
    let points: Vec<DVec3> = truth.iter().map(|p| glam::Vec3::from_array(*p).as_dvec3()).collect();
    let keys: Vec<_> = points.par_iter().map(|p| key(*p)).collect();
    let mut first: HashMap<_, usize> = HashMap::new();
    let tested: Vec<usize> = keys.iter().enumerate().filter_map(|(i, k)| first.insert(*k, i).is_none().then_some(i)).collect();
    let seen: HashMap<_, bool> = tested.par_iter().map(|&i| (keys[i], cameras.iter().any(|camera| sees(shape, camera, points[i])))).collect();
    keys.iter().map(|k| seen[k]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera_geom::{Intrinsics, PixelCenters};

    /// A 64 × 64 camera at `eye` looking at `target`, 60° across.
    fn camera(eye: DVec3, target: DVec3) -> PinholeCamera {
        let k = Intrinsics { fx: 55.4, fy: 55.4, cx: 32.0, cy: 32.0, skew: 0.0 };
        PinholeCamera::look_at(eye, target, DVec3::Z, k, 64, 64, PixelCenters::Integer).unwrap()
    }

    /// A plate seen from above: its top is observed, its underside (hidden by the plate from every
    /// camera above it) is not, and a camera looking away sees nothing.
    #[test]
    fn a_plate_seen_from_above_has_its_top_observed_and_not_its_underside() {
        let plate = Shape::Box { center: DVec3::ZERO, half_extents: DVec3::new(0.5, 0.5, 0.05) };
        let cameras: Vec<PinholeCamera> =
            (0..8).map(|k| camera(DVec3::new((k as f64 * 0.8).cos(), (k as f64 * 0.8).sin(), 2.5), DVec3::ZERO)).collect();
        let truth: Vec<[f32; 3]> = plate.sample_surface(4_000.0, 3).iter().map(|p| p.as_vec3().to_array()).collect();
        let flags = observed(&plate, &cameras, &truth);
        let share = |pick: &dyn Fn(&[f32; 3]) -> bool| {
            let chosen: Vec<bool> = truth.iter().zip(&flags).filter(|(p, _)| pick(p)).map(|(_, f)| *f).collect();
            chosen.iter().filter(|f| **f).count() as f64 / chosen.len() as f64
        };
        assert_eq!(share(&|p| p[2] > 0.049), 1.0, "the top");
        // The underside's points at its rim share cells with the sides (and are seen where the
        // rim is): away from it, none is observed.
        assert_eq!(share(&|p| p[2] < -0.049 && p[0].abs().max(p[1].abs()) < 0.49), 0.0, "the underside");
        assert!(share(&|p| p[2] < -0.049) < 0.01, "the underside with its rim");
        let side = share(&|p| p[2].abs() < 0.049);
        assert!(side > 0.5, "the sides, seen at a slant: {side}");
        let away = [camera(DVec3::new(0.0, 0.0, 2.5), DVec3::new(0.0, 0.0, 5.0))];
        assert!(observed(&plate, &away, &truth).iter().all(|f| !f), "a camera looking away sees nothing");
        assert!(!sees(&plate, &cameras[0], DVec3::new(0.0, 0.0, -0.05)) && sees(&plate, &cameras[0], DVec3::new(0.0, 0.0, 0.05)));
    }
}
