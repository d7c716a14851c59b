//! A backbone that is not psneus's, trained with the estimator's two verbs alone: a sphere SDF
//! S(x) = |x − c| − r with four parameters learns the silhouettes of a hidden sphere from twelve
//! cameras. Each iteration: `update_due` (the guide, when its schedule says so, from the current
//! SDF) and `draw_rays` (rays with their coarse samples and λ̃); the SDF renders each ray's
//! opacity NeuS-style from its samples (plus a few around λ̃ for guided rays), and finite
//! differences give the gradient. No dataset, no psneus backbone.
//!
//! `cargo run --release -p view-sampler --example toy_sdf`
use camera_geom::{Intrinsics, PinholeCamera, PixelCenters, ray_sphere};
use glam::{DVec3, Vec3};
use prob_grid::SdfField;
use view_sampler::{DrawnRay, Estimator, EstimatorConfig};

/// The model: centre (3) and radius (1).
struct SphereSdf([f64; 4]);

impl SdfField for SphereSdf {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        let [x, y, z, r] = self.0;
        for (p, o) in points.iter().zip(out) {
            *o = ((p.as_dvec3() - DVec3::new(x, y, z)).length() - r) as f32;
        }
    }
}

/// NeuS opacity of a ray from the SDF at its sample depths at logistic scale `s`.
fn opacity(params: &[f64; 4], ray: &DrawnRay, s: f64) -> f64 {
    let (o, d) = (DVec3::from_array(ray.ray.origin.map(f64::from)), DVec3::from_array(ray.ray.direction.map(f64::from)));
    let mut depths: Vec<f64> = ray.ray.depths.iter().map(|&t| f64::from(t)).collect();
    if let Some(surface) = ray.surface.filter(|s| !s.background) {
        // A few samples around λ̃: where the guide says the surface is.
        depths.extend((-3..=3).map(|k| surface.distance + f64::from(k) * 0.01));
        depths.sort_by(f64::total_cmp);
    }
    let sdf = |t: f64| (o + t * d - DVec3::new(params[0], params[1], params[2])).length() - params[3];
    let cdf = |x: f64| 1.0 / (1.0 + (-s * x).exp());
    let mut transmittance = 1.0;
    for w in depths.windows(2) {
        let (a, b) = (cdf(sdf(w[0])), cdf(sdf(w[1])));
        let alpha = ((a - b) / a.max(1e-9)).clamp(0.0, 1.0);
        transmittance *= 1.0 - alpha;
    }
    1.0 - transmittance
}

fn main() {
    let truth = (DVec3::new(0.1, -0.05, 0.05), 0.4);
    let k = Intrinsics { fx: 110.0, fy: 110.0, cx: 47.5, cy: 35.5, skew: 0.0 };
    let cameras: Vec<PinholeCamera> = (0..12)
        .map(|i| {
            let a = std::f64::consts::TAU * i as f64 / 12.0;
            let eye = DVec3::new(2.5 * a.cos(), 2.5 * a.sin(), 0.8 * (a * 3.0).sin());
            PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 96, 72, PixelCenters::Integer).expect("a valid camera")
        })
        .collect();
    let mut estimator =
        Estimator::new(cameras, EstimatorConfig { skip_empty: false, updates: 10, ..Default::default() }).expect("a valid configuration");
    let mut params = [0.0, 0.0, 0.0, 0.7];
    let (steps, rays, lr) = (300u64, 256, 0.02);
    for step in 0..steps {
        let progress = step as f64 / steps as f64;
        let s = 20.0 + 180.0 * progress;
        // Verb 1: the guide, rebuilt from the current SDF when the schedule says so.
        if let Some(report) = estimator.update_due(progress, &SphereSdf(params), s as f32).expect("the update") {
            println!("step {step}: guide updated in {:.3} s (scene mass {:.3})", report.seconds, report.scene_mass);
        }
        // Verb 2: rays with coarse samples and λ̃ (one explicit uniform jitter per ray).
        let batch = estimator.draw_rays(rays, progress, 7, step, 32, &|i| ((i as f64 * 0.618_034) + step as f64 * 0.1) % 1.0);
        let cameras = estimator.cameras();
        let target: Vec<f64> = batch
            .iter()
            .map(|r| {
                let ray = cameras[r.sample.camera as usize].ray_through_pixel_index(r.sample.pixel[0], r.sample.pixel[1]);
                f64::from(u8::from(ray_sphere(&ray, truth.0, truth.1).is_some()))
            })
            .collect();
        let loss = |p: &[f64; 4]| -> f64 { batch.iter().zip(&target).map(|(r, t)| (opacity(p, r, s) - t).powi(2)).sum::<f64>() / batch.len() as f64 };
        let mut gradient = [0.0; 4];
        for (k, g) in gradient.iter_mut().enumerate() {
            let (mut plus, mut minus) = (params, params);
            plus[k] += 1e-4;
            minus[k] -= 1e-4;
            *g = (loss(&plus) - loss(&minus)) / 2e-4;
        }
        for (p, g) in params.iter_mut().zip(gradient) {
            *p -= lr * (1.0 - 0.9 * progress) * g.clamp(-5.0, 5.0);
        }
        if step % 50 == 0 || step + 1 == steps {
            println!("step {step}: loss {:.4}, centre {:.3?}, radius {:.3}", loss(&params), &params[..3], params[3]);
        }
    }
    let centre_error = (DVec3::new(params[0], params[1], params[2]) - truth.0).length();
    println!("centre error {centre_error:.4}, radius error {:.4} (truth: centre {:.2}, radius {})", (params[3] - truth.1).abs(), truth.0, truth.1);
}
