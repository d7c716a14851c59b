//! Properties of the sampler (pdfs, bounds, inverse round trips, histograms) and golden checks
//! against scenes whose silhouettes and depths are known.

use camera_geom::{DepthBounds, ImageSpaceBounds, Intrinsics, PinholeCamera, PixelCenters};
use datasets::golden::{self, GeometrySource, GoldenScene, GoldenSpec, rig::Rig};
use glam::{DVec2, DVec3, Vec3};
use prob_grid::{CameraGrid, CameraGridConfig, MeshSdf, SceneGridConfig, SdfField, Shape, TriangleMesh, ViewDependency, update};
use proptest::prelude::*;
use view_sampler::{CameraDistribution, Interpolation, SamplerConfig, UniformSchedule, ViewSampler};

fn test_camera() -> PinholeCamera {
    let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
    PinholeCamera::look_at(DVec3::new(0.0, -3.0, 0.0), DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap()
}

fn grid_from(values: Vec<f32>, ru: usize, rv: usize, rl: usize) -> CameraGrid {
    let camera = test_camera();
    let bounds = ImageSpaceBounds { u: [-0.5, 199.5], v: [-0.5, 149.5], depth: [2.0, 4.0] };
    CameraGrid { camera, bounds, ru, rv, rl, values, mass_outside: 0.0 }
}

fn arb_grid() -> impl Strategy<Value = (Vec<f32>, usize, usize, usize)> {
    (1usize..6, 1usize..6, 1usize..8).prop_flat_map(|(ru, rv, rl)| {
        // Values with many exact zeros, including whole empty columns.
        (proptest::collection::vec(prop_oneof![Just(0.0f32), 0.0f32..10.0], ru * rv * rl), Just(ru), Just(rv), Just(rl))
            .prop_filter("some mass", |(v, ..)| v.iter().sum::<f32>() > 1e-3)
    })
}

const INTERPOLATIONS: [Interpolation; 2] = [Interpolation::Nearest, Interpolation::Linear];

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    #[test]
    fn samples_are_in_bounds_with_consistent_pdf_and_invert(
        (values, ru, rv, rl) in arb_grid(), u0 in 0.0f64..1.0, u1 in 0.0f64..1.0, u2 in 0.0f64..1.0,
    ) {
        for interpolation in INTERPOLATIONS {
            let d = CameraDistribution::new(grid_from(values.clone(), ru, rv, rl), interpolation);
            let s = d.sample([u0, u1, u2]);
            let b = d.bounds();
            prop_assert!(s.pixel.x >= b.u[0] && s.pixel.x <= b.u[1] && s.pixel.y >= b.v[0] && s.pixel.y <= b.v[1]);
            prop_assert!(s.depth >= b.depth[0] && s.depth <= b.depth[1]);
            prop_assert!(s.pdf() > 0.0 && s.pdf().is_finite());
            // pdf() evaluates the density that sample() drew from (away from the far edges,
            // where the half-open cell lookup and the sampled edge value may differ).
            if s.pixel.x < b.u[1] - 1e-9 && s.pixel.y < b.v[1] - 1e-9 && s.depth < b.depth[1] - 1e-12 {
                let p = d.pdf(s.pixel, s.depth);
                prop_assert!((p - s.pdf()).abs() <= 1e-9 * s.pdf(), "{interpolation:?}: {p} vs {}", s.pdf());
                let back = d.invert(s.pixel, s.depth);
                for (a, b) in back.iter().zip([u0, u1, u2]) {
                    prop_assert!((a - b).abs() < 1e-5, "{interpolation:?}: invert {back:?} vs {:?}", [u0, u1, u2]);
                }
            }
        }
    }

    #[test]
    fn pdfs_integrate_to_one((values, ru, rv, rl) in arb_grid(), x in 0.0f64..1.0) {
        for interpolation in INTERPOLATIONS {
            let d = CameraDistribution::new(grid_from(values.clone(), ru, rv, rl), interpolation);
            let b = *d.bounds();
            let (du, dv, dl) = ((b.u[1] - b.u[0]) / ru as f64, (b.v[1] - b.v[0]) / rv as f64, (b.depth[1] - b.depth[0]) / rl as f64);
            // p(u) is constant per u cell and p(v | u) sums to 1 for any u, so evaluating at one
            // point per u cell (at a random offset) integrates exactly.
            let mut total = 0.0;
            for j in 0..ru {
                let pu = b.u[0] + (j as f64 + x) * du;
                for k in 0..rv {
                    total += d.pdf_pixel(DVec2::new(pu, b.v[0] + (k as f64 + 0.5) * dv)) * du * dv;
                }
            }
            prop_assert!((total - 1.0).abs() < 1e-5, "{interpolation:?}: Σ pdf_pixel = {total}");
            // p(λ | u, v) where the pixel has mass.
            let pixel = d.sample([x, 0.5, 0.5]).pixel;
            let sum: f64 = (0..rl).map(|l| d.pdf_depth(pixel, b.depth[0] + (l as f64 + 0.5) * dl) * dl).sum();
            prop_assert!((sum - 1.0).abs() < 1e-5, "{interpolation:?}: Σ pdf_depth = {sum}");
        }
    }
}

