//! Camera rigs for golden scenes, in the normalised frame (z up, object at the origin).

use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
use glam::{DMat3, DVec3};
use prob_grid::field::uniform_direction;
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use serde::{Deserialize, Serialize};

/// Where the cameras stand.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Rig {
    /// DTU-like: a spherical cap in front of and above the object (half-angle 35°), camera
    /// centres 2.77–2.97 from the origin, as in DTU scan 24's normalised frame.
    Dtu,
    /// A full sphere of directions (Fibonacci lattice) at distance 3.
    Sphere,
    /// Random directions, distances in [2.4, 3.4], look-at target jittered by ±0.05, roll ±15°.
    Random,
    /// A full ring around the object (every azimuth, evenly spaced) at 25° elevation and
    /// distance 2.8, as a turntable capture is.
    Ring,
}

impl Rig {
    /// Parses `dtu`, `sphere`, `random`, `ring`.
    pub fn by_name(name: &str) -> Option<Rig> {
        match name {
            "dtu" => Some(Rig::Dtu),
            "sphere" => Some(Rig::Sphere),
            "random" => Some(Rig::Random),
            "ring" => Some(Rig::Ring),
            _ => None,
        }
    }
}

/// Size and count of a rig's cameras.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RigOptions {
    /// Which rig.
    pub rig: Rig,
    /// Number of cameras.
    pub count: usize,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Seed (distance jitter, random rig).
    pub seed: u64,
}

/// The cameras of a rig. Focal length `1.8·height` (a vertical half field of view of 15.5°, like
/// DTU's 2.4·height but wide enough for objects of radius 0.75 at distance 2.8), principal point
/// at the image centre, integer pixel centres (the IDR convention golden scenes are written in).
pub fn cameras(options: &RigOptions) -> Vec<PinholeCamera> {
    let RigOptions { rig, count, width, height, seed } = *options;
    let f = 1.8 * height as f64;
    let intrinsics = Intrinsics { fx: f, fy: f, cx: (width as f64 - 1.0) / 2.0, cy: (height as f64 - 1.0) / 2.0, skew: 0.0 };
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let golden_angle = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    (0..count)
        .map(|i| {
            let (eye, target, up) = match rig {
                Rig::Dtu => {
                    let axis = DVec3::new(0.0, -0.8, 0.6).normalize();
                    let cos_max = 35f64.to_radians().cos();
                    // Fibonacci spiral on the cap: uniform in cos θ.
                    let cos_t = 1.0 - (1.0 - cos_max) * (i as f64 + 0.5) / count as f64;
                    let sin_t = (1.0 - cos_t * cos_t).sqrt();
                    let phi = golden_angle * i as f64;
                    let e1 = axis.cross(DVec3::Z).normalize();
                    let e2 = e1.cross(axis);
                    let dir = cos_t * axis + sin_t * (phi.cos() * e1 + phi.sin() * e2);
                    let distance = 2.77 + 0.2 * rng.random::<f64>();
                    (dir * distance, DVec3::ZERO, DVec3::Z)
                }
                Rig::Sphere => {
                    let z = 1.0 - 2.0 * (i as f64 + 0.5) / count as f64;
                    let r = (1.0 - z * z).sqrt();
                    let phi = golden_angle * i as f64;
                    (3.0 * DVec3::new(r * phi.cos(), r * phi.sin(), z), DVec3::ZERO, DVec3::Z)
                }
                Rig::Ring => {
                    let azimuth = 2.0 * std::f64::consts::PI * i as f64 / count as f64;
                    let elevation = 25f64.to_radians();
                    let dir = DVec3::new(elevation.cos() * azimuth.cos(), elevation.cos() * azimuth.sin(), elevation.sin());
                    (dir * 2.8, DVec3::ZERO, DVec3::Z)
                }
                Rig::Random => {
                    let dir = uniform_direction(rng.random(), rng.random());
                    let distance = 2.4 + rng.random::<f64>();
                    let target = 0.05 * (2.0 * DVec3::new(rng.random(), rng.random(), rng.random()) - DVec3::ONE);
                    let roll = (2.0 * rng.random::<f64>() - 1.0) * 15f64.to_radians();
                    let up = DMat3::from_axis_angle(dir, roll) * DVec3::Z;
                    (dir * distance, target, up)
                }
            };
            PinholeCamera::look_at(eye, target, up, intrinsics, width, height, PixelCenters::Integer).expect("rig cameras are valid by construction")
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_rig_sees_the_origin_in_front_near_the_image_centre() {
        for rig in [Rig::Dtu, Rig::Sphere, Rig::Random, Rig::Ring] {
            let cams = cameras(&RigOptions { rig, count: 49, width: 160, height: 120, seed: 3 });
            assert_eq!(cams.len(), 49);
            for c in &cams {
                let p = c.pixel_space_from_world(DVec3::ZERO);
                assert!(p.z > 2.0 && p.z < 3.5, "{rig:?}: depth {}", p.z);
                assert!((p.x - 79.5).abs() < 15.0 && (p.y - 59.5).abs() < 15.0, "{rig:?}: {p}");
            }
        }
        let dtu = cameras(&RigOptions { rig: Rig::Dtu, count: 49, width: 160, height: 120, seed: 3 });
        for c in &dtu {
            let d = c.center_in_world().length();
            assert!((2.77..=2.97).contains(&d), "{d}");
            assert!(c.center_in_world().z > 0.0, "DTU cameras look from above");
        }
    }
}
