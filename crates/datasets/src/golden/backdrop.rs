//! What lies behind a golden scene's object: nothing (black, as DTU with masks), an environment
//! at infinity (a function of the ray's direction only, what NeRF++'s background model can
//! represent exactly), or a near surface that crosses the bound (a floor under the object, a wall
//! behind it, as DTU's table and walls are).
//!
//! Several kinds exist so that training without masks is not tuned to one backdrop: they differ
//! in frequency (22.5° and 45° checker cells, value noise of ~6° features, a smooth gradient),
//! contrast and depth. None of them is part of the object: masks, depth and normal maps and the
//! truth points are the object's alone.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

/// A golden scene's backdrop.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Backdrop {
    /// Black: nothing behind the object.
    None,
    /// At infinity: a lat-long checker of 22.5° cells with a soft modulation (the built-in
    /// scene's).
    Checker,
    /// At infinity: 45° checker cells of low contrast over a vertical gradient (sky bright above,
    /// ground dark below).
    CoarseChecker,
    /// At infinity: a smooth vertical gradient with a warm horizon band, no edges.
    Gradient,
    /// At infinity: three octaves of value noise on the direction (features of ~6°, high
    /// contrast), a backdrop with detail at every scale.
    Noise,
    /// Near: a textured floor (z = −0.75, below the object, crossing the unit bound) under a
    /// [`Backdrop::Gradient`] sky.
    Floor,
    /// Near: a textured wall (y = 1.1, behind the object for a DTU-like rig, crossing the unit
    /// bound) and a floor (z = −0.75) under a [`Backdrop::Gradient`] sky.
    Wall,
}

/// The height of the near backdrops' floor.
pub const FLOOR_Z: f64 = -0.75;
/// Where the wall stands (y).
pub const WALL_Y: f64 = 1.1;

impl Backdrop {
    /// Every backdrop.
    pub const ALL: [Backdrop; 7] =
        [Backdrop::None, Backdrop::Checker, Backdrop::CoarseChecker, Backdrop::Gradient, Backdrop::Noise, Backdrop::Floor, Backdrop::Wall];

    /// The name in configurations and on command lines.
    pub fn name(self) -> &'static str {
        match self {
            Backdrop::None => "none",
            Backdrop::Checker => "checker",
            Backdrop::CoarseChecker => "coarse-checker",
            Backdrop::Gradient => "gradient",
            Backdrop::Noise => "noise",
            Backdrop::Floor => "floor",
            Backdrop::Wall => "wall",
        }
    }

    /// The backdrop of [`Backdrop::name`]; the error names the known ones.
    pub fn from_name(name: &str) -> Result<Backdrop, String> {
        Backdrop::ALL
            .into_iter()
            .find(|b| b.name() == name)
            .ok_or_else(|| format!("unknown backdrop {name:?} (known: {})", Backdrop::ALL.map(Backdrop::name).join(", ")))
    }

    /// Whether part of it lies at a finite distance (inside or across the bound).
    pub fn is_near(self) -> bool {
        matches!(self, Backdrop::Floor | Backdrop::Wall)
    }

    /// The distance along a ray to the backdrop's nearest surface (∞ for environments at
    /// infinity, and where a near backdrop's ray misses its planes).
    pub fn distance(self, origin: DVec3, direction: DVec3) -> f64 {
        self.near_hit(origin, direction).map_or(f64::INFINITY, |(t, _)| t)
    }

    /// A near backdrop's nearest plane along the ray: its distance and whether it is the floor.
    fn near_hit(self, origin: DVec3, direction: DVec3) -> Option<(f64, bool)> {
        let plane = |o: f64, d: f64, at: f64| (d.abs() > 1e-12 && (at - o) / d > 0.0).then(|| (at - o) / d);
        let floor = || plane(origin.z, direction.z, FLOOR_Z).map(|t| (t, true));
        match self {
            Backdrop::Floor => floor(),
            Backdrop::Wall => {
                let wall = plane(origin.y, direction.y, WALL_Y).map(|t| (t, false));
                [floor(), wall].into_iter().flatten().min_by(|a, b| a.0.total_cmp(&b.0))
            }
            _ => None,
        }
    }

    /// The colour a ray from `origin` along unit `direction` sees of the backdrop (linear RGB in
    /// [0, 1]; black for [`Backdrop::None`]).
    pub fn color(self, origin: DVec3, direction: DVec3) -> [f32; 3] {
        match self {
            Backdrop::None => [0.0; 3],
            Backdrop::Checker => checker(direction),
            Backdrop::CoarseChecker => coarse_checker(direction),
            Backdrop::Gradient => gradient(direction),
            Backdrop::Noise => noise_environment(direction),
            Backdrop::Floor | Backdrop::Wall => match self.near_hit(origin, direction) {
                None => gradient(direction),
                Some((t, is_floor)) => {
                    let p = origin + t * direction;
                    if is_floor { floor_texture(p.x, p.y) } else { wall_texture(p.x, p.z) }
                }
            },
        }
    }
}