/// Pearson's chi-square of a histogram of 200 000 draws over the cells of a fixed grid against the
/// cell probabilities (integrated numerically from `pdf`), at a fixed seed.
#[test]
fn histogram_matches_pdf_by_chi_square() {
    let (ru, rv, rl) = (4, 3, 5);
    let values: Vec<f32> = (0..ru * rv * rl).map(|i| ((i * 7919) % 13) as f32 * if i % 5 == 0 { 0.0 } else { 1.0 }).collect();
    for interpolation in INTERPOLATIONS {
        let d = CameraDistribution::new(grid_from(values.clone(), ru, rv, rl), interpolation);
        let b = *d.bounds();
        let size = [(b.u[1] - b.u[0]) / ru as f64, (b.v[1] - b.v[0]) / rv as f64, (b.depth[1] - b.depth[0]) / rl as f64];
        let cell = |x: f64, o: f64, s: f64, n: usize| (((x - o) / s) as usize).min(n - 1);
        let n = 200_000;
        let mut counts = vec![0usize; ru * rv * rl];
        let mut state = 0x1234_5678_9abc_def0u64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..n {
            let s = d.sample([uniform(), uniform(), uniform()]);
            let idx =
                (cell(s.pixel.x, b.u[0], size[0], ru) * rv + cell(s.pixel.y, b.v[0], size[1], rv)) * rl + cell(s.depth, b.depth[0], size[2], rl);
            counts[idx] += 1;
        }
        // Expected probabilities: midpoint rule with 32 points per axis in each cell.
        let m = 32;
        let mut chi2 = 0.0;
        let mut dof = 0;
        for iu in 0..ru {
            for iv in 0..rv {
                for il in 0..rl {
                    let mut p = 0.0;
                    for a in 0..m {
                        for c in 0..m {
                            let px = DVec2::new(
                                b.u[0] + (iu as f64 + (a as f64 + 0.5) / m as f64) * size[0],
                                b.v[0] + (iv as f64 + (c as f64 + 0.5) / m as f64) * size[1],
                            );
                            // p(λ | u, v) is constant along λ within a cell.
                            p += d.pdf(px, b.depth[0] + (il as f64 + 0.5) * size[2]);
                        }
                    }
                    let expected = p / (m * m) as f64 * size[0] * size[1] * size[2] * n as f64;
                    let observed = counts[(iu * rv + iv) * rl + il] as f64;
                    if expected > 0.0 {
                        chi2 += (observed - expected).powi(2) / expected;
                        dof += 1;
                    } else {
                        assert_eq!(observed, 0.0, "{interpolation:?}: draws in a zero-probability cell");
                    }
                }
            }
        }
        // 99.9th percentile of χ² with dof − 1 degrees of freedom, by Wilson–Hilferty.
        let k = (dof - 1) as f64;
        let critical = k * (1.0 - 2.0 / (9.0 * k) + 3.09 * (2.0 / (9.0 * k)).sqrt()).powi(3);
        assert!(chi2 < critical, "{interpolation:?}: χ² = {chi2} ≥ {critical} ({dof} cells)");
    }
}

