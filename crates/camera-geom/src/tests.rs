use super::*;
use glam::{DQuat, DVec2, DVec3};
use proptest::prelude::*;

fn arb_rotation() -> impl Strategy<Value = DMat3> {
    (-1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0, -1.0f64..1.0)
        .prop_filter("non-degenerate quaternion", |(a, b, c, d)| a * a + b * b + c * c + d * d > 0.05)
        .prop_map(|(a, b, c, d)| DMat3::from_quat(DQuat::from_xyzw(a, b, c, d).normalize()))
}

fn arb_intrinsics() -> impl Strategy<Value = Intrinsics> {
    (50.0f64..5000.0, 0.5f64..2.0, -200.0f64..2000.0, -200.0f64..2000.0, -20.0f64..20.0).prop_map(|(fx, aspect, cx, cy, skew)| Intrinsics {
        fx,
        fy: fx * aspect,
        cx,
        cy,
        skew,
    })
}

fn arb_camera() -> impl Strategy<Value = PinholeCamera> {
    (arb_intrinsics(), arb_rotation(), -5.0f64..5.0, -5.0f64..5.0, -5.0f64..5.0).prop_map(|(k, r, tx, ty, tz)| {
        let camera_from_world = Rigid3 { rotation: r, translation: DVec3::new(tx, ty, tz) };
        PinholeCamera::new(k, 1600, 1200, camera_from_world, PixelCenters::Integer).unwrap()
    })
}

fn rel_err(a: DVec3, b: DVec3) -> f64 {
    (a - b).length() / b.length().max(1.0)
}

proptest! {
    #[test]
    fn f_inverse_of_f_is_identity(cam in arb_camera(), u in -2.0f64..2.0, v in -2.0f64..2.0, depth in 1e-3f64..100.0) {
        // Build a point in front of the camera, then round-trip it through f and f⁻¹.
        let x = cam.world_from_image_space(DVec3::new(u, v, depth));
        let back = cam.world_from_image_space(cam.image_space_from_world(x));
        prop_assert!(rel_err(back, x) < 1e-12, "{back} vs {x}");
        let pix = cam.pixel_space_from_world(x);
        let back = cam.world_from_pixel_space(pix);
        prop_assert!(rel_err(back, x) < 1e-11, "{back} vs {x}");
    }

    #[test]
    fn jacobian_det_matches_finite_differences(cam in arb_camera(), u in -1.0f64..1.0, v in -1.0f64..1.0, depth in 0.05f64..20.0) {
        let q = DVec3::new(u, v, depth);
        let h = 1e-6;
        let col = |axis: usize| {
            let mut e = DVec3::ZERO;
            e[axis] = h;
            (cam.world_from_image_space(q + e) - cam.world_from_image_space(q - e)) / (2.0 * h)
        };
        let jac = DMat3::from_cols(col(0), col(1), col(2));
        let det = jac.determinant();
        let expected = jacobian_det_world_from_image_space(q);
        prop_assert!((det - expected).abs() <= 1e-6 * expected.max(1.0), "{det} vs {expected}");

        // Pixel space: λ²/(fx fy).
        let p = cam.pixel_space_from_world(cam.world_from_image_space(q));
        let hp = DVec3::new(1e-3, 1e-3, 1e-6);
        let colp = |axis: usize| {
            let mut e = DVec3::ZERO;
            e[axis] = hp[axis];
            (cam.world_from_pixel_space(p + e) - cam.world_from_pixel_space(p - e)) / (2.0 * hp[axis])
        };
        let det = DMat3::from_cols(colp(0), colp(1), colp(2)).determinant();
        let expected = cam.jacobian_det_world_from_pixel_space(depth);
        prop_assert!((det - expected).abs() <= 1e-5 * expected, "{det} vs {expected}");
    }

    #[test]
    fn decomposition_recovers_k_r_t(cam in arb_camera(), scale in prop_oneof![-50.0f64..-0.01, 0.01f64..50.0]) {
        let mut p = cam.projection_matrix();
        for row in p.iter_mut() { for v in row.iter_mut() { *v *= scale; } }
        let (k, camera_from_world) = decompose_projection(&p).unwrap();
        let k0 = cam.intrinsics;
        for (a, b) in [(k.fx, k0.fx), (k.fy, k0.fy), (k.cx, k0.cx), (k.cy, k0.cy), (k.skew, k0.skew)] {
            prop_assert!((a - b).abs() <= 1e-9 * b.abs().max(1.0), "{k:?} vs {k0:?}");
        }
        let dr = (camera_from_world.rotation - cam.camera_from_world.rotation).abs().to_cols_array();
        prop_assert!(dr.iter().all(|d| *d < 1e-9), "rotation {dr:?}");
        let dt = (camera_from_world.translation - cam.camera_from_world.translation).length();
        prop_assert!(dt < 1e-9 * cam.camera_from_world.translation.length().max(1.0), "translation off by {dt}");
    }

    #[test]
    fn ray_through_projected_point_passes_through_it(cam in arb_camera(), u in -1.0f64..1.0, v in -1.0f64..1.0, depth in 0.01f64..50.0) {
        let x = cam.world_from_image_space(DVec3::new(u, v, depth));
        let pix = cam.pixel_space_from_world(x);
        let ray = cam.ray_through_pixel(pix.truncate());
        let t = (x - ray.origin).dot(ray.direction);
        prop_assert!(t > 0.0);
        let miss = (ray.at(t) - x).length();
        prop_assert!(miss < 1e-9 * depth.max(1.0), "miss {miss}");
        // depth = t · (d · axis)
        let d = t * cam.depth_per_distance(ray.direction);
        prop_assert!((d - depth).abs() < 1e-9 * depth.max(1.0));
    }
}

