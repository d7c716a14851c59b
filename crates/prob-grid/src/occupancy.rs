//! An occupancy bitfield over the scene grid: which cells can hold mass (the surface's band at
//! the current s), from the same evaluation as the probability grid, for empty-space skipping
//! (instant-ngp's and nerfacc's occupancy grids).
//!
//! A cell is occupied when the evaluation kept it (its density is above the negligible level,
//! see [`crate::scene`]); the set is then dilated by `dilation` cells so that a surface that moved
//! a little since the update is still covered. Rays query the occupied intervals of their path
//! by a 3D DDA (Amanatides & Woo) over the grid.
//!
//! Safety: the evaluation behind it checks the field's Lipschitz claim against the field's own
//! values ([`crate::LipschitzCheck`]), so a field steeper than it claims does not empty cells
//! that hold the surface.

use crate::scene::{ActiveCells, SceneGridConfig};
use glam::{UVec3, Vec3};

/// Occupied cells of a scene grid (one bit per cell, x fastest).
#[derive(Debug, Clone, PartialEq)]
pub struct Occupancy {
    resolution: usize,
    bound_min: Vec3,
    cell: f32,
    bits: Vec<u64>,
    occupied: usize,
    /// The box (world corners) rays are clipped to before the DDA, where
    /// [`Self::clipped_to_occupied`] set it: the occupied cells' bounding box.
    clip: Option<[Vec3; 2]>,
}

impl Occupancy {
    /// Every cell occupied (no skipping).
    pub fn full(config: &SceneGridConfig) -> Occupancy {
        let n = config.resolution.pow(3);
        let mut bits = vec![u64::MAX; n.div_ceil(64)];
        if !n.is_multiple_of(64) {
            *bits.last_mut().expect("at least one word") = (1u64 << (n % 64)) - 1;
        }
        Occupancy { resolution: config.resolution, bound_min: config.bound_min, cell: config.cell_size(), bits, occupied: n, clip: None }
    }

    /// The cells holding the evaluation's mass (the sub-cells' parents), dilated by `dilation`
    /// cells along each axis (a cube of side 2·dilation + 1 around each).
    pub fn from_active(active: &ActiveCells, config: &SceneGridConfig, dilation: u32) -> Occupancy {
        let r = config.resolution;
        let cell = config.cell_size();
        let mut dense = vec![false; r * r * r];
        for p in &active.points {
            let c = ((*p - config.bound_min) / cell).floor();
            if c.cmpge(Vec3::ZERO).all() && c.cmplt(Vec3::splat(r as f32)).all() {
                dense[(c.z as usize * r + c.y as usize) * r + c.x as usize] = true;
            }
        }
        // Separable box dilation: along x, then y, then z.
        let d = dilation as usize;
        for axis in 0..3 {
            if d == 0 {
                break;
            }
            let stride = [1, r, r * r][axis];
            let mut next = dense.clone();
            for base in 0..r * r * r {
                let pos = (base / stride) % r;
                if !dense[base] {
                    continue;
                }
                for k in pos.saturating_sub(d)..(pos + d + 1).min(r) {
                    next[base - pos * stride + k * stride] = true;
                }
            }
            dense = next;
        }
        let mut bits = vec![0u64; dense.len().div_ceil(64)];
        let mut occupied = 0;
        for (i, &b) in dense.iter().enumerate() {
            if b {
                bits[i / 64] |= 1 << (i % 64);
                occupied += 1;
            }
        }
        Occupancy { resolution: r, bound_min: config.bound_min, cell, bits, occupied, clip: None }
    }

    /// One value per cell (x fastest): 1 occupied, 0 empty (for checkpoints).
    pub fn to_values(&self) -> Vec<f32> {
        let n = self.resolution.pow(3);
        (0..n).map(|i| if self.bits[i / 64] & (1 << (i % 64)) != 0 { 1.0 } else { 0.0 }).collect()
    }

    /// The occupancy [`Self::to_values`] wrote, for `config`'s grid; `None` if the count differs.
    pub fn from_values(config: &SceneGridConfig, values: &[f32]) -> Option<Occupancy> {
        let n = config.resolution.pow(3);
        if values.len() != n {
            return None;
        }
        let mut bits = vec![0u64; n.div_ceil(64)];
        let mut occupied = 0;
        for (i, v) in values.iter().enumerate() {
            if *v > 0.5 {
                bits[i / 64] |= 1 << (i % 64);
                occupied += 1;
            }
        }
        Some(Occupancy { resolution: config.resolution, bound_min: config.bound_min, cell: config.cell_size(), bits, occupied, clip: None })
    }

