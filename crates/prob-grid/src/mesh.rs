//! Triangle meshes with a bounding-volume hierarchy, for ray casting golden scenes.

use glam::Vec3;

/// A hit of a ray on a mesh.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshHit {
    /// Distance along the (unit) ray direction.
    pub t: f32,
    /// Index of the triangle hit.
    pub triangle: u32,
    /// Barycentric coordinates (weights of vertices 1 and 2; vertex 0 gets 1 − b1 − b2).
    pub barycentric: [f32; 2],
}

#[derive(Debug, Clone, Copy)]
struct Node {
    min: Vec3,
    max: Vec3,
    /// Leaf: first triangle in `order`; inner: index of the left child (right = left + 1).
    start: u32,
    /// Number of triangles for a leaf, 0 for an inner node.
    count: u32,
}

/// An indexed triangle mesh with a BVH over its triangles.
#[derive(Debug, Clone)]
pub struct TriangleMesh {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Triangles as vertex indices.
    pub triangles: Vec<[u32; 3]>,
    nodes: Vec<Node>,
    /// Triangle indices in BVH leaf order.
    order: Vec<u32>,
}

const LEAF_SIZE: usize = 4;

impl TriangleMesh {
    /// Builds the mesh and its BVH (median split along the widest centroid axis).
    /// Panics if an index is out of range: loaders check indices before calling this.
    pub fn new(positions: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> TriangleMesh {
        let n = positions.len() as u32;
        assert!(triangles.iter().flatten().all(|&i| i < n), "triangle index out of range");
        let centroids: Vec<Vec3> =
            triangles.iter().map(|t| (positions[t[0] as usize] + positions[t[1] as usize] + positions[t[2] as usize]) / 3.0).collect();
        let mut mesh = TriangleMesh { positions, triangles, nodes: Vec::new(), order: (0..centroids.len() as u32).collect() };
        if !mesh.triangles.is_empty() {
            mesh.nodes.push(Node { min: Vec3::ZERO, max: Vec3::ZERO, start: 0, count: 0 });
            mesh.build(0, 0, centroids.len(), &centroids);
        }
        mesh
    }

    fn triangle_bounds(&self, tri: u32) -> (Vec3, Vec3) {
        let [a, b, c] = self.triangles[tri as usize].map(|i| self.positions[i as usize]);
        (a.min(b).min(c), a.max(b).max(c))
    }

    fn build(&mut self, node: usize, start: usize, end: usize, centroids: &[Vec3]) {
        let (mut min, mut max) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let (mut cmin, mut cmax) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        for &t in &self.order[start..end] {
            let (lo, hi) = self.triangle_bounds(t);
            min = min.min(lo);
            max = max.max(hi);
            cmin = cmin.min(centroids[t as usize]);
            cmax = cmax.max(centroids[t as usize]);
        }
        self.nodes[node].min = min;
        self.nodes[node].max = max;
        if end - start <= LEAF_SIZE {
            self.nodes[node].start = start as u32;
            self.nodes[node].count = (end - start) as u32;
            return;
        }
        let extent = cmax - cmin;
        let axis = if extent.x >= extent.y && extent.x >= extent.z {
            0
        } else if extent.y >= extent.z {
            1
        } else {
            2
        };
        let mid = (start + end) / 2;
        self.order[start..end].select_nth_unstable_by(mid - start, |&a, &b| centroids[a as usize][axis].total_cmp(&centroids[b as usize][axis]));
        let left = self.nodes.len();
        self.nodes.push(Node { min, max, start: 0, count: 0 });
        self.nodes.push(Node { min, max, start: 0, count: 0 });
        self.nodes[node].start = left as u32;
        self.nodes[node].count = 0;
        self.build(left, start, mid, centroids);
        self.build(left + 1, mid, end, centroids);
    }

    /// Axis-aligned bounds of all vertices.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.positions.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
    }

    /// The geometric (unnormalised) normal of a triangle, by its winding (counter-clockwise = front).
    pub fn face_normal(&self, triangle: u32) -> Vec3 {
        let [a, b, c] = self.triangles[triangle as usize].map(|i| self.positions[i as usize]);
        (b - a).cross(c - a)
    }

