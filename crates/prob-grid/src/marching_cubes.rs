//! Mesh extraction: marching cubes on a dense grid with shared vertices, block by block.
//!
//! The grid `[min, max]` is cut into `resolution` cells per axis and into blocks of `block³`
//! cells. A block is evaluated only when its centre is within `L · half-diagonal` of the surface
//! (L = the field's Lipschitz bound; a block further away cannot hold the iso-surface), so the
//! work and memory follow the surface, not the volume: resolution 1024 needs only the blocks
//! the surface crosses. Within a block the (block + 1)³ corner values are computed in one batch
//! and each cube is triangulated with Lorensen & Cline's tables (`mc_tables`). Vertices
//! sit on grid edges (linear interpolation) and are keyed by their global edge, so neighbouring
//! cubes and blocks share them: the mesh of a closed surface is watertight.
//!
//! Inside is `S < iso`; triangles are wound so that normals point outwards (towards S > iso).

use crate::field::SdfField;
use crate::mc_tables::{EDGE_CORNERS, EDGE_TABLE, TRI_TABLE};
use crate::scene::{GridError, LipschitzCheck};
use glam::{UVec3, Vec3};
use rayon::prelude::*;
use std::collections::HashMap;

/// Where and how finely to extract.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarchingCubesConfig {
    /// Lower corner of the grid.
    pub min: Vec3,
    /// Upper corner of the grid.
    pub max: Vec3,
    /// Cells per axis (≥ 2).
    pub resolution: u32,
    /// Cells per block edge (≥ 1).
    pub block: u32,
    /// The iso-value (0 for an SDF's zero level set).
    pub iso: f32,
}

impl Default for MarchingCubesConfig {
    fn default() -> Self {
        MarchingCubesConfig { min: Vec3::splat(-1.0), max: Vec3::splat(1.0), resolution: 256, block: 32, iso: 0.0 }
    }
}

/// An indexed triangle mesh (shared vertices).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct IsoMesh {
    /// Vertex positions.
    pub vertices: Vec<Vec3>,
    /// Triangles (counter-clockwise seen from outside).
    pub triangles: Vec<[u32; 3]>,
}

/// What an extraction did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ExtractionStats {
    /// Blocks in the grid.
    pub blocks: usize,
    /// Blocks evaluated (near the surface).
    pub blocks_evaluated: usize,
    /// Field queries of the final pass: every block centre and the corners of the blocks it
    /// evaluated (a block an earlier pass meshed counts here once; its centre queries do not).
    pub field_queries: usize,
    /// The field's Lipschitz claim checked against its values (block centres against their
    /// neighbours and their blocks' corners); a broken claim redoes the extraction with a larger
    /// bound, meshing only the blocks it adds.
    pub lipschitz: LipschitzCheck,
}

/// Global id of the grid edge from vertex `v` along `axis`.
fn edge_key(v: UVec3, axis: usize, n: u64) -> u64 {
    ((u64::from(v.z) * n + u64::from(v.y)) * n + u64::from(v.x)) * 3 + axis as u64
}

const CORNERS: [[u32; 3]; 8] = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]];

/// Extracts the iso-surface of `field`.
pub fn marching_cubes(field: &dyn SdfField, config: &MarchingCubesConfig) -> Result<(IsoMesh, ExtractionStats), GridError> {
    marching_cubes_with_progress(field, config, &|_, _| {})
}