    /// This occupancy with every ray clipped to the bounding box of its occupied cells before
    /// [`Self::segments`]' DDA walks its cells (no occupied cell: no interval at all): a ray
    /// that misses the box takes no step, one that crosses it steps through the box's cells
    /// alone. The same intervals but for the rounding of their ends (where the DDA enters the
    /// box its boundary crossings are computed from there, not summed from the grid's side);
    /// for a render's own occupancy, where most rays miss the object (training's estimator
    /// keeps the unclipped walk, and its bits).
    pub fn clipped_to_occupied(mut self) -> Occupancy {
        let r = self.resolution;
        let (mut lo, mut hi) = (UVec3::splat(u32::MAX), UVec3::ZERO);
        for (w, &word) in self.bits.iter().enumerate() {
            let mut word = word;
            while word != 0 {
                let i = 64 * w + word.trailing_zeros() as usize;
                word &= word - 1;
                let c = UVec3::new((i % r) as u32, ((i / r) % r) as u32, (i / (r * r)) as u32);
                (lo, hi) = (lo.min(c), hi.max(c));
            }
        }
        // No occupied cell: `segments` returns at once, clipped or not.
        self.clip = (self.occupied > 0).then(|| [self.bound_min + lo.as_vec3() * self.cell, self.bound_min + (hi + 1).as_vec3() * self.cell]);
        self
    }

    /// Cells per axis.
    pub fn resolution(&self) -> usize {
        self.resolution
    }

    /// Whether cell (i, j, k) is occupied.
    pub fn is_occupied(&self, cell: UVec3) -> bool {
        let r = self.resolution;
        let i = (cell.z as usize * r + cell.y as usize) * r + cell.x as usize;
        self.bits[i / 64] & (1 << (i % 64)) != 0
    }

    /// Whether the cell containing `point` is occupied (points outside the grid are not).
    pub fn contains(&self, point: Vec3) -> bool {
        let c = ((point - self.bound_min) / self.cell).floor();
        c.cmpge(Vec3::ZERO).all() && c.cmplt(Vec3::splat(self.resolution as f32)).all() && self.is_occupied(c.as_uvec3())
    }

    /// Fraction of the cells occupied.
    pub fn occupied_fraction(&self) -> f64 {
        self.occupied as f64 / (self.resolution.pow(3)) as f64
    }

