//! Times draws from one camera and from 49 (a profiling aid).
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::DVec3;
use prob_grid::{CameraGridConfig, SceneGridConfig, Shape, update};
use std::time::Instant;
use view_sampler::{Interpolation, SamplerConfig, UniformSchedule, ViewSampler};

fn main() {
    let k = Intrinsics { fx: 2892.0, fy: 2883.0, cx: 823.0, cy: 619.0, skew: 0.0 };
    let cams: Vec<PinholeCamera> = (0..49)
        .map(|i| {
            let a = i as f64 * 0.1;
            PinholeCamera::look_at(DVec3::new(2.5 * a.cos(), 2.5 * a.sin(), 1.3), DVec3::ZERO, DVec3::Z, k, 1600, 1200, PixelCenters::Integer)
                .unwrap()
        })
        .collect();
    let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
    for n_cams in [1, 49] {
        for interpolation in [Interpolation::Nearest, Interpolation::Linear] {
            let small = std::env::var("SMALL").is_ok();
            let cg = if small { CameraGridConfig { ru: 32, rv: 32, rl: 64, ..Default::default() } } else { CameraGridConfig::default() };
            let grids = update(&sphere, 200.0, &cams[..n_cams], &SceneGridConfig::default(), &cg).unwrap();
            let sampler = ViewSampler::new(grids.cameras, SamplerConfig { interpolation, schedule: UniformSchedule { fractions: vec![0.0] } });
            let (batch, steps) = (65_536, 32);
            let t = Instant::now();
            let mut count = 0;
            for step in 0..steps {
                count += sampler.sample_batch(batch, 0.0, 1, step).len();
            }
            let secs = t.elapsed().as_secs_f64();
            println!("{n_cams} cameras, {interpolation:?}: {:.1} M samples/s ({count} rays in batches of {batch})", count as f64 / secs / 1e6);
        }
    }
}
