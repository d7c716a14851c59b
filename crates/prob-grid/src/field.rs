//! Signed distance fields the sampler can be guided by, and analytic shapes with known truth.
//!
//! The sampler sees only [`SdfField`]: batched, thread-safe SDF queries. A trained backbone
//! implements it; so do the analytic [`Shape`]s and [`crate::mesh::TriangleMesh`], which let the
//! sampler be tested and shown without any training, and give the golden scenes their truth.

use glam::{DVec3, Vec3};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};

/// A signed distance field: negative inside, positive outside, zero on the surface.
///
/// Implementations must be `Sync`: the grid update calls [`SdfField::sdf_batch`] from several
/// threads at once, each with its own slices.
pub trait SdfField: Sync {
    /// Writes `S(points[i])` into `out[i]`. `points.len() == out.len()`.
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]);

    /// An upper bound on |∇S| (1 for an exact distance; a learnt SDF is only ≈ 1). The sparse
    /// grid update uses it to skip blocks that cannot hold the surface.
    fn lipschitz_bound(&self) -> f32 {
        1.0
    }
}

/// The named analytic shapes (golden scenes and the built-in scene), typed once at the edge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ShapeName {
    /// A sphere of radius 0.5.
    Sphere,
    /// A torus of radii 0.5 and 0.15.
    Torus,
    /// A box of half-extent 0.35.
    Box,
    /// [`Shape::composite`].
    Composite,
    /// [`Shape::multipart`].
    Multipart,
}

impl ShapeName {
    /// Every named shape.
    pub const ALL: [ShapeName; 5] = [ShapeName::Sphere, ShapeName::Torus, ShapeName::Box, ShapeName::Composite, ShapeName::Multipart];

    /// The name in configurations and on command lines.
    pub fn name(self) -> &'static str {
        match self {
            ShapeName::Sphere => "sphere",
            ShapeName::Torus => "torus",
            ShapeName::Box => "box",
            ShapeName::Composite => "composite",
            ShapeName::Multipart => "multipart",
        }
    }

    /// The shape of [`ShapeName::name`]; the error names the known ones.
    pub fn from_name(name: &str) -> Result<ShapeName, String> {
        ShapeName::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| format!("unknown shape {name:?} (known: {})", ShapeName::ALL.map(ShapeName::name).join(", ")))
    }

    /// The shape.
    pub fn shape(self) -> Shape {
        match self {
            ShapeName::Sphere => Shape::Sphere { center: DVec3::ZERO, radius: 0.5 },
            ShapeName::Torus => Shape::Torus { center: DVec3::ZERO, major_radius: 0.5, minor_radius: 0.15 },
            ShapeName::Box => Shape::Box { center: DVec3::ZERO, half_extents: DVec3::splat(0.35) },
            ShapeName::Composite => Shape::composite(),
            ShapeName::Multipart => Shape::multipart(),
        }
    }
}

impl std::fmt::Display for ShapeName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Analytic shapes with exact (or Lipschitz-1 bounding) SDFs and uniform surface sampling.
#[derive(Debug, Clone, PartialEq)]
pub enum Shape {
    /// A sphere.
    Sphere {
        /// Centre.
        center: DVec3,
        /// Radius.
        radius: f64,
    },
    /// A torus around the z axis through `center`.
    Torus {
        /// Centre.
        center: DVec3,
        /// Distance from the centre to the tube's centre line.
        major_radius: f64,
        /// Tube radius.
        minor_radius: f64,
    },
    /// An axis-aligned box.
    Box {
        /// Centre.
        center: DVec3,
        /// Half the side lengths.
        half_extents: DVec3,
    },
    /// The union of shapes (`min` of their SDFs).
    Union(Vec<Shape>),
    /// `a` minus `b` (`max(S_a, −S_b)`).
    Difference(std::boxed::Box<Shape>, std::boxed::Box<Shape>),
}