#[test]
fn empty_grid_falls_back_to_uniform_without_nan() {
    let d = CameraDistribution::new(grid_from(vec![0.0; 4 * 4 * 4], 4, 4, 4), Interpolation::Linear);
    assert!(d.is_uniform_fallback());
    let s = d.sample([0.3, 0.9, 0.999_999]);
    assert!(s.pdf().is_finite() && s.pdf() > 0.0);
    let uniform = 1.0 / (200.0 * 150.0 * 2.0);
    assert!((s.pdf() - uniform).abs() < 1e-9 * uniform);
    let sampler = ViewSampler::new(vec![grid_from(vec![0.0; 64], 4, 4, 4)], SamplerConfig::default());
    assert_eq!(sampler.fallback_cameras(), vec![0]);
    for r in sampler.sample_batch(1000, 0.5, 1, 2) {
        let d = r.depth.expect("a guided sampler gives every ray a depth");
        assert!(d.depth.is_finite() && d.pdf > 0.0 && r.pixel[0] < 200 && r.pixel[1] < 150);
    }
}

#[test]
fn uniform_rays_on_an_empty_column_get_uniform_depths() {
    let mut values = vec![0.0f32; 2 * 2 * 4];
    values[0] = 1.0; // only column (0, 0) has mass
    let d = CameraDistribution::new(grid_from(values, 2, 2, 4), Interpolation::Nearest);
    assert!(d.sample_depth(DVec2::new(150.0, 100.0), 0.5).is_none());
    let sampler = ViewSampler::new(
        vec![grid_from(vec![0.0; 16].into_iter().enumerate().map(|(i, _)| if i == 0 { 1.0 } else { 0.0 }).collect(), 2, 2, 4)],
        SamplerConfig { schedule: UniformSchedule { fractions: vec![1.0] }, ..Default::default() },
    );
    let rays = sampler.sample_batch(500, 0.0, 3, 0);
    assert!(rays.iter().all(|r| !r.guided && r.depth.is_some_and(|d| d.depth >= 2.0 && d.depth <= 4.0 && d.pdf > 0.0)));
}

#[test]
fn batches_do_not_depend_on_thread_count_and_follow_the_schedule() {
    let grids = update(
        &Shape::Sphere { center: DVec3::ZERO, radius: 0.5 },
        100.0,
        &[test_camera(), test_camera()],
        &SceneGridConfig { resolution: 32, ..Default::default() },
        &CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() },
    )
    .unwrap();
    let sampler = ViewSampler::new(grids.cameras, SamplerConfig::default());
    let run = |threads| rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap().install(|| sampler.sample_batch(5000, 0.6, 42, 17));
    let (a, b) = (run(1), run(2));
    assert_eq!(a, b);
    // Progress 0.6 → third quarter → 60 % uniform.
    assert_eq!(a.iter().filter(|r| !r.guided).count(), 3000);
    assert_ne!(a, sampler.sample_batch(5000, 0.6, 42, 18), "another step draws other rays");
}

// ----- golden checks ------------------------------------------------------------------------

struct GoldenReport {
    inside_dilated: f64,
    median_depth_error_cells: f64,
}

/// Draws guided rays and compares them with the scene's masks and depth maps.
fn golden_check(g: &GoldenScene, field: &dyn SdfField, s: f32, view_dependency: ViewDependency) -> GoldenReport {
    let cameras: Vec<PinholeCamera> = g.scene.views.iter().map(|v| v.camera).collect();
    let camera_config = CameraGridConfig { depth_bounds: DepthBounds::CentralRay, view_dependency, ..Default::default() };
    let grids = update(field, s, &cameras, &SceneGridConfig { resolution: 128, ..Default::default() }, &camera_config).unwrap();
    assert!(grids.empty_cameras.is_empty());
    let sampler = ViewSampler::new(grids.cameras, SamplerConfig { schedule: UniformSchedule { fractions: vec![0.0] }, ..Default::default() });
    let rays = sampler.sample_batch(20_000, 0.0, 11, 0);
    let (mut inside, mut errors) = (0usize, Vec::new());
    for r in &rays {
        let view = &g.scene.views[r.camera as usize];
        let cam = &view.camera;
        let dist = sampler.cameras()[r.camera as usize].bounds();
        let (ru, rv, rl) = sampler.cameras()[r.camera as usize].resolution();
        let cell_px = ((dist.u[1] - dist.u[0]) / ru as f64).max((dist.v[1] - dist.v[0]) / rv as f64).ceil() as i64;
        let mask = view.mask.as_ref().unwrap();
        let [c, row] = r.pixel.map(|x| x as i64);
        let hit = (-cell_px..=cell_px).any(|dy| {
            (-cell_px..=cell_px).any(|dx| {
                let (x, y) = (c + dx, row + dy);
                x >= 0 && y >= 0 && x < cam.width as i64 && y < cam.height as i64 && mask.get(x as u32, y as u32)
            })
        });
        inside += hit as usize;
        let depth = g.depths[r.camera as usize][(r.pixel[1] * cam.width + r.pixel[0]) as usize];
        if depth > 0.0 {
            let dl = (dist.depth[1] - dist.depth[0]) / rl as f64;
            errors.push((r.depth.expect("guided").depth as f64 - depth as f64).abs() / dl);
        }
    }
    errors.sort_by(f64::total_cmp);
    GoldenReport { inside_dilated: inside as f64 / rays.len() as f64, median_depth_error_cells: errors[errors.len() / 2] }
}

