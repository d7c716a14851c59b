//! Reprojection and view dependency against closed forms, and the extremes.

use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::{DVec3, Vec3};
use prob_grid::*;

fn camera_at(eye: DVec3) -> PinholeCamera {
    let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
    PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap()
}

fn sphere() -> Shape {
    Shape::Sphere { center: DVec3::ZERO, radius: 0.5 }
}

fn scene(resolution: usize) -> SceneGridConfig {
    SceneGridConfig { resolution, ..Default::default() }
}

/// Sums p̃ in the 6×6 columns around the principal point (rays within 4° of the axis, so the
/// sphere is crossed almost head-on), split at depth `split`.
fn front_back(grid: &CameraGrid, split: f64) -> (f64, f64) {
    let (du, dv, dl) = grid.cell_sizes();
    let (iu, iv) = (((99.5 - grid.bounds.u[0]) / du) as usize, ((74.5 - grid.bounds.v[0]) / dv) as usize);
    let (mut front, mut back) = (0.0, 0.0);
    for u in iu - 3..iu + 3 {
        for v in iv - 3..iv + 3 {
            for il in 0..grid.rl {
                let depth = grid.bounds.depth[0] + (il as f64 + 0.5) * dl;
                let x = grid.values[grid.index(u, v, il)] as f64;
                if depth < split { front += x } else { back += x }
            }
        }
    }
    (front, back)
}

#[test]
fn mass_preserving_reprojection_conserves_mass() {
    let config = CameraGridConfig { weighting: Weighting::MassPreserving, view_dependency: ViewDependency::Off, ..Default::default() };
    let g = update(&sphere(), 200.0, &[camera_at(DVec3::new(0.0, -3.0, 0.0))], &scene(64), &config).unwrap();
    let grid = &g.cameras[0];
    let sum = grid.total() + grid.mass_outside;
    assert!((sum - g.scene_mass).abs() < 1e-4 * g.scene_mass, "{sum} vs {}", g.scene_mass);
    assert!(grid.mass_outside < 1e-6 * g.scene_mass, "the whole sphere is in view");
}

#[test]
fn inverse_square_weighting_is_depth_neutral_and_mass_weighting_is_not() {
    // Coarse columns and F = 4 so that each column holds many sub-cells: the Riemann sum's
    // quantisation (a sub-cell lands in one column whole) stays below 2%.
    let cam = camera_at(DVec3::new(0.0, -3.0, 0.0));
    let off = |weighting| CameraGridConfig { weighting, view_dependency: ViewDependency::Off, ru: 16, rv: 16, ..Default::default() };
    let fine = SceneGridConfig { partition: 4, ..scene(128) };
    let central = |grid: &CameraGrid| {
        let (mut f, mut b) = (0.0, 0.0);
        for (iu, iv) in [(7, 7), (7, 8), (8, 7), (8, 8)] {
            for il in 0..grid.rl {
                let depth = grid.bounds.depth[0] + (il as f64 + 0.5) * grid.cell_sizes().2;
                let x = grid.values[grid.index(iu, iv, il)] as f64;
                if depth < 3.0 { f += x } else { b += x }
            }
        }
        (f, b)
    };
    let g = update(&sphere(), 500.0, &[cam], &fine, &off(Weighting::InverseSquareDepth)).unwrap();
    let (f, b) = central(&g.cameras[0]);
    assert!((b / f - 1.0).abs() < 0.03, "η⁻²: back/front = {}", b / f);
    let g = update(&sphere(), 500.0, &[cam], &fine, &off(Weighting::MassPreserving)).unwrap();
    let (f, b) = central(&g.cameras[0]);
    let expect = (3.5f64 / 2.5).powi(2);
    assert!((b / f / expect - 1.0).abs() < 0.03, "mass: back/front = {} (expected {expect})", b / f);
}

