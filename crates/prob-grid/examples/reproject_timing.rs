//! Times the reprojection of one update into one camera (a profiling aid).
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::DVec3;
use prob_grid::{CameraGridConfig, SceneGridConfig, Shape, evaluate, reproject};
use std::time::Instant;

fn main() {
    let k = Intrinsics { fx: 2892.0, fy: 2883.0, cx: 823.0, cy: 619.0, skew: 0.0 };
    let camera = PinholeCamera::look_at(DVec3::new(0.9, -2.0, 1.8), DVec3::ZERO, DVec3::Z, k, 1600, 1200, PixelCenters::Integer).unwrap();
    let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
    let active = evaluate(&sphere, 200.0, &SceneGridConfig::default()).unwrap();
    for (ru, rv, rl) in [(1, 1, 1), (8, 8, 8), (64, 64, 128)] {
        let config = CameraGridConfig { ru, rv, rl, ..Default::default() };
        let t = Instant::now();
        let mut total = 0.0;
        for _ in 0..5 {
            total += reproject(&active, &camera, &config).total();
        }
        let per = t.elapsed().as_secs_f64() / 5.0;
        let n = active.points.len() * active.offsets.len();
        println!("{ru}×{rv}×{rl}: {:.1} ms for {n} sub-cells = {:.2} ns each (total {total:.3e})", per * 1e3, per * 1e9 / n as f64);
    }
}