fn dtu_like_camera(eye: DVec3) -> PinholeCamera {
    let k = Intrinsics { fx: 2892.3, fy: 2883.2, cx: 823.2, cy: 619.1, skew: 0.0 };
    PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 1600, 1200, PixelCenters::Integer).unwrap()
}

#[test]
fn look_at_centres_the_target() {
    let cam = dtu_like_camera(DVec3::new(0.3, -2.8, 0.9));
    let p = cam.pixel_space_from_world(DVec3::ZERO);
    assert!((p.x - 823.2).abs() < 1e-9 && (p.y - 619.1).abs() < 1e-9);
    assert!((p.z - DVec3::new(0.3, -2.8, 0.9).length()).abs() < 1e-12);
    // World up projects upwards in the image (smaller row).
    let up = cam.pixel_space_from_world(DVec3::new(0.0, 0.0, 0.1));
    assert!(up.y < p.y);
}

/// The footprint's square has the area spanned by the rays of neighbouring pixels at the
/// point's depth, and no pixel sees a point behind the camera.
#[test]
fn pixel_footprint_is_the_spacing_of_neighbouring_rays() {
    let eye = DVec3::new(0.3, -2.8, 0.9);
    let cam = dtu_like_camera(eye);
    let footprint = cam.pixel_footprint_at(DVec3::ZERO).unwrap();
    let depth = eye.length();
    let (a, b) = (cam.world_from_pixel_space(DVec3::new(823.2, 619.1, depth)), cam.world_from_pixel_space(DVec3::new(824.2, 619.1, depth)));
    let (c, d) = (cam.world_from_pixel_space(DVec3::new(823.2, 619.1, depth)), cam.world_from_pixel_space(DVec3::new(823.2, 620.1, depth)));
    let area_side = ((b - a).length() * (d - c).length()).sqrt();
    assert!((footprint - area_side).abs() < 1e-12, "{footprint} vs {area_side}");
    assert_eq!(cam.pixel_footprint_at(eye * 2.0), None);
    assert_eq!(cam.pixel_footprint_at(eye * 1.001), None);
}

#[test]
fn pixel_centre_conventions() {
    let mut cam = dtu_like_camera(DVec3::new(0.0, -3.0, 0.0));
    assert_eq!(cam.pixel_center(3, 4), DVec2::new(3.0, 4.0));
    assert_eq!(cam.nearest_pixel(DVec2::new(3.4, 4.6)), Some((3, 5)));
    assert_eq!(cam.nearest_pixel(DVec2::new(-0.6, 0.0)), None);
    cam.pixel_centers = PixelCenters::HalfInteger;
    assert_eq!(cam.pixel_center(3, 4), DVec2::new(3.5, 4.5));
    assert_eq!(cam.nearest_pixel(DVec2::new(3.9, 4.1)), Some((3, 4)));
    assert_eq!(cam.nearest_pixel(DVec2::new(4.1, 3.9)), Some((4, 3)));
    let b = cam.image_space_bounds(DVec3::ZERO, 1.0, DepthBounds::Tight, 1e-3);
    assert_eq!(b.u, [0.0, 1600.0]);
    let cam = dtu_like_camera(DVec3::new(0.0, -3.0, 0.0));
    let b = cam.image_space_bounds(DVec3::ZERO, 1.0, DepthBounds::Tight, 1e-3);
    assert_eq!(b.u, [-0.5, 1599.5]);
}

#[test]
fn downscaled_intrinsics_keep_rays_through_block_centres() {
    // A point projecting to the centre of new pixel (j, i) must project to the mean of the old
    // centres of its n×n block.
    for centers in [PixelCenters::Integer, PixelCenters::HalfInteger] {
        let k = Intrinsics { fx: 1000.0, fy: 900.0, cx: 400.3, cy: 300.7, skew: 2.0 };
        let n = 4;
        let k2 = k.downscaled(n, centers);
        let o = centers.offset();
        let (j, i) = (10.0, 7.0);
        let new_center = DVec2::new(j + o, i + o);
        let old_mean = DVec2::new(j * n as f64 + (n as f64 - 1.0) / 2.0 + o, i * n as f64 + (n as f64 - 1.0) / 2.0 + o);
        let a = k2.normalized_from_pixel(new_center);
        let b = k.normalized_from_pixel(old_mean);
        assert!((a - b).length() < 1e-12, "{centers:?}: {a} vs {b}");
    }
}