    /// Appends to `out` the occupied intervals `[t_a, t_b]` of the ray `origin + t·direction`
    /// within `[t0, t1]`, in increasing order, adjacent cells merged. Parts of the ray outside the
    /// grid are not occupied. `direction` need not be normalised (t is in its units).
    pub fn segments(&self, origin: Vec3, direction: Vec3, t0: f32, t1: f32, out: &mut Vec<[f32; 2]>) {
        if self.occupied == 0 {
            return;
        }
        let r = self.resolution as i32;
        let size = self.cell * self.resolution as f32;
        let lo = self.bound_min;
        // Clip [t0, t1] to the grid's box, or the occupied cells' (slabs).
        let [box_lo, box_hi] = self.clip.unwrap_or([lo, lo + Vec3::splat(size)]);
        let inv = direction.recip();
        let (ta, tb) = ((box_lo - origin) * inv, (box_hi - origin) * inv);
        let (mut t_enter, mut t_exit) = (t0, t1);
        for a in 0..3 {
            if direction[a] == 0.0 {
                // Parallel to the slab: within it all along, or never (0 · ∞ would be NaN for an
                // origin on one of its faces).
                if !(box_lo[a] <= origin[a] && origin[a] <= box_hi[a]) {
                    return;
                }
            } else {
                (t_enter, t_exit) = (t_enter.max(ta[a].min(tb[a])), t_exit.min(ta[a].max(tb[a])));
            }
        }
        if !(t_enter < t_exit) {
            return;
        }
        // Start cell, at a point slightly inside the clipped interval.
        let start = origin + direction * t_enter;
        let mut c = ((start - lo) / self.cell).floor().as_ivec3().clamp(glam::IVec3::ZERO, glam::IVec3::splat(r - 1));
        let step = direction.signum().as_ivec3();
        // t at which the ray crosses the next cell boundary on each axis, and the t per cell.
        let next_boundary = |axis: usize| {
            let d = direction[axis];
            if d > 0.0 {
                (lo[axis] + (c[axis] + 1) as f32 * self.cell - origin[axis]) / d
            } else if d < 0.0 {
                (lo[axis] + c[axis] as f32 * self.cell - origin[axis]) / d
            } else {
                f32::INFINITY
            }
        };
        let mut t_max = Vec3::new(next_boundary(0), next_boundary(1), next_boundary(2));
        let t_delta = (Vec3::splat(self.cell) * inv).abs();
        let mut t = t_enter;
        let mut open: Option<f32> = None;
        loop {
            let inside = c.cmpge(glam::IVec3::ZERO).all() && c.cmplt(glam::IVec3::splat(r)).all();
            if !inside {
                break;
            }
            let occupied = self.is_occupied(c.as_uvec3());
            let axis = if t_max.x <= t_max.y && t_max.x <= t_max.z {
                0
            } else if t_max.y <= t_max.z {
                1
            } else {
                2
            };
            let t_next = t_max[axis].min(t_exit);
            match (occupied, open) {
                (true, None) => open = Some(t),
                (false, Some(a)) => {
                    out.push([a, t]);
                    open = None;
                }
                _ => {}
            }
            if t_next >= t_exit {
                break;
            }
            t = t_next;
            c[axis] += step[axis];
            t_max[axis] += t_delta[axis];
        }
        if let Some(a) = open {
            out.push([a, t_exit]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Shape, evaluate};
    use glam::DVec3;

    #[test]
    fn occupancy_covers_the_shell_and_rays_find_it() {
        let config = SceneGridConfig { resolution: 32, ..Default::default() };
        let sphere = Shape::Sphere { center: DVec3::ZERO, radius: 0.5 };
        let active = evaluate(&sphere, 300.0, &config).unwrap();
        let occ = Occupancy::from_active(&active, &config, 1);
        assert!(occ.occupied_fraction() < 0.3, "a thin shell: {}", occ.occupied_fraction());
        assert!(occ.contains(Vec3::new(0.5, 0.0, 0.0)) && !occ.contains(Vec3::ZERO) && !occ.contains(Vec3::splat(0.9)));
        // A ray through the centre crosses the shell twice: two segments around t = 2.5 and 3.5.
        let mut seg = Vec::new();
        occ.segments(Vec3::new(0.0, 0.0, -3.0), Vec3::Z, 0.0, 10.0, &mut seg);
        assert_eq!(seg.len(), 2, "{seg:?}");
        assert!(seg[0][0] < 2.5 && seg[0][1] > 2.5 && seg[1][0] < 3.5 && seg[1][1] > 3.5, "{seg:?}");
        assert!(seg.iter().all(|s| s[1] - s[0] < 0.4), "{seg:?}");
        // A ray that misses the sphere finds nothing; one clipped before the shell neither.
        seg.clear();
        occ.segments(Vec3::new(0.9, 0.9, -3.0), Vec3::Z, 0.0, 10.0, &mut seg);
        assert!(seg.is_empty(), "{seg:?}");
        occ.segments(Vec3::new(0.0, 0.0, -3.0), Vec3::Z, 0.0, 2.0, &mut seg);
        assert!(seg.is_empty(), "{seg:?}");
        // Diagonal and negative directions: every sample point inside a segment is occupied.
        for dir in [Vec3::new(1.0, 0.7, -0.4), Vec3::new(-0.3, -1.0, 0.2), Vec3::new(0.0, 1.0, 0.0)] {
            let dir = dir.normalize();
            let origin = -3.0 * dir + Vec3::new(0.05, -0.02, 0.03);
            seg.clear();
            occ.segments(origin, dir, 0.0, 6.0, &mut seg);
            assert!(!seg.is_empty());
            for s in &seg {
                for k in 1..10 {
                    let t = s[0] + (s[1] - s[0]) * k as f32 / 10.0;
                    assert!(occ.contains(origin + t * dir), "{dir}: t = {t} in {s:?}");
                }
            }
            // And points outside every segment are empty.
            for k in 0..600 {
                let t = k as f32 * 0.01;
                let inside_segment = seg.iter().any(|s| t >= s[0] - 1e-4 && t <= s[1] + 1e-4);
                if !inside_segment {
                    assert!(!occ.contains(origin + t * dir), "{dir}: t = {t} is occupied but outside {seg:?}");
                }
            }
        }
        let full = Occupancy::full(&config);
        assert_eq!(full.occupied_fraction(), 1.0);
    }

    /// Guards a render's clipped walk: rays clipped to the occupied cells' box find the same
    /// intervals as the walk over the whole grid, their ends within rounding (rays from outside
    /// and inside the grid, through the object, grazing it, missing its box, along an axis, and
    /// cut short by [t0, t1]); an occupancy with no occupied cell gives none either way.
    #[test]
    fn rays_clipped_to_the_occupied_box_find_the_same_intervals() {
        let config = SceneGridConfig { resolution: 48, ..Default::default() };
        let shape = Shape::Sphere { center: DVec3::new(0.2, -0.1, 0.05), radius: 0.35 };
        let occupancy = Occupancy::from_active(&evaluate(&shape, 300.0, &config).unwrap(), &config, 1);
        let clipped = occupancy.clone().clipped_to_occupied();
        let [lo, hi] = clipped.clip.expect("cells are occupied");
        // The sphere's box, dilated: well inside the grid's [−1, 1]³.
        assert!(lo.cmpgt(Vec3::splat(-0.6)).all() && hi.cmplt(Vec3::splat(0.7)).all(), "{lo} {hi}");
        let (mut whole, mut cut) = (Vec::new(), Vec::new());
        let mut crossing = 0;
        for i in 0..400 {
            let a = i as f32 * 0.173;
            let origin =
                if i % 5 == 0 { Vec3::new(0.1 * a.sin(), 0.2, -0.1) } else { Vec3::new(3.0 * a.cos(), 3.0 * a.sin(), 0.7 * (1.3 * a).sin()) };
            let target = Vec3::new(0.2 + 0.6 * (2.1 * a).sin(), -0.1 + 0.6 * (1.7 * a).cos(), 0.6 * (0.9 * a).sin());
            // Ray 7 along an axis, through the sphere.
            let (origin, direction) = if i == 7 { (Vec3::new(-3.0, -0.1, 0.05), Vec3::X) } else { (origin, (target - origin).normalize()) };
            let (t0, t1) = if i % 7 == 3 { (0.5, 2.9) } else { (0.0, 8.0) };
            whole.clear();
            cut.clear();
            occupancy.segments(origin, direction, t0, t1, &mut whole);
            clipped.segments(origin, direction, t0, t1, &mut cut);
            assert_eq!(whole.len(), cut.len(), "ray {i}: {whole:?} against {cut:?}");
            for (w, c) in whole.iter().zip(&cut) {
                assert!((w[0] - c[0]).abs() <= 1e-5 && (w[1] - c[1]).abs() <= 1e-5, "ray {i}: {whole:?} against {cut:?}");
            }
            crossing += usize::from(!whole.is_empty());
        }
        assert!((100..380).contains(&crossing), "{crossing} of 400 rays cross the occupancy: the rays test too little");
        // Along an axis from a point on a face of the occupied box (where 0 · ∞ is NaN): the
        // intervals of the whole walk.
        let [lo, _] = clipped.clip.expect("cells are occupied");
        for origin in [Vec3::new(-3.0, lo.y, 0.05), Vec3::new(0.2, lo.y, -3.0)] {
            let direction = if origin.x < -2.0 { Vec3::X } else { Vec3::Z };
            whole.clear();
            cut.clear();
            occupancy.segments(origin, direction, 0.0, 8.0, &mut whole);
            clipped.segments(origin, direction, 0.0, 8.0, &mut cut);
            assert!(!whole.is_empty(), "{origin} along {direction} crosses the sphere's lowest cells");
            assert_eq!(whole.len(), cut.len(), "{origin} along {direction}: {whole:?} against {cut:?}");
        }
        let none = Occupancy::from_active(&ActiveCells::default(), &config, 1).clipped_to_occupied();
        cut.clear();
        none.segments(Vec3::new(0.0, 0.0, -3.0), Vec3::Z, 0.0, 10.0, &mut cut);
        assert!(cut.is_empty() && none.occupied_fraction() == 0.0);
    }
}
