//! Micro-benchmarks of the sampler's hot paths (divan):
//! `cargo bench -p view-sampler --bench sampler`.
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::DVec3;
use prob_grid::{CameraGridConfig, SceneGridConfig, Shape, evaluate, reproject, update};
use view_sampler::{CameraDistribution, Interpolation, SamplerConfig, UniformSchedule, ViewSampler};

fn main() {
    divan::main();
}

fn camera(i: usize) -> PinholeCamera {
    let k = Intrinsics { fx: 2892.0, fy: 2883.0, cx: 823.0, cy: 619.0, skew: 0.0 };
    let a = i as f64 * 0.1;
    PinholeCamera::look_at(DVec3::new(2.5 * a.cos(), 2.5 * a.sin(), 1.3), DVec3::ZERO, DVec3::Z, k, 1600, 1200, PixelCenters::Integer).unwrap()
}

const SPHERE: Shape = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };

/// Reprojection of one update (128³, F = 2, s = 200) into one 64×64×128 camera grid.
#[divan::bench]
fn reproject_one_camera(bencher: divan::Bencher) {
    let active = evaluate(&SPHERE, 200.0, &SceneGridConfig::default()).unwrap();
    let cam = camera(0);
    let config = CameraGridConfig::default();
    bencher.bench(|| reproject(&active, &cam, &config));
}

/// Building one camera's CDFs.
#[divan::bench]
fn build_cdfs_one_camera(bencher: divan::Bencher) {
    let grids = update(&SPHERE, 200.0, &[camera(0)], &SceneGridConfig::default(), &CameraGridConfig::default()).unwrap();
    bencher.with_inputs(|| grids.cameras[0].clone()).bench_values(|g| CameraDistribution::new(g, Interpolation::Linear));
}

/// 4096 guided rays over `n` cameras (throughput per ray).
#[divan::bench(args = [1, 49])]
fn draw_4096_rays(bencher: divan::Bencher, n: usize) {
    let cams: Vec<_> = (0..n).map(camera).collect();
    let grids = update(&SPHERE, 200.0, &cams, &SceneGridConfig::default(), &CameraGridConfig::default()).unwrap();
    let sampler = ViewSampler::new(grids.cameras, SamplerConfig { schedule: UniformSchedule { fractions: vec![0.0] }, ..Default::default() });
    let mut step = 0;
    bencher.counter(divan::counter::ItemsCount::new(4096usize)).bench_local(|| {
        step += 1;
        sampler.sample_batch(4096, 0.0, 1, step)
    });
}