    /// The nearest hit with `t_min < t < t_max` along `origin + t·direction`, if any.
    /// Möller–Trumbore against each candidate triangle; both faces count.
    pub fn ray_hit(&self, origin: Vec3, direction: Vec3, t_min: f32, t_max: f32) -> Option<MeshHit> {
        if self.nodes.is_empty() {
            return None;
        }
        let inv = direction.recip();
        let mut best: Option<MeshHit> = None;
        let mut t_best = t_max;
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            if !slab_hit(node.min, node.max, origin, inv, t_min, t_best) {
                continue;
            }
            if node.count > 0 {
                for &tri in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    if let Some((t, b1, b2)) = self.intersect(tri, origin, direction)
                        && t > t_min
                        && t < t_best
                    {
                        t_best = t;
                        best = Some(MeshHit { t, triangle: tri, barycentric: [b1, b2] });
                    }
                }
            } else if top + 2 <= stack.len() {
                stack[top] = node.start;
                stack[top + 1] = node.start + 1;
                top += 2;
            }
        }
        best
    }

    fn intersect(&self, tri: u32, origin: Vec3, direction: Vec3) -> Option<(f32, f32, f32)> {
        let [a, b, c] = self.triangles[tri as usize].map(|i| self.positions[i as usize]);
        let e1 = b - a;
        let e2 = c - a;
        let p = direction.cross(e2);
        let det = e1.dot(p);
        if det.abs() < 1e-12 {
            return None;
        }
        let inv_det = 1.0 / det;
        let s = origin - a;
        let b1 = s.dot(p) * inv_det;
        if !(0.0..=1.0).contains(&b1) {
            return None;
        }
        let q = s.cross(e1);
        let b2 = direction.dot(q) * inv_det;
        if b2 < 0.0 || b1 + b2 > 1.0 {
            return None;
        }
        Some((e2.dot(q) * inv_det, b1, b2))
    }
}

impl TriangleMesh {
    /// The closest point on the mesh to `p`: (squared distance, triangle, point). `None` for an
    /// empty mesh.
    pub fn closest_point(&self, p: Vec3) -> Option<(f32, u32, Vec3)> {
        if self.nodes.is_empty() {
            return None;
        }
        let mut best = (f32::INFINITY, 0u32, Vec3::ZERO);
        let mut stack = [0u32; 64];
        let mut top = 1;
        while top > 0 {
            top -= 1;
            let node = self.nodes[stack[top] as usize];
            if box_distance_squared(node.min, node.max, p) >= best.0 {
                continue;
            }
            if node.count > 0 {
                for &tri in &self.order[node.start as usize..(node.start + node.count) as usize] {
                    let [a, b, c] = self.triangles[tri as usize].map(|i| self.positions[i as usize]);
                    let q = closest_point_on_triangle(p, a, b, c);
                    let d = (q - p).length_squared();
                    if d < best.0 {
                        best = (d, tri, q);
                    }
                }
            } else if top + 2 <= stack.len() {
                // Visit the nearer child first.
                let (l, r) = (node.start, node.start + 1);
                let dl = box_distance_squared(self.nodes[l as usize].min, self.nodes[l as usize].max, p);
                let dr = box_distance_squared(self.nodes[r as usize].min, self.nodes[r as usize].max, p);
                let (near, far) = if dl <= dr { (l, r) } else { (r, l) };
                stack[top] = far;
                stack[top + 1] = near;
                top += 2;
            }
        }
        Some(best)
    }

    /// Whether `p` is inside a closed mesh, by the parity of crossings along three fixed
    /// irrational directions (majority vote, robust to a ray grazing an edge).
    pub fn contains(&self, p: Vec3) -> bool {
        const DIRECTIONS: [Vec3; 3] =
            [Vec3::new(0.5773503, 0.5773503, 0.5773503), Vec3::new(-0.4082483, 0.8164966, -0.4082483), Vec3::new(0.6, -0.1, -0.79)];
        let mut inside_votes = 0;
        for d in DIRECTIONS {
            let d = d.normalize();
            let mut crossings = 0;
            let mut t = 0.0f32;
            while let Some(hit) = self.ray_hit(p, d, t, f32::INFINITY) {
                crossings += 1;
                t = hit.t + 1e-6 * hit.t.max(1.0);
                if crossings > 10_000 {
                    break;
                }
            }
            inside_votes += crossings % 2;
        }
        inside_votes >= 2
    }
}

/// A signed distance field from a closed (watertight) triangle mesh: the distance to the
/// closest point, negative inside (ray-parity vote).
#[derive(Debug, Clone)]
pub struct MeshSdf {
    /// The mesh.
    pub mesh: TriangleMesh,
}

impl crate::field::SdfField for MeshSdf {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "sdf_batch: points and out differ in length");
        for (p, o) in points.iter().zip(out.iter_mut()) {
            *o = match self.mesh.closest_point(*p) {
                Some((d2, _, _)) => {
                    let d = d2.sqrt();
                    if self.mesh.contains(*p) { -d } else { d }
                }
                None => f32::INFINITY,
            };
        }
    }
}

fn box_distance_squared(min: Vec3, max: Vec3, p: Vec3) -> f32 {
    let d = (min - p).max(p - max).max(Vec3::ZERO);
    d.length_squared()
}

