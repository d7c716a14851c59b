//! prob-grid on its own: the probability grid of an analytic torus seen by one camera, printed
//! as an ASCII picture of the pixel marginal. No backbone, no dataset.
//!
//! `cargo run --release -p prob-grid --example sphere_grid`
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::DVec3;
use prob_grid::{CameraGridConfig, SceneGridConfig, Shape, ViewDependency, update};

fn main() {
    let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
    let camera =
        PinholeCamera::look_at(DVec3::new(0.0, -2.4, 1.6), DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).expect("a valid camera");
    let torus = Shape::Torus { center: DVec3::ZERO, major_radius: 0.5, minor_radius: 0.15 };
    let scene = SceneGridConfig::default(); // 128³ over [−1, 1]³, F = 2, sparse
    for view_dependency in [ViewDependency::Off, ViewDependency::Opaque] {
        let cameras = CameraGridConfig { ru: 48, rv: 24, rl: 64, view_dependency, ..Default::default() };
        let grids = update(&torus, 200.0, &[camera], &scene, &cameras).expect("valid configuration");
        let grid = &grids.cameras[0];
        let marginal = grid.pixel_marginal();
        let peak = marginal.iter().cloned().fold(0.0f32, f32::max);
        println!(
            "view dependency {view_dependency:?}: scene mass {:.3} (≈ torus area 4π²Rr = {:.3}), {} field queries",
            grids.scene_mass,
            4.0 * std::f64::consts::PI.powi(2) * 0.5 * 0.15,
            grids.field_queries
        );
        for iv in 0..grid.rv {
            let line: String = (0..grid.ru)
                .map(|iu| {
                    let t = marginal[iv * grid.ru + iu] / peak;
                    [' ', '.', ':', '-', '=', '+', '*', '#', '%', '@'][((t * 9.0).round() as usize).min(9)]
                })
                .collect();
            println!("|{line}|");
        }
    }
}