impl Shape {
    /// The unit-radius-friendly composite used by golden scenes and the built-in default scene:
    /// a sphere with a spherical bite (a concavity) and a thin ring (a thin part, 0.08 thick)
    /// around it. Everything lies inside radius 0.75.
    pub fn composite() -> Shape {
        let body = Shape::Sphere { center: DVec3::new(0.0, 0.0, 0.05), radius: 0.42 };
        let bite = Shape::Sphere { center: DVec3::new(0.22, -0.3, 0.3), radius: 0.25 };
        let ring = Shape::Torus { center: DVec3::new(0.0, 0.0, -0.12), major_radius: 0.58, minor_radius: 0.04 };
        let foot = Shape::Box { center: DVec3::new(0.0, 0.0, -0.45), half_extents: DVec3::new(0.22, 0.22, 0.08) };
        Shape::Union(vec![Shape::Difference(Box::new(body), Box::new(bite)), ring, foot])
    }

    /// A scene of six separate parts, as users' scenes have (a statue on a base, a cup and its
    /// saucer): a flat base; above it, a cubic cage (bars 0.04 thick) with a ball inside that is
    /// seen only through the cage's openings; a thin ring (tube radius 0.035); a thin pole under
    /// the ring's centre; and a bowl (a concavity). No part touches another; everything lies
    /// inside radius 0.95.
    pub fn multipart() -> Shape {
        let cage_center = DVec3::new(-0.3, 0.05, -0.15);
        let cage = Shape::Difference(
            Box::new(Shape::Box { center: cage_center, half_extents: DVec3::splat(0.2) }),
            Box::new(Shape::Union(vec![
                Shape::Box { center: cage_center, half_extents: DVec3::new(0.16, 0.16, 0.3) },
                Shape::Box { center: cage_center, half_extents: DVec3::new(0.16, 0.3, 0.16) },
                Shape::Box { center: cage_center, half_extents: DVec3::new(0.3, 0.16, 0.16) },
            ])),
        );
        let bowl_center = DVec3::new(0.0, -0.45, -0.3);
        Shape::Union(vec![
            Shape::Box { center: DVec3::new(0.0, 0.0, -0.55), half_extents: DVec3::new(0.5, 0.5, 0.04) },
            cage,
            Shape::Sphere { center: cage_center, radius: 0.1 },
            Shape::Torus { center: DVec3::new(0.35, 0.05, -0.1), major_radius: 0.22, minor_radius: 0.035 },
            Shape::Box { center: DVec3::new(0.35, 0.05, -0.3), half_extents: DVec3::new(0.02, 0.02, 0.17) },
            Shape::Difference(
                Box::new(Shape::Sphere { center: bowl_center, radius: 0.17 }),
                Box::new(Shape::Sphere { center: bowl_center + DVec3::new(0.0, 0.0, 0.1), radius: 0.15 }),
            ),
        ])
    }

    /// The signed distance at `p` (exact for primitives; a Lipschitz-1 bound for CSG).
    pub fn sdf(&self, p: DVec3) -> f64 {
        match self {
            Shape::Sphere { center, radius } => (p - *center).length() - radius,
            Shape::Torus { center, major_radius, minor_radius } => {
                let q = p - *center;
                let ring = (q.x * q.x + q.y * q.y).sqrt() - major_radius;
                (ring * ring + q.z * q.z).sqrt() - minor_radius
            }
            Shape::Box { center, half_extents } => {
                let q = (p - *center).abs() - *half_extents;
                q.max(DVec3::ZERO).length() + q.max_element().min(0.0)
            }
            Shape::Union(parts) => parts.iter().map(|s| s.sdf(p)).fold(f64::INFINITY, f64::min),
            Shape::Difference(a, b) => a.sdf(p).max(-b.sdf(p)),
        }
    }

    /// The SDF gradient by central differences (unit length where the SDF is exact).
    pub fn gradient(&self, p: DVec3) -> DVec3 {
        let h = 1e-6;
        DVec3::new(
            self.sdf(p + DVec3::X * h) - self.sdf(p - DVec3::X * h),
            self.sdf(p + DVec3::Y * h) - self.sdf(p - DVec3::Y * h),
            self.sdf(p + DVec3::Z * h) - self.sdf(p - DVec3::Z * h),
        ) / (2.0 * h)
    }