/// Area-weighted vertex normals of an indexed triangle mesh (unit length; zero for a vertex of
/// only degenerate triangles). Counter-clockwise triangles give outward normals.
pub fn vertex_normals(positions: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut normals = vec![Vec3::ZERO; positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| positions[i as usize]);
        let n = (b - a).cross(c - a); // length = 2 × area: area weighting
        for &i in t {
            normals[i as usize] += n;
        }
    }
    normals.into_iter().map(|n| n.normalize_or_zero()).collect()
}

/// The closest point of triangle abc to p (Ericson, Real-Time Collision Detection, 5.1.5).
pub fn closest_point_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> Vec3 {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

fn slab_hit(min: Vec3, max: Vec3, origin: Vec3, inv: Vec3, t_min: f32, t_max: f32) -> bool {
    let t0 = (min - origin) * inv;
    let t1 = (max - origin) * inv;
    // NaN (0·∞ for a ray in a slab's plane) is dropped by min/max, which is the safe answer.
    let near = t0.min(t1).max_element().max(t_min);
    let far = t0.max(t1).min_element().min(t_max);
    near <= far
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A unit cube [-0.5, 0.5]³ with outward (counter-clockwise) faces.
    pub(crate) fn cube() -> TriangleMesh {
        let p: Vec<Vec3> = (0..8).map(|i| Vec3::new((i & 1) as f32 - 0.5, ((i >> 1) & 1) as f32 - 0.5, ((i >> 2) & 1) as f32 - 0.5)).collect();
        let quads = [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]];
        let tris = quads.iter().flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]]).collect();
        TriangleMesh::new(p, tris)
    }

    #[test]
    fn ray_hits_cube_faces_with_outward_normals() {
        let m = cube();
        let hit = m.ray_hit(Vec3::new(-3.0, 0.1, 0.2), Vec3::X, 0.0, 100.0).unwrap();
        assert!((hit.t - 2.5).abs() < 1e-6);
        assert!(m.face_normal(hit.triangle).normalize().dot(-Vec3::X) > 0.999);
        assert!(m.ray_hit(Vec3::new(-3.0, 0.6, 0.2), Vec3::X, 0.0, 100.0).is_none());
        // From inside, the exit face.
        let hit = m.ray_hit(Vec3::ZERO, Vec3::Z, 0.0, 100.0).unwrap();
        assert!((hit.t - 0.5).abs() < 1e-6);
    }

    #[test]
    fn cube_sdf_matches_the_analytic_box() {
        use crate::field::{SdfField, Shape};
        let sdf = MeshSdf { mesh: cube() };
        let b = Shape::Box { center: glam::DVec3::ZERO, half_extents: glam::DVec3::splat(0.5) };
        let points: Vec<Vec3> =
            (0..500).map(|i| Vec3::new((i as f32 * 0.618).fract(), (i as f32 * 0.377).fract(), (i as f32 * 0.913).fract()) * 2.0 - 1.0).collect();
        let mut out = vec![0.0; points.len()];
        sdf.sdf_batch(&points, &mut out);
        for (p, d) in points.iter().zip(&out) {
            let expect = b.sdf(p.as_dvec3()) as f32;
            assert!((d - expect).abs() < 1e-5, "{p}: {d} vs {expect}");
        }
    }

    #[test]
    fn bvh_agrees_with_brute_force_on_many_triangles() {
        // A 30×30 height field: compare the BVH with testing every triangle.
        let n = 30;
        let mut p = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                let (x, y) = (i as f32 / n as f32 - 0.5, j as f32 / n as f32 - 0.5);
                p.push(Vec3::new(x, y, 0.1 * (7.0 * x).sin() * (5.0 * y).cos()));
            }
        }
        let mut t = Vec::new();
        for j in 0..n {
            for i in 0..n {
                let a = j * (n + 1) + i;
                t.push([a, a + 1, a + n + 2]);
                t.push([a, a + n + 2, a + n + 1]);
            }
        }
        let m = TriangleMesh::new(p, t);
        for k in 0..200 {
            let x = (k as f32 * 0.618).fract() - 0.5;
            let y = (k as f32 * 0.377).fract() - 0.5;
            let o = Vec3::new(x, y, 1.0);
            let d = Vec3::new(0.1, -0.2, -1.0).normalize();
            let bvh = m.ray_hit(o, d, 0.0, 10.0).map(|h| h.t);
            let brute = (0..m.triangles.len() as u32)
                .filter_map(|tri| m.intersect(tri, o, d).map(|h| h.0))
                .filter(|t| *t > 0.0)
                .fold(None, |b: Option<f32>, t| Some(b.map_or(t, |b| b.min(t))));
            assert_eq!(bvh, brute, "ray {k}");
        }
    }
}
