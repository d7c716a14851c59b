//! view-sampler on its own: draw guided rays for an analytic sphere seen by two cameras, check
//! where they land, and evaluate pdfs. No backbone, no dataset.
//!
//! `cargo run --release -p view-sampler --example guided_rays`
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, ray_sphere};
use glam::DVec3;
use prob_grid::{CameraGridConfig, SceneGridConfig, Shape, update};
use view_sampler::{SamplerConfig, ViewSampler};

fn main() {
    let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
    let cameras = [DVec3::new(0.0, -3.0, 0.5), DVec3::new(2.5, 1.0, 1.0)]
        .map(|eye| PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).expect("valid camera"));
    let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
    let grids = update(&sphere, 500.0, &cameras, &SceneGridConfig::default(), &CameraGridConfig::default()).expect("valid configuration");
    let sampler = ViewSampler::new(grids.cameras, SamplerConfig::default());

    // At the start of training the schedule draws 20 % uniform and 80 % guided rays.
    let rays = sampler.sample_batch(10_000, 0.0, 42, 0);
    let (mut guided, mut on_sphere, mut depth_error) = (0, 0, 0.0);
    for r in rays.iter().filter(|r| r.guided) {
        guided += 1;
        let camera = &cameras[r.camera as usize];
        let ray = camera.ray_through_pixel(r.pixel_coords);
        if let Some((t_near, _)) = ray_sphere(&ray, DVec3::ZERO, 0.5) {
            on_sphere += 1;
            let depth = r.depth.expect("a guided sampler gives every ray a depth").depth;
            depth_error += (depth as f64 - t_near * camera.depth_per_distance(ray.direction)).abs();
        }
    }
    println!("{} rays: {guided} guided, {:.1} % of them through the sphere's silhouette", rays.len(), 100.0 * on_sphere as f64 / guided as f64);
    println!("mean |λ̃ − depth of the first hit| = {:.4} (logistic scale 1/s = {:.4})", depth_error / on_sphere as f64, 1.0 / 500.0);
    let r = rays.iter().find(|r| r.guided).expect("some guided ray");
    let d = &sampler.cameras()[r.camera as usize];
    let depth = r.depth.expect("a guided sampler gives every ray a depth").depth;
    println!(
        "first guided ray: camera {}, pixel {:?}, λ̃ = {:.4}, pdf(pixel) = {:.3e}/px², pdf(λ̃ | pixel) = {:.3}",
        r.camera,
        r.pixel,
        depth,
        d.pdf_pixel(r.pixel_coords),
        d.pdf_depth(r.pixel_coords, depth as f64)
    );
}