#[test]
fn depth_bounds_variants_agree_on_axis_and_differ_off_axis() {
    let cam = dtu_like_camera(DVec3::new(0.0, -3.0, 0.0));
    let a = cam.image_space_bounds(DVec3::ZERO, 1.0, DepthBounds::CentralRay, 1e-3);
    let b = cam.image_space_bounds(DVec3::ZERO, 1.0, DepthBounds::Tight, 1e-3);
    assert!((a.depth[0] - 2.0).abs() < 1e-9 && (a.depth[1] - 4.0).abs() < 1e-9);
    assert!((b.depth[0] - 2.0).abs() < 1e-9 && (b.depth[1] - 4.0).abs() < 1e-9);
    // Sphere centred 0.6 off the optical axis: the central ray sees a shorter chord.
    let a = cam.image_space_bounds(DVec3::new(0.6, 0.0, 0.0), 1.0, DepthBounds::CentralRay, 1e-3);
    let b = cam.image_space_bounds(DVec3::new(0.6, 0.0, 0.0), 1.0, DepthBounds::Tight, 1e-3);
    assert!((a.depth[0] - 2.2).abs() < 1e-9 && (a.depth[1] - 3.8).abs() < 1e-9, "{a:?}");
    assert!((b.depth[0] - 2.0).abs() < 1e-9 && (b.depth[1] - 4.0).abs() < 1e-9, "{b:?}");
}

#[test]
fn camera_inside_bound_sphere_gets_positive_depths() {
    let cam = dtu_like_camera(DVec3::new(0.0, -0.5, 0.0));
    for mode in [DepthBounds::CentralRay, DepthBounds::Tight] {
        let b = cam.image_space_bounds(DVec3::ZERO, 1.0, mode, 1e-3);
        assert!(b.depth[0] >= 1e-3 && b.depth[1] > b.depth[0], "{mode:?} {b:?}");
    }
    let ray = cam.ray_through_pixel_index(800, 600);
    let (near, far) = cam.near_far_in_sphere(&ray, DVec3::ZERO, 1.0, 1e-4).unwrap();
    assert!(near == 1e-4 && far > 1.0);
}

#[test]
fn ray_sphere_far_origin_keeps_precision() {
    let ray = Ray { origin: DVec3::new(0.0, 0.0, -1e8), direction: DVec3::Z };
    let (t0, t1) = ray_sphere(&ray, DVec3::new(1e-3, 0.0, 0.0), 1.0).unwrap();
    assert!((t1 - t0 - 2.0 * (1.0f64 - 1e-6).sqrt()).abs() < 1e-6);
    assert!(ray_sphere(&ray, DVec3::new(2.0, 0.0, 0.0), 1.0).is_none());
}

#[test]
fn construction_rejects_bad_values() {
    let k = Intrinsics { fx: 100.0, fy: 100.0, cx: 50.0, cy: 50.0, skew: 0.0 };
    let bad_k = Intrinsics { fx: 0.0, ..k };
    let r = Rigid3::IDENTITY;
    assert!(matches!(PinholeCamera::new(bad_k, 10, 10, r, PixelCenters::Integer), Err(CameraError::BadFocal { .. })));
    let nan_k = Intrinsics { cx: f64::NAN, ..k };
    assert!(matches!(PinholeCamera::new(nan_k, 10, 10, r, PixelCenters::Integer), Err(CameraError::NonFinite { .. })));
    let shear = Rigid3 { rotation: DMat3::from_cols(DVec3::X, DVec3::new(0.3, 1.0, 0.0), DVec3::Z), translation: DVec3::ZERO };
    assert!(matches!(PinholeCamera::new(k, 10, 10, shear, PixelCenters::Integer), Err(CameraError::NotARotation { .. })));
    let mirror = Rigid3 { rotation: DMat3::from_diagonal(DVec3::new(1.0, 1.0, -1.0)), translation: DVec3::ZERO };
    assert!(matches!(PinholeCamera::new(k, 10, 10, mirror, PixelCenters::Integer), Err(CameraError::NotARotation { .. })));
    assert!(matches!(PinholeCamera::new(k, 0, 10, r, PixelCenters::Integer), Err(CameraError::EmptyImage { .. })));
    let singular = [[1.0, 2.0, 3.0, 0.0], [2.0, 4.0, 6.0, 1.0], [0.0, 0.0, 1.0, 1.0]];
    assert!(matches!(decompose_projection(&singular), Err(CameraError::SingularProjection { .. })));
    let mut nan = singular;
    nan[0][3] = f64::INFINITY;
    assert!(matches!(decompose_projection(&nan), Err(CameraError::NonFinite { .. })));
}