#[test]
fn view_dependency_matches_closed_forms_behind_the_first_surface() {
    // Head-on through a sphere at large s: the naive density has optical depth 1 per crossing,
    // so the back surface is weighted e⁻¹ relative to the front; the opaque variant hides it.
    let cam = camera_at(DVec3::new(0.0, -3.0, 0.0));
    // Relative to the same grid without view dependency (whose back/front ratio is ≈ 1 up to
    // discretisation, see the test above).
    for s in [300.0f32, 2000.0] {
        let vd = |view_dependency| CameraGridConfig { view_dependency, ..Default::default() };
        let g = update(&sphere(), s, &[cam], &scene(128), &vd(ViewDependency::Off)).unwrap();
        let (f0, b0) = front_back(&g.cameras[0], 3.0);
        let g = update(&sphere(), s, &[cam], &scene(128), &vd(ViewDependency::Quadrature)).unwrap();
        let (f, b) = front_back(&g.cameras[0], 3.0);
        // The front is weighted by ∫φe^{−∫φ} = 1 − e⁻¹, the back by e⁻¹(1 − e⁻¹).
        assert!((f / f0 - (1.0 - (-1f64).exp())).abs() < 0.05, "s {s}: front weight {}", f / f0);
        let ratio = (b / f) / (b0 / f0);
        assert!((ratio - (-1f64).exp()).abs() < 0.03, "s {s}: quadrature back/front = {ratio}");
        let g = update(&sphere(), s, &[cam], &scene(128), &vd(ViewDependency::Opaque)).unwrap();
        let (f, b) = front_back(&g.cameras[0], 3.0);
        // ~0 up to quantisation (a column that gets 95% of its front mass keeps 5% transmittance).
        assert!((b / f) / (b0 / f0) < 0.05, "s {s}: opaque back/front = {}", b / f);
        // The literal sum has no cell length: with psneus's grid values (masses · λ⁻², ≪ 1 per
        // cell) it occludes only weakly. It must still reduce the back relative to the front.
        let g = update(&sphere(), s, &[cam], &scene(128), &vd(ViewDependency::PaperSum)).unwrap();
        let (f, b) = front_back(&g.cameras[0], 3.0);
        let ratio = (b / f) / (b0 / f0);
        assert!(f > 0.0 && ratio < 1.0 && ratio > 0.5, "paper sum: back/front = {ratio}");
    }
}

#[test]
fn sparse_camera_grids_equal_dense_within_tolerance() {
    let cams = [camera_at(DVec3::new(0.0, -3.0, 0.0)), camera_at(DVec3::new(2.0, 1.0, 1.5))];
    let config = CameraGridConfig { ru: 32, rv: 32, rl: 64, ..Default::default() };
    for s in [20.0f32, 200.0, 2000.0] {
        let dense = update(&sphere(), s, &cams, &SceneGridConfig { evaluation: Evaluation::Dense, ..scene(64) }, &config).unwrap();
        let sparse = update(&sphere(), s, &cams, &scene(64), &config).unwrap();
        for (d, sp) in dense.cameras.iter().zip(&sparse.cameras) {
            let diff: f64 = d.values.iter().zip(&sp.values).map(|(a, b)| (*a as f64 - *b as f64).abs()).sum();
            assert!(diff <= 1e-4 * d.total(), "s {s}: Σ|dense − sparse| = {diff} of {}", d.total());
        }
    }
}

fn assert_finite(g: &ProbabilityGrids, what: &str) {
    for (i, c) in g.cameras.iter().enumerate() {
        assert!(c.values.iter().all(|v| v.is_finite() && *v >= 0.0), "{what}: camera {i} has a bad value");
        assert!(c.mass_outside.is_finite(), "{what}");
    }
}

#[test]
fn extremes_never_give_nan_inf_or_panic() {
    let cams = [
        camera_at(DVec3::new(0.0, -3.0, 0.0)),
        camera_at(DVec3::new(0.0, -0.55, 0.0)),                            // 0.05 from the surface
        camera_at(DVec3::new(0.0, -0.2, 0.1)),                             // inside the sphere and the bound
        camera_at(DVec3::new(0.0, 0.0, 0.0) + DVec3::new(1e-3, 0.0, 0.0)), // at the centre
    ];
    let small = CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() };
    for vd in [ViewDependency::Off, ViewDependency::PaperSum, ViewDependency::Quadrature, ViewDependency::Opaque] {
        for weighting in [Weighting::InverseSquareDepth, Weighting::MassPreserving] {
            let config = CameraGridConfig { view_dependency: vd, weighting, ..small.clone() };
            for s in [1e-3f32, 1.0, 200.0, 1e5, 1e7] {
                let g = update(&sphere(), s, &cams, &scene(32), &config).unwrap();
                assert_finite(&g, &format!("{vd:?} {weighting:?} s {s}"));
                assert!(g.cameras[0].total() > 0.0, "{vd:?} s {s}: the outside camera sees the sphere");
            }
        }
    }
    // One-cell grids.
    let one = CameraGridConfig { ru: 1, rv: 1, rl: 1, ..Default::default() };
    let g = update(&sphere(), 200.0, &cams, &scene(1), &one).unwrap();
    assert_finite(&g, "one cell");
    // An all-zero (everywhere far from a surface) field and a NaN field.
    struct Constant(f32);
    impl SdfField for Constant {
        fn sdf_batch(&self, _: &[Vec3], out: &mut [f32]) {
            out.fill(self.0);
        }
    }
    let g = update(&Constant(10.0), 200.0, &cams, &scene(16), &small).unwrap();
    assert_finite(&g, "empty");
    assert_eq!(g.empty_cameras, vec![0, 1, 2, 3]);
    let g = update(&Constant(f32::NAN), 200.0, &cams, &scene(16), &small).unwrap();
    assert_finite(&g, "NaN field");
    assert!(g.nan_values > 0);
}