fn golden_spec(geometry: GeometrySource) -> GoldenSpec {
    let mut spec = GoldenSpec::new(geometry);
    spec.rig.rig = Rig::Dtu;
    spec.rig.count = 8;
    spec.rig.width = 200;
    spec.rig.height = 150;
    spec.surface_points = 100;
    spec
}

#[test]
fn golden_analytic_sphere_guides_rays_onto_the_silhouette_and_surface() {
    let g = golden::generate(&golden_spec(GeometrySource::Shape(prob_grid::ShapeName::Sphere))).unwrap();
    let golden::render::Geometry::Analytic(shape) = &g.geometry else { unreachable!() };
    // λ̃ is a draw from p̃(λ | u, v), not its mode: the logistic itself has a median
    // |λ − surface| of ln 3 / s, which is 0.70 depth cells at s = 100 (Δλ = 2/128 here). The
    // median error beyond that spread must stay within one cell.
    for s in [100.0f32, 300.0, 1000.0] {
        let r = golden_check(&g, shape, s, ViewDependency::default());
        let dl = 2.0 / 128.0;
        let spread = 3f64.ln() / s as f64 / dl;
        assert!(r.inside_dilated >= 0.97, "s {s}: {:.3} inside the dilated silhouette", r.inside_dilated);
        assert!(
            r.median_depth_error_cells <= 1.0 + spread,
            "s {s}: median depth error {:.2} cells (logistic spread {spread:.2})",
            r.median_depth_error_cells
        );
        if s >= 300.0 {
            assert!(r.median_depth_error_cells <= 1.0, "s {s}: median depth error {:.2} cells", r.median_depth_error_cells);
        }
    }
}

/// A watertight torus mesh (major radius 0.45, minor 0.18), written as OBJ.
fn torus_obj(dir: &std::path::Path) -> std::path::PathBuf {
    let (n, m) = (64, 32);
    let mut s = String::new();
    for i in 0..n {
        for j in 0..m {
            let (a, b) = (std::f64::consts::TAU * i as f64 / n as f64, std::f64::consts::TAU * j as f64 / m as f64);
            let ring = 0.45 + 0.18 * b.cos();
            s += &format!("v {} {} {}\n", ring * a.cos(), 0.18 * b.sin(), ring * a.sin());
        }
    }
    let idx = |i: usize, j: usize| (i % n) * m + (j % m) + 1;
    for i in 0..n {
        for j in 0..m {
            let (a, b, c, d) = (idx(i, j), idx(i + 1, j), idx(i + 1, j + 1), idx(i, j + 1));
            s += &format!("f {a} {d} {c}\nf {a} {c} {b}\n");
        }
    }
    let path = dir.join("torus.obj");
    std::fs::write(&path, s).unwrap();
    path
}

#[test]
fn golden_mesh_scene_guides_rays_onto_the_silhouette_and_surface() {
    let dir = tempfile_dir();
    let g = golden::generate(&golden_spec(GeometrySource::Mesh(torus_obj(&dir)))).unwrap();
    let mesh: TriangleMesh = g.mesh().unwrap().mesh.clone();
    let field = MeshSdf { mesh };
    // Sanity: the mesh SDF is ≈ 0 on the golden surface points.
    let pts: Vec<Vec3> = g.surface_points.iter().map(|p| p.as_vec3()).collect();
    let mut out = vec![0.0; pts.len()];
    field.sdf_batch(&pts, &mut out);
    assert!(out.iter().all(|d| d.abs() < 1e-4));
    let r = golden_check(&g, &field, 300.0, ViewDependency::default());
    assert!(r.inside_dilated >= 0.97, "{:.3} inside the dilated silhouette", r.inside_dilated);
    assert!(r.median_depth_error_cells <= 1.0, "median depth error {:.2} cells", r.median_depth_error_cells);
}

fn tempfile_dir() -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("psneus-sampler-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}