/// [`marching_cubes`], calling `progress(blocks done, blocks to evaluate)` as blocks finish (from
/// worker threads). The blocks to evaluate are those near the surface; a broken Lipschitz claim
/// restarts the count with more blocks, those already meshed counted done.
pub fn marching_cubes_with_progress(
    field: &dyn SdfField,
    config: &MarchingCubesConfig,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(IsoMesh, ExtractionStats), GridError> {
    // Blocks meshed by an earlier pass: a redo with a larger bound only adds blocks, and a block's
    // mesh does not depend on the bound. The mesh is merged once, from the last pass's blocks.
    let mut meshed = HashMap::new();
    let ((near, mut stats), check) = LipschitzCheck::run(field.lipschitz_bound(), |bound| {
        let (near, stats, measured) = extract(field, config, bound, progress, &mut meshed)?;
        Ok::<_, GridError>(((near, stats), measured))
    })?;
    stats.lipschitz = check;
    let parts = near.iter().map(|b| meshed.remove(b).expect("every block near the surface is meshed"));
    Ok((merge(parts), stats))
}

/// The lattice of an extraction: `resolution` cells per axis from `min`, cut into cubic blocks
/// of `block` cells.
struct Lattice {
    min: Vec3,
    cell: Vec3,
    res: u32,
    block: u32,
    iso: f32,
}

impl Lattice {
    /// The position of lattice vertex `v`.
    fn point(&self, v: UVec3) -> Vec3 {
        self.min + v.as_vec3() * self.cell
    }

    /// The first and one-past-last cell of block `b` (the last block may be smaller).
    fn block_range(&self, b: UVec3) -> (UVec3, UVec3) {
        let lo = b * self.block;
        let hi = (lo + UVec3::splat(self.block)).min(UVec3::splat(self.res));
        (lo, hi)
    }
}

/// One block's share of the mesh: its vertices by global edge key, its triangles (indices into
/// its own vertices), the field queries it made and the largest slope it measured.
struct BlockMesh {
    keys: Vec<u64>,
    positions: Vec<Vec3>,
    triangles: Vec<[u32; 3]>,
    queries: usize,
    slope: f32,
}

/// One pass with Lipschitz bound `lipschitz`: meshes the blocks near the surface that `meshed`
/// (an earlier pass's) lacks, into it. Returns the blocks near the surface in order, the pass's
/// stats and the largest slope measured (between block centres and in every block near).
fn extract(
    field: &dyn SdfField,
    config: &MarchingCubesConfig,
    lipschitz: f32,
    progress: &(dyn Fn(usize, usize) + Sync),
    meshed: &mut HashMap<UVec3, BlockMesh>,
) -> Result<(Vec<UVec3>, ExtractionStats, f32), GridError> {
    let invalid = |message: String| GridError::InvalidConfig { what: "marching cubes", message };
    if config.resolution < 2 || config.block < 1 {
        return Err(invalid(format!("resolution {} must be ≥ 2 and block {} ≥ 1", config.resolution, config.block)));
    }
    if !(config.max.cmpgt(config.min).all()) || !config.min.is_finite() || !config.max.is_finite() {
        return Err(invalid(format!("bounds {:?}..{:?} must be finite with min < max", config.min, config.max)));
    }
    let res = config.resolution;
    let lattice = Lattice { min: config.min, cell: (config.max - config.min) / res as f32, res, block: config.block, iso: config.iso };
    let blocks_per_axis = res.div_ceil(config.block);

    // Block centres → which blocks can hold the surface.
    let blocks: Vec<UVec3> =
        (0..blocks_per_axis).flat_map(|z| (0..blocks_per_axis).flat_map(move |y| (0..blocks_per_axis).map(move |x| UVec3::new(x, y, z)))).collect();
    let centres: Vec<Vec3> = blocks
        .iter()
        .map(|&b| {
            let (lo, hi) = lattice.block_range(b);
            0.5 * (lattice.point(lo) + lattice.point(hi))
        })
        .collect();
    let mut centre_values = vec![0.0f32; centres.len()];
    centre_values.par_chunks_mut(4096).zip(centres.par_chunks(4096)).for_each(|(o, p)| field.sdf_batch(p, o));
    let near: Vec<(UVec3, Vec3, f32)> = blocks
        .iter()
        .zip(&centres)
        .zip(&centre_values)
        .filter(|&((&b, _), &v)| {
            let (lo, hi) = lattice.block_range(b);
            let half_diagonal = 0.5 * (lattice.point(hi) - lattice.point(lo)).length();
            // NaN counts as "maybe": evaluate.
            !((v - config.iso).abs() > lipschitz * half_diagonal * 1.01 + 1e-6)
        })
        .map(|((&b, &c), &v)| (b, c, v))
        .collect();
    // Slopes between neighbouring block centres.
    let measured = crate::scene::neighbour_slope(&centre_values, blocks_per_axis as usize, |a, b| centres[a].distance(centres[b]));
    let done = std::sync::atomic::AtomicUsize::new(near.iter().filter(|(b, _, _)| meshed.contains_key(b)).count());
    progress(done.load(std::sync::atomic::Ordering::Relaxed), near.len());
    let new: Vec<(UVec3, BlockMesh)> = near
        .par_iter()
        .filter(|(b, _, _)| !meshed.contains_key(b))
        .map(|&(b, centre, centre_value)| {
            let part = mesh_block(&lattice, field, b, centre, centre_value);
            progress(done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1, near.len());
            (b, part)
        })
        .collect();
    meshed.extend(new);
    let near: Vec<UVec3> = near.into_iter().map(|(b, _, _)| b).collect();
    let (queries, measured) = near.iter().map(|b| &meshed[b]).fold((centres.len(), measured), |(q, m), part| (q + part.queries, m.max(part.slope)));
    let stats = ExtractionStats { blocks: blocks.len(), blocks_evaluated: near.len(), field_queries: queries, ..Default::default() };
    Ok((near, stats, measured))
}

/// Block `b`'s corners through the field (its slopes against its centre's value, which the
/// Lipschitz claim must cover) and its cells' triangles.
fn mesh_block(lattice: &Lattice, field: &dyn SdfField, b: UVec3, centre: Vec3, centre_value: f32) -> BlockMesh {
    let (lo, hi) = lattice.block_range(b);
    let dim = hi - lo + UVec3::ONE; // corners per axis
    let idx = |v: UVec3| ((v.z * dim.y + v.y) * dim.x + v.x) as usize;
    let mut points = Vec::with_capacity((dim.x * dim.y * dim.z) as usize);
    for z in 0..dim.z {
        for y in 0..dim.y {
            for x in 0..dim.x {
                points.push(lattice.point(lo + UVec3::new(x, y, z)));
            }
        }
    }
    let mut values = vec![0.0f32; points.len()];
    field.sdf_batch(&points, &mut values);
    let slope = points
        .iter()
        .zip(&values)
        .map(|(p, v)| {
            let d = p.distance(centre);
            if d > 0.0 { (v - centre_value).abs() / d } else { 0.0 }
        })
        .filter(|x| x.is_finite())
        .fold(0.0f32, f32::max);
    let mut local: HashMap<u64, u32> = HashMap::new();
    let mut out = BlockMesh { keys: Vec::new(), positions: Vec::new(), triangles: Vec::new(), queries: points.len(), slope };
    for z in 0..dim.z - 1 {
        for y in 0..dim.y - 1 {
            for x in 0..dim.x - 1 {
                let c = UVec3::new(x, y, z);
                let vals: [f32; 8] = CORNERS.map(|o| values[idx(c + UVec3::from_array(o))]);
                mesh_cell(lattice, lo + c, &vals, &mut local, &mut out);
            }
        }
    }
    out
}

/// The triangles of the cell whose lowest corner is lattice vertex `corner`, with corner values
/// `vals`; new edge vertices go to `out` (found again through `local`).
fn mesh_cell(lattice: &Lattice, corner: UVec3, vals: &[f32; 8], local: &mut HashMap<u64, u32>, out: &mut BlockMesh) {
    if vals.iter().any(|v| !v.is_finite()) {
        return; // no surface where the field is undefined
    }
    let case = vals.iter().enumerate().fold(0usize, |acc, (i, &v)| acc | (usize::from(v < lattice.iso) << i));
    if EDGE_TABLE[case] == 0 {
        return;
    }
    let n_vertices_axis = u64::from(lattice.res) + 1;
    let mut edge_vertex = [u32::MAX; 12];
    for e in 0..12 {
        if EDGE_TABLE[case] & (1 << e) == 0 {
            continue;
        }
        let [a, b2] = EDGE_CORNERS[e];
        // The edge's lower corner and axis, in global vertex coordinates.
        let (ca, cb) = (UVec3::from_array(CORNERS[a]), UVec3::from_array(CORNERS[b2]));
        let base = corner + ca.min(cb);
        let axis = (ca.max(cb) - ca.min(cb)).to_array().iter().position(|&d| d == 1).expect("unit edge");
        let key = edge_key(base, axis, n_vertices_axis);
        let id = *local.entry(key).or_insert_with(|| {
            // Interpolate from the lower corner so both blocks compute the same bits.
            let (v0, v1) = if ca.min(cb) == ca { (vals[a], vals[b2]) } else { (vals[b2], vals[a]) };
            let f = ((lattice.iso - v0) / (v1 - v0)).clamp(0.0, 1.0);
            let mut p = lattice.point(base);
            p[axis] += f * lattice.cell[axis];
            out.keys.push(key);
            out.positions.push(p);
            (out.positions.len() - 1) as u32
        });
        edge_vertex[e] = id;
    }
    for tri in TRI_TABLE[case].chunks(3) {
        if tri[0] < 0 {
            break;
        }
        let t = [edge_vertex[tri[0] as usize], edge_vertex[tri[2] as usize], edge_vertex[tri[1] as usize]];
        if t[0] != t[1] && t[1] != t[2] && t[0] != t[2] {
            out.triangles.push(t);
        }
    }
}

/// The blocks' meshes as one: vertices on block faces appear in both blocks; the first one wins.
fn merge(parts: impl Iterator<Item = BlockMesh>) -> IsoMesh {
    let mut mesh = IsoMesh::default();
    let mut global: HashMap<u64, u32> = HashMap::new();
    for part in parts {
        let remap: Vec<u32> = part
            .keys
            .iter()
            .zip(&part.positions)
            .map(|(&k, &p)| {
                *global.entry(k).or_insert_with(|| {
                    mesh.vertices.push(p);
                    (mesh.vertices.len() - 1) as u32
                })
            })
            .collect();
        mesh.triangles.extend(part.triangles.iter().map(|t| t.map(|i| remap[i as usize])));
    }
    mesh
}

impl IsoMesh {
    /// Connected components (triangles sharing a vertex): a label per triangle in `0..count`,
    /// numbered in the order of their first triangle, and the count.
    pub fn component_labels(&self) -> (Vec<u32>, usize) {
        let n = self.vertices.len();
        let mut parent: Vec<u32> = (0..n as u32).collect();
        fn find(parent: &mut [u32], mut x: u32) -> u32 {
            while parent[x as usize] != x {
                parent[x as usize] = parent[parent[x as usize] as usize];
                x = parent[x as usize];
            }
            x
        }
        for t in &self.triangles {
            for k in 1..3 {
                let (a, b) = (find(&mut parent, t[0]), find(&mut parent, t[k]));
                if a != b {
                    parent[a as usize] = b;
                }
            }
        }
        let mut label_of_root: HashMap<u32, u32> = HashMap::new();
        let labels = self
            .triangles
            .iter()
            .map(|t| {
                let root = find(&mut parent, t[0]);
                let next = label_of_root.len() as u32;
                *label_of_root.entry(root).or_insert(next)
            })
            .collect();
        (labels, label_of_root.len())
    }

    /// The triangles whose component label is kept (`keep[labels[t]]`); vertices are reindexed.
    pub fn select_components(&self, labels: &[u32], keep: &[bool]) -> IsoMesh {
        let mut remap = vec![u32::MAX; self.vertices.len()];
        let mut out = IsoMesh::default();
        for (t, &label) in self.triangles.iter().zip(labels) {
            if !keep[label as usize] {
                continue;
            }
            out.triangles.push(t.map(|v| {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = out.vertices.len() as u32;
                    out.vertices.push(self.vertices[v as usize]);
                }
                remap[v as usize]
            }));
        }
        out
    }

    /// Surface area of each component (`labels` and `count` from [`Self::component_labels`]).
    pub fn component_areas(&self, labels: &[u32], count: usize) -> Vec<f64> {
        let mut areas = vec![0.0f64; count];
        for (t, &label) in self.triangles.iter().zip(labels) {
            let [a, b, c] = t.map(|i| self.vertices[i as usize].as_dvec3());
            areas[label as usize] += 0.5 * (b - a).cross(c - a).length();
        }
        areas
    }

    /// Keeps only the largest connected component (by triangle count; ties: the first);
    /// vertices are reindexed.
    pub fn largest_component(&self) -> IsoMesh {
        let (labels, count) = self.component_labels();
        let mut triangles = vec![0usize; count];
        for &l in &labels {
            triangles[l as usize] += 1;
        }
        let Some(best) = (0..count).max_by_key(|&c| (triangles[c], std::cmp::Reverse(c))) else {
            return IsoMesh::default();
        };
        let keep: Vec<bool> = (0..count).map(|c| c == best).collect();
        self.select_components(&labels, &keep)
    }

    /// Euler characteristic V − E + F.
    pub fn euler_characteristic(&self) -> i64 {
        let edges: std::collections::HashSet<(u32, u32)> =
            self.triangles.iter().flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])].map(|(a, b)| (a.min(b), a.max(b)))).collect();
        self.vertices.len() as i64 - edges.len() as i64 + self.triangles.len() as i64
    }

    /// True when every edge is shared by exactly two triangles, in opposite directions.
    pub fn is_watertight(&self) -> bool {
        let mut directed: HashMap<(u32, u32), u32> = HashMap::new();
        for t in &self.triangles {
            for (a, b) in [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])] {
                *directed.entry((a, b)).or_default() += 1;
            }
        }
        directed.iter().all(|(&(a, b), &c)| c == 1 && directed.get(&(b, a)) == Some(&1))
    }

    /// Signed volume (positive when triangles face outwards).
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize].as_dvec3());
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::field::Shape;
    use glam::DVec3;

    fn extract(shape: &Shape, res: u32, block: u32) -> (IsoMesh, ExtractionStats, f32) {
        let config = MarchingCubesConfig { resolution: res, block, ..Default::default() };
        let (mesh, stats) = marching_cubes(shape, &config).unwrap();
        (mesh, stats, 2.0 / res as f32)
    }

    fn max_vertex_error(shape: &Shape, mesh: &IsoMesh) -> f32 {
        let mut values = vec![0.0; mesh.vertices.len()];
        shape.sdf_batch(&mesh.vertices, &mut values);
        values.iter().fold(0.0f32, |m, v| m.max(v.abs()))
    }

    #[test]
    fn sphere_mesh_is_watertight_genus_zero_and_within_half_a_voxel() {
        let sphere = Shape::Sphere { center: DVec3::new(0.05, -0.02, 0.01), radius: 0.6 };
        for (res, block) in [(48, 7), (96, 32)] {
            let (mesh, stats, voxel) = extract(&sphere, res, block);
            assert!(mesh.is_watertight(), "res {res}: not watertight");
            assert_eq!(mesh.euler_characteristic(), 2, "res {res}");
            let err = max_vertex_error(&sphere, &mesh);
            assert!(err <= 0.5 * voxel, "res {res}: vertex error {err} > half voxel {}", 0.5 * voxel);
            let volume = 4.0 / 3.0 * std::f64::consts::PI * 0.6f64.powi(3);
            assert!((mesh.signed_volume() / volume - 1.0).abs() < 0.02, "volume {} vs {volume}", mesh.signed_volume());
            assert!(stats.blocks_evaluated < stats.blocks, "res {res}: {stats:?}");
        }
    }

    #[test]
    fn torus_mesh_is_watertight_genus_one() {
        let torus = Shape::Torus { center: DVec3::ZERO, major_radius: 0.55, minor_radius: 0.2 };
        let (mesh, _, voxel) = extract(&torus, 80, 16);
        assert!(mesh.is_watertight());
        assert_eq!(mesh.euler_characteristic(), 0);
        assert!(max_vertex_error(&torus, &mesh) <= 0.5 * voxel);
        assert!(mesh.signed_volume() > 0.0);
    }

    #[test]
    fn block_size_does_not_change_the_mesh() {
        let torus = Shape::Torus { center: DVec3::ZERO, major_radius: 0.5, minor_radius: 0.25 };
        let (a, _, _) = extract(&torus, 40, 40);
        let (b, _, _) = extract(&torus, 40, 6);
        assert_eq!(a.triangles.len(), b.triangles.len());
        assert_eq!(a.vertices.len(), b.vertices.len());
        let key = |m: &IsoMesh| {
            let mut v: Vec<[u32; 3]> = m.vertices.iter().map(|p| p.to_array().map(f32::to_bits)).collect();
            v.sort();
            v
        };
        assert_eq!(key(&a), key(&b));
    }

    #[test]
    fn largest_component_drops_the_small_sphere() {
        let two = Shape::Union(vec![
            Shape::Sphere { center: DVec3::new(-0.4, 0.0, 0.0), radius: 0.4 },
            Shape::Sphere { center: DVec3::new(0.6, 0.0, 0.0), radius: 0.15 },
        ]);
        let (mesh, _, _) = extract(&two, 64, 16);
        assert_eq!(mesh.euler_characteristic(), 4);
        let big = mesh.largest_component();
        assert_eq!(big.euler_characteristic(), 2);
        assert!(big.vertices.iter().all(|p| p.x < 0.1));
        let (labels, count) = mesh.component_labels();
        assert_eq!(count, 2);
        let areas = mesh.component_areas(&labels, count);
        let mut sorted = areas.clone();
        sorted.sort_by(f64::total_cmp);
        // 4π r² for r = 0.15 and 0.4, within the mesh's discretisation.
        assert!((sorted[0] - 0.2827).abs() < 0.02 && (sorted[1] - 2.0106).abs() < 0.1, "{areas:?}");
    }

    /// A sphere's SDF times 4 (slope 4) that claims `claim` as its Lipschitz bound, counting the
    /// points it is asked for.
    struct Steep {
        claim: f32,
        queries: std::sync::atomic::AtomicUsize,
    }

    impl Steep {
        fn claiming(claim: f32) -> Steep {
            Steep { claim, queries: Default::default() }
        }
    }

    impl SdfField for Steep {
        fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
            self.queries.fetch_add(points.len(), std::sync::atomic::Ordering::Relaxed);
            for (p, o) in points.iter().zip(out) {
                *o = 4.0 * ((*p - Vec3::new(0.13, -0.07, 0.05)).length() - 0.45);
            }
        }
        fn lipschitz_bound(&self) -> f32 {
            self.claim
        }
    }

    /// Regression: blocks were skipped by the field's claimed bound without checking it; a field
    /// steeper than it claims lost parts of its surface (holes) silently.
    #[test]
    fn marching_cubes_detects_a_broken_lipschitz_claim_and_keeps_the_surface_closed() {
        let config = MarchingCubesConfig { resolution: 64, block: 8, ..Default::default() };
        let (mesh, stats) = marching_cubes(&Steep::claiming(1.0), &config).unwrap();
        assert!(stats.lipschitz.retries >= 1 && stats.lipschitz.measured > 3.5, "{:?}", stats.lipschitz);
        assert_eq!(mesh.euler_characteristic(), 2, "the sphere must come out closed");
    }

    /// A redo after a broken claim meshes only the blocks the larger bound adds: the blocks of
    /// the first pass are not evaluated again (the default run's mesh took twice its time when
    /// its claim broke), and the mesh is the one an honest claim gives.
    #[test]
    fn a_broken_lipschitz_claim_reuses_the_blocks_already_meshed() {
        let config = MarchingCubesConfig { resolution: 64, block: 8, ..Default::default() };
        let broken = Steep::claiming(1.0);
        let (mesh, stats) = marching_cubes(&broken, &config).unwrap();
        assert!(stats.lipschitz.retries >= 1, "{:?}", stats.lipschitz);
        // Each pass queries every block's centre; each block's corners are queried once.
        let passes = stats.lipschitz.retries as usize + 1;
        assert_eq!(broken.queries.into_inner(), stats.field_queries + (passes - 1) * stats.blocks);
        let (expected, _) = marching_cubes(&Steep::claiming(6.0), &config).unwrap();
        assert_eq!((mesh.vertices, mesh.triangles), (expected.vertices, expected.triangles));
    }

    #[test]
    fn empty_field_gives_an_empty_mesh_and_bad_config_an_error() {
        let far = Shape::Sphere { center: DVec3::new(5.0, 0.0, 0.0), radius: 0.1 };
        let (mesh, stats, _) = extract(&far, 32, 8);
        assert!(mesh.triangles.is_empty() && stats.blocks_evaluated == 0);
        assert!(mesh.largest_component().triangles.is_empty());
        let bad = MarchingCubesConfig { resolution: 1, ..Default::default() };
        assert!(marching_cubes(&far, &bad).is_err());
        let bad = MarchingCubesConfig { max: Vec3::splat(-2.0), ..Default::default() };
        assert!(marching_cubes(&far, &bad).is_err());
    }
}