    /// Surface area (for CSG: the sum over the primitives, an upper bound).
    pub fn area(&self) -> f64 {
        use std::f64::consts::PI;
        match self {
            Shape::Sphere { radius, .. } => 4.0 * PI * radius * radius,
            Shape::Torus { major_radius, minor_radius, .. } => 4.0 * PI * PI * major_radius * minor_radius,
            Shape::Box { half_extents: h, .. } => 8.0 * (h.x * h.y + h.y * h.z + h.z * h.x),
            Shape::Union(parts) => parts.iter().map(Shape::area).sum(),
            Shape::Difference(a, b) => a.area() + b.area(),
        }
    }

    /// Pushes points uniform by area on every primitive's surface, about `density` per unit area.
    fn sample_primitive_surfaces(&self, density: f64, rng: &mut Xoshiro256PlusPlus, out: &mut Vec<DVec3>) {
        use std::f64::consts::TAU;
        let count = (self.area() * density).round() as usize;
        match self {
            Shape::Sphere { center, radius } => {
                for _ in 0..count {
                    out.push(*center + *radius * uniform_direction(rng.random(), rng.random()));
                }
            }
            Shape::Torus { center, major_radius: big, minor_radius: small } => {
                let mut n = 0;
                while n < count {
                    // Area element ∝ (R + r cos θ): rejection on θ.
                    let theta = TAU * rng.random::<f64>();
                    let accept = (big + small * theta.cos()) / (big + small);
                    if rng.random::<f64>() > accept {
                        continue;
                    }
                    let phi = TAU * rng.random::<f64>();
                    let ring = big + small * theta.cos();
                    out.push(*center + DVec3::new(ring * phi.cos(), ring * phi.sin(), small * theta.sin()));
                    n += 1;
                }
            }
            Shape::Box { center, half_extents: h } => {
                let areas = [h.y * h.z, h.z * h.x, h.x * h.y];
                let total: f64 = areas.iter().sum();
                for _ in 0..count {
                    let mut pick = rng.random::<f64>() * total;
                    let mut axis = 0;
                    while axis < 2 && pick >= areas[axis] {
                        pick -= areas[axis];
                        axis += 1;
                    }
                    let mut p = DVec3::new(
                        (2.0 * rng.random::<f64>() - 1.0) * h.x,
                        (2.0 * rng.random::<f64>() - 1.0) * h.y,
                        (2.0 * rng.random::<f64>() - 1.0) * h.z,
                    );
                    p[axis] = if rng.random::<bool>() { h[axis] } else { -h[axis] };
                    out.push(*center + p);
                }
            }
            Shape::Union(parts) => parts.iter().for_each(|s| s.sample_primitive_surfaces(density, rng, out)),
            Shape::Difference(a, b) => {
                a.sample_primitive_surfaces(density, rng, out);
                b.sample_primitive_surfaces(density, rng, out);
            }
        }
    }

    /// Points uniformly distributed by area on the shape's surface, about `density` per unit
    /// area, deterministic for a seed. For CSG shapes, each primitive is sampled uniformly and the
    /// points that are not on the final surface (|S| > 1e-9) are dropped, which keeps the density
    /// uniform.
    pub fn sample_surface(&self, density: f64, seed: u64) -> Vec<DVec3> {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let mut out = Vec::new();
        self.sample_primitive_surfaces(density, &mut rng, &mut out);
        out.retain(|p| self.sdf(*p).abs() <= 1e-9);
        out
    }

    /// The shape's parts: a union's members, or the shape itself. Per-part metrics (the thin
    /// ring of the built-in scene, the pole of the multipart one) group the truth by these.
    pub fn parts(&self) -> &[Shape] {
        match self {
            Shape::Union(parts) => parts,
            _ => std::slice::from_ref(self),
        }
    }

    /// The index in [`Shape::parts`] of the part whose surface is nearest `p` (smallest |S|).
    pub fn nearest_part(&self, p: DVec3) -> usize {
        self.parts().iter().map(|part| part.sdf(p).abs()).enumerate().min_by(|a, b| a.1.total_cmp(&b.1)).map_or(0, |(i, _)| i)
    }