fn angles(direction: DVec3) -> (f64, f64) {
    (direction.y.atan2(direction.x), direction.z.clamp(-1.0, 1.0).asin())
}

fn checker(direction: DVec3) -> [f32; 3] {
    let (theta, phi) = angles(direction);
    let cell = ((theta * 8.0 / PI).floor() + (phi * 8.0 / PI).floor()) as i64;
    let shade = (0.85 + 0.15 * (5.0 * theta).sin() * (3.0 * phi).cos()) as f32;
    let base = if cell.rem_euclid(2) == 0 { [0.62, 0.58, 0.50] } else { [0.28, 0.30, 0.35] };
    base.map(|c| c * shade)
}

fn gradient(direction: DVec3) -> [f32; 3] {
    let up = direction.z.clamp(-1.0, 1.0);
    let sky = [0.55 + 0.25 * up, 0.62 + 0.22 * up, 0.75 + 0.15 * up];
    let band = (-(up / 0.15).powi(2)).exp();
    let warm = [0.85, 0.62, 0.40];
    std::array::from_fn(|k| ((1.0 - band) * sky[k] + band * warm[k]).clamp(0.0, 1.0) as f32)
}

fn coarse_checker(direction: DVec3) -> [f32; 3] {
    let (theta, phi) = angles(direction);
    let cell = ((theta * 4.0 / PI).floor() + (phi * 4.0 / PI).floor()) as i64;
    let g = gradient(direction);
    let k = if cell.rem_euclid(2) == 0 { 1.08 } else { 0.82 };
    g.map(|c| (c * k).min(1.0))
}