#[test]
fn initial_sphere_has_mass_in_every_camera_that_sees_it() {
    let cams: Vec<_> = (0..6).map(|i| camera_at(DVec3::new((i as f64).cos() * 3.0, (i as f64).sin() * 3.0, 0.5))).collect();
    let g = initial_sphere(0.5, 50.0, &cams, &scene(32), &CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() }).unwrap();
    assert!(g.empty_cameras.is_empty());
}

#[test]
fn scalar_and_simd_projection_paths_conserve_mass_for_every_partition() {
    // F = 1 takes the scalar path; F = 2 fills one 8-lane vector; F = 3 (27 sub-cells) pads.
    let config = CameraGridConfig { weighting: Weighting::MassPreserving, view_dependency: ViewDependency::Off, ..Default::default() };
    let cam = camera_at(DVec3::new(0.3, -2.5, 0.8));
    let mut totals = Vec::new();
    for partition in [1, 2, 3] {
        let scene = SceneGridConfig { resolution: 48, partition, ..Default::default() };
        let g = update(&sphere(), 200.0, &[cam], &scene, &config).unwrap();
        let sum = g.cameras[0].total() + g.cameras[0].mass_outside;
        assert!((sum - g.scene_mass).abs() < 1e-4 * g.scene_mass, "F {partition}: {sum} vs {}", g.scene_mass);
        totals.push(g.cameras[0].total());
    }
    // The same mass lands in the grid whatever F (the sphere is fully in view).
    assert!((totals[0] - totals[2]).abs() < 1e-3 * totals[0], "{totals:?}");
}

/// Regression: the 8-lane projection computed the flat cell index in f32, exact only below 2²⁴
/// cells; above that the mass of odd indices landed in a neighbouring cell (or past the end).
#[test]
fn camera_grids_above_two_to_the_24_cells_index_the_right_cell() {
    let cam = camera_at(DVec3::new(0.0, -3.0, 0.0));
    // 1000 × 1000 × 32 = 3.2·10⁷ cells > 2²⁴ ≈ 1.68·10⁷.
    let config = CameraGridConfig {
        ru: 1000,
        rv: 1000,
        rl: 32,
        weighting: Weighting::MassPreserving,
        view_dependency: ViewDependency::Off,
        ..Default::default()
    };
    assert!(config.ru * config.rv * config.rl > 1 << 24);
    // Points spread over the image, each with 8 tiny sub-cell offsets (the 8-lane path) that
    // stay in the point's camera cell.
    let points: Vec<Vec3> = (0..40).map(|i| Vec3::new(-0.45 + 0.023 * i as f32, 0.13 - 0.011 * i as f32, 0.3 - 0.017 * i as f32)).collect();
    let active = ActiveCells {
        masses: vec![1.0; points.len()],
        offsets: (0..8).map(|k| Vec3::new((k & 1) as f32, ((k >> 1) & 1) as f32, (k >> 2) as f32) * 1e-7).collect(),
        subcell_size: 1e-7,
        total_mass: points.len() as f64,
        cells: points.len(),
        points: points.clone(),
        ..Default::default()
    };
    let grid = reproject(&active, &cam, &config);
    let (du, dv, dl) = grid.cell_sizes();
    let mut checked = 0;
    for p in &points {
        let x = cam.pixel_space_from_world(p.as_dvec3());
        let f = [(x.x - grid.bounds.u[0]) / du, (x.y - grid.bounds.v[0]) / dv, (x.z - grid.bounds.depth[0]) / dl];
        // Points within f32 rounding of a cell border may land on either side: not a check.
        if f.iter().any(|c| (c - c.round()).abs() < 1e-3) {
            continue;
        }
        checked += 1;
        let (iu, iv, il) = (f[0] as usize, f[1] as usize, f[2] as usize);
        let value = grid.values[grid.index(iu, iv, il)];
        assert!((value - 1.0).abs() < 1e-5, "point {p}: cell ({iu}, {iv}, {il}) holds {value}, expected its whole mass 1");
    }
    assert!(checked >= 30, "only {checked} points away from cell borders");
    assert!((grid.total() - points.len() as f64).abs() < 1e-3);
}