    /// A short description, e.g. `torus 0.58 × 0.04` or `sphere 0.42 − sphere 0.25` (sizes to
    /// four decimals, so that a scaled shape reads as plainly).
    pub fn describe(&self) -> String {
        let n = |x: f64| {
            let s = format!("{x:.4}");
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        };
        match self {
            Shape::Sphere { radius, .. } => format!("sphere {}", n(*radius)),
            Shape::Torus { major_radius, minor_radius, .. } => format!("torus {} × {}", n(*major_radius), n(*minor_radius)),
            Shape::Box { half_extents: h, .. } => format!("box {} × {} × {}", n(2.0 * h.x), n(2.0 * h.y), n(2.0 * h.z)),
            Shape::Union(parts) => parts.iter().map(|p| p.describe()).collect::<Vec<_>>().join(" ∪ "),
            Shape::Difference(a, b) => format!("{} − {}", a.describe(), b.describe()),
        }
    }

    /// Radius of a sphere about the origin that contains the shape.
    pub fn bounding_radius(&self) -> f64 {
        match self {
            Shape::Sphere { center, radius } => center.length() + radius,
            Shape::Torus { center, major_radius, minor_radius } => center.length() + major_radius + minor_radius,
            Shape::Box { center, half_extents } => center.length() + half_extents.length(),
            Shape::Union(parts) => parts.iter().map(Shape::bounding_radius).fold(0.0, f64::max),
            Shape::Difference(a, _) => a.bounding_radius(),
        }
    }

    /// The shape scaled by `factor` > 0 about the origin: `S'(p) = factor · S(p / factor)`, exact
    /// where `S` is.
    pub fn scaled(&self, factor: f64) -> Shape {
        match self {
            Shape::Sphere { center, radius } => Shape::Sphere { center: *center * factor, radius: radius * factor },
            Shape::Torus { center, major_radius, minor_radius } => {
                Shape::Torus { center: *center * factor, major_radius: major_radius * factor, minor_radius: minor_radius * factor }
            }
            Shape::Box { center, half_extents } => Shape::Box { center: *center * factor, half_extents: *half_extents * factor },
            Shape::Union(parts) => Shape::Union(parts.iter().map(|p| p.scaled(factor)).collect()),
            Shape::Difference(a, b) => Shape::Difference(std::boxed::Box::new(a.scaled(factor)), std::boxed::Box::new(b.scaled(factor))),
        }
    }

    /// Sphere tracing along `origin + t·direction` (unit direction) for t in `[t_min, t_max]`:
    /// the first t with S < `epsilon`, or `None`. Safe for Lipschitz-1 bounds (CSG).
    pub fn ray_hit(&self, origin: DVec3, direction: DVec3, t_min: f64, t_max: f64, epsilon: f64) -> Option<f64> {
        let mut t = t_min;
        for _ in 0..1024 {
            if t > t_max {
                return None;
            }
            let d = self.sdf(origin + t * direction);
            if d < epsilon {
                return Some(t);
            }
            t += d;
        }
        None
    }
}

/// The unit vector for two uniform numbers in [0, 1): uniform on the sphere.
pub fn uniform_direction(u1: f64, u2: f64) -> DVec3 {
    let z = 1.0 - 2.0 * u1;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = std::f64::consts::TAU * u2;
    DVec3::new(r * phi.cos(), r * phi.sin(), z)
}