/// A hash of a lattice point to [0, 1).
fn lattice(i: i64, j: i64, k: i64, seed: u64) -> f64 {
    let mut h = seed ^ (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ (j as u64).wrapping_mul(0xc2b2_ae3d_27d4_eb4f);
    h ^= (k as u64).wrapping_mul(0x1656_67b1_9e37_79f9);
    h ^= h >> 33;
    h = h.wrapping_mul(0xff51_afd7_ed55_8ccd);
    h ^= h >> 33;
    (h >> 11) as f64 / (1u64 << 53) as f64
}

/// Trilinear value noise with smoothstep weights, in [0, 1).
fn value_noise(p: DVec3, seed: u64) -> f64 {
    let base = p.floor();
    let f = p - base;
    let s = f * f * (DVec3::splat(3.0) - 2.0 * f);
    let (i, j, k) = (base.x as i64, base.y as i64, base.z as i64);
    let mut sum = 0.0;
    for corner in 0..8 {
        let (dx, dy, dz) = ((corner & 1) as i64, ((corner >> 1) & 1) as i64, ((corner >> 2) & 1) as i64);
        let w = (if dx == 1 { s.x } else { 1.0 - s.x }) * (if dy == 1 { s.y } else { 1.0 - s.y }) * (if dz == 1 { s.z } else { 1.0 - s.z });
        sum += w * lattice(i + dx, j + dy, k + dz, seed);
    }
    sum
}

fn octaves(p: DVec3, seed: u64) -> f64 {
    (value_noise(p, seed) * 4.0 + value_noise(2.0 * p, seed + 1) * 2.0 + value_noise(4.0 * p, seed + 2)) / 7.0
}

fn noise_environment(direction: DVec3) -> [f32; 3] {
    let p = direction * 9.0;
    let a = octaves(p, 11);
    let b = octaves(p + DVec3::splat(17.3), 23);
    let contrast = |v: f64| ((v - 0.5) * 2.2 + 0.5).clamp(0.02, 0.98);
    let (a, b) = (contrast(a), contrast(b));
    [(0.2 + 0.7 * a) as f32, (0.15 + 0.6 * (0.6 * a + 0.4 * b)) as f32, (0.2 + 0.7 * b) as f32]
}

fn floor_texture(x: f64, y: f64) -> [f32; 3] {
    let cell = ((x / 0.3).floor() + (y / 0.3).floor()) as i64;
    let grain = 0.85 + 0.3 * octaves(DVec3::new(x * 6.0, y * 6.0, 0.5), 5);
    let base = if cell.rem_euclid(2) == 0 { [0.58, 0.48, 0.36] } else { [0.40, 0.33, 0.26] };
    base.map(|c| (c * grain).min(1.0) as f32)
}

fn wall_texture(x: f64, z: f64) -> [f32; 3] {
    let v = octaves(DVec3::new(x * 4.0, z * 4.0, 2.5), 9);
    let stripe = if ((x / 0.45).floor() as i64).rem_euclid(2) == 0 { 1.0 } else { 0.88 };
    [(0.45 + 0.35 * v) * stripe, (0.50 + 0.30 * v) * stripe, (0.42 + 0.25 * v) * stripe].map(|c| c as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_backdrop_round_trips_its_name_and_stays_in_range() {
        for b in Backdrop::ALL {
            assert_eq!(Backdrop::from_name(b.name()), Ok(b));
            for i in 0..500 {
                let d = prob_grid::field::uniform_direction((i as f64 * 0.618_034) % 1.0, (i as f64 + 0.5) / 500.0);
                let c = b.color(DVec3::new(0.3, -2.5, 1.8), d);
                assert!(c.iter().all(|v| (0.0..=1.0).contains(v)), "{b:?} {c:?}");
            }
        }
        assert!(Backdrop::from_name("brick").unwrap_err().contains("coarse-checker"));
    }

    #[test]
    fn near_backdrops_cross_the_unit_bound_and_environments_are_at_infinity() {
        let eye = DVec3::new(0.0, -2.4, 1.8);
        let down = (DVec3::new(0.0, 0.0, FLOOR_Z) - eye).normalize();
        let back = (DVec3::new(0.0, WALL_Y, 0.2) - eye).normalize();
        assert!((Backdrop::Floor.distance(eye, down) - (DVec3::new(0.0, 0.0, FLOOR_Z) - eye).length()).abs() < 1e-9);
        assert!(Backdrop::Wall.distance(eye, back).is_finite());
        assert!(Backdrop::Floor.distance(eye, -down).is_infinite());
        for b in [Backdrop::Checker, Backdrop::CoarseChecker, Backdrop::Gradient, Backdrop::Noise] {
            assert!(!b.is_near() && b.distance(eye, down).is_infinite());
            // At infinity: the colour depends on the direction only.
            assert_eq!(b.color(eye, down), b.color(DVec3::ZERO, down));
        }
        assert!(FLOOR_Z.abs() < 1.0 && WALL_Y < 1.2, "the near backdrops cross the unit bound");
    }

    #[test]
    fn the_noise_backdrop_has_detail_and_the_gradient_has_none() {
        let d = |a: f64| DVec3::new(a.cos(), a.sin(), 0.3).normalize();
        let step = 1f64.to_radians();
        let variation = |b: Backdrop| {
            (0..360).map(|i| (b.color(DVec3::ZERO, d(i as f64 * step))[0] - b.color(DVec3::ZERO, d((i + 1) as f64 * step))[0]).abs()).sum::<f32>()
        };
        assert!(variation(Backdrop::Noise) > 1.0, "{}", variation(Backdrop::Noise));
        assert!(variation(Backdrop::Gradient) < 1e-4);
    }
}