impl SdfField for Shape {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "sdf_batch: points and out differ in length");
        for (p, o) in points.iter().zip(out.iter_mut()) {
            *o = self.sdf(p.as_dvec3()) as f32;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn surface_samples_lie_on_surface_and_cover_every_part() {
        for name in ShapeName::ALL {
            let s = name.shape();
            let pts = s.sample_surface(2000.0, 7);
            assert!(pts.len() > 1000, "{name}: {}", pts.len());
            assert!(pts.iter().all(|p| s.sdf(*p).abs() <= 1e-9));
            assert!(pts.iter().all(|p| p.length() <= s.bounding_radius() + 1e-12));
        }
        // The composite keeps points on the bite (concave) and on the ring (thin part).
        let s = Shape::composite();
        let pts = s.sample_surface(2000.0, 7);
        let on_bite = pts.iter().filter(|p| ((**p - DVec3::new(0.22, -0.3, 0.3)).length() - 0.25).abs() < 1e-9).count();
        let on_ring = pts.iter().filter(|p| p.truncate().length() > 0.5).count();
        assert!(on_bite > 50 && on_ring > 100, "bite {on_bite}, ring {on_ring}");
    }

    #[test]
    fn the_composites_surface_points_fall_to_their_own_parts() {
        let s = Shape::composite();
        assert_eq!(s.parts().len(), 3);
        assert_eq!(s.parts()[1].describe(), "torus 0.58 × 0.04");
        assert_eq!(s.scaled(1.0 / 1.6).parts()[1].describe(), "torus 0.3625 × 0.025");
        assert_eq!(s.parts()[2].describe(), "box 0.44 × 0.44 × 0.16");
        assert_eq!(ShapeName::Sphere.shape().parts(), std::slice::from_ref(&ShapeName::Sphere.shape()));
        let counts = s.sample_surface(2000.0, 7).iter().fold([0usize; 3], |mut c, p| {
            let part = s.nearest_part(*p);
            assert!(s.parts()[part].sdf(*p).abs() <= 1e-9, "a surface point falls to a part it lies on");
            c[part] += 1;
            c
        });
        // The ring lies wholly outside the body and the foot: its share is its area's.
        let ring_share = counts[1] as f64 / counts.iter().sum::<usize>() as f64;
        let expected = s.parts()[1].area() / (s.sample_surface(2000.0, 7).len() as f64 / 2000.0);
        assert!((ring_share - expected).abs() < 0.02, "ring {ring_share} against its area's {expected}");
    }

    #[test]
    fn sphere_surface_sampling_is_uniform() {
        // Fraction of points above z = 0.25 on a unit sphere is (1 − 0.25)/2 exactly.
        let s = Shape::Sphere { center: DVec3::ZERO, radius: 1.0 };
        let pts = s.sample_surface(40000.0 / (4.0 * std::f64::consts::PI), 3);
        let frac = pts.iter().filter(|p| p.z > 0.25).count() as f64 / pts.len() as f64;
        assert!((frac - 0.375).abs() < 0.01, "{frac}");
    }

    #[test]
    fn sphere_tracing_hits_the_analytic_intersection() {
        let s = Shape::Torus { center: DVec3::ZERO, major_radius: 0.5, minor_radius: 0.15 };
        let t = s.ray_hit(DVec3::new(-3.0, 0.0, 0.0), DVec3::X, 0.0, 10.0, 1e-9).unwrap();
        assert!((t - (3.0 - 0.65)).abs() < 1e-8, "{t}");
        assert!(s.ray_hit(DVec3::new(-3.0, 0.0, 0.3), DVec3::X, 0.0, 10.0, 1e-9).is_none());
    }

    #[test]
    fn a_scaled_shape_is_the_shape_at_a_scaled_point() {
        for name in ShapeName::ALL {
            let (shape, scaled) = (name.shape(), name.shape().scaled(0.625));
            for i in 0..200 {
                let p = uniform_direction((i as f64 * 0.618_034) % 1.0, (i as f64 + 0.5) / 200.0) * (0.2 + (i % 7) as f64 * 0.15);
                assert!((scaled.sdf(p * 0.625) - 0.625 * shape.sdf(p)).abs() < 1e-12, "{name}");
            }
            assert!((scaled.area() - 0.625 * 0.625 * shape.area()).abs() < 1e-9 * shape.area());
            assert!((scaled.bounding_radius() - 0.625 * shape.bounding_radius()).abs() < 1e-12);
        }
    }

    #[test]
    fn gradients_are_unit_near_the_surface() {
        let s = ShapeName::Box.shape();
        let g = s.gradient(DVec3::new(0.36, 0.1, -0.2));
        assert!((g - DVec3::X).length() < 1e-6);
    }
}
