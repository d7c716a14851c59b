//! What a run shows and leaves: renders of views (PSNR, SSIM, validation panels), pdf heat maps,
//! the mesh (connected components filtered, written in the input's world units with optional
//! vertex colours) and its picture, and geometry metrics.

use crate::config::MeshFilter;
use crate::draw::colormap;
use crate::error::Result;
use crate::metrics::{ObservedMetrics, PartMetrics};
use datasets::Scene;
use datasets::images::RgbImage;
use datasets::io::{MeshFormat, mesh_bytes};
use glam::{DMat4, Vec3};
use prob_grid::IsoMesh;
use sdf_backbone::RayOutput;

/// A view rendered at `downscale`: prediction and targets, row-major.
pub struct ViewRender {
    /// Width.
    pub width: u32,
    /// Height.
    pub height: u32,
    /// Outputs per pixel.
    pub outputs: Vec<RayOutput<f32>>,
    /// Ground-truth colours.
    pub target: Vec<[f32; 3]>,
    /// Mask, if the view has one.
    pub mask: Option<Vec<bool>>,
}

impl ViewRender {
    /// PSNR over the whole image and inside the mask.
    pub fn psnr(&self) -> (f64, Option<f64>) {
        let pred: Vec<[f32; 3]> = self.outputs.iter().map(|o| o.color).collect();
        let whole = eval_metrics::psnr(&pred, &self.target, None).unwrap_or(f64::NAN);
        let masked = self.mask.as_ref().and_then(|m| eval_metrics::psnr(&pred, &self.target, Some(m)).ok());
        (whole, masked)
    }

    /// SSIM over the whole image.
    pub fn ssim(&self) -> Option<f64> {
        let pred: Vec<[f32; 3]> = self.outputs.iter().map(|o| o.color).collect();
        eval_metrics::ssim(&pred, &self.target, self.width as usize, self.height as usize).ok()
    }

    /// RGB | ground truth | |error| (×4) | normal | depth, side by side.
    pub fn panel(&self) -> RgbImage {
        let (w, h) = (self.width, self.height);
        let mut img = RgbImage::new(5 * w, h);
        let hit: Vec<f32> = self.outputs.iter().filter(|o| o.opacity > 0.5).map(|o| o.depth / o.opacity).collect();
        let (d_lo, d_hi) = hit.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &d| (a.min(d), b.max(d)));
        for r in 0..h {
            for c in 0..w {
                let i = (r * w + c) as usize;
                let o = &self.outputs[i];
                let t = self.target[i];
                img.set_f32(c, r, o.color);
                img.set_f32(w + c, r, t);
                img.set_f32(2 * w + c, r, [0, 1, 2].map(|k| ((o.color[k] - t[k]).abs() * 4.0).min(1.0)));
                let n = Vec3::from_array(o.normal);
                let n = if n.length() > 1e-6 { n.normalize() } else { Vec3::ZERO };
                img.set_f32(3 * w + c, r, (n * 0.5 + 0.5).to_array().map(|v| v * o.opacity.clamp(0.0, 1.0)));
                let depth = if o.opacity > 0.5 && d_hi > d_lo { colormap(1.0 - (o.depth / o.opacity - d_lo) / (d_hi - d_lo)) } else { [0.0; 3] };
                img.set_f32(4 * w + c, r, depth);
            }
        }
        img
    }
}

/// A heat map of a pixel marginal (R_u × R_v, row-major in v), scaled up `zoom` times.
pub fn heat_map(marginal: &[f64], ru: usize, rv: usize, zoom: u32) -> RgbImage {
    let peak = marginal.iter().copied().fold(0.0f64, f64::max).max(1e-300);
    let mut img = RgbImage::new(ru as u32 * zoom, rv as u32 * zoom);
    for y in 0..img.height {
        for x in 0..img.width {
            let v = marginal[(y / zoom) as usize * ru + (x / zoom) as usize] / peak;
            img.set_f32(x, y, colormap(v as f32));
        }
    }
    img
}

/// Which connected components of `mesh` (normalised frame) to keep, by `filter`: `supported`
/// keeps the largest component always (it is never a floater) and, with masks, the components
/// whose vertices lie in the visual hull (a vertex is in it
/// when ≥ 90 % of the training views that see it in frame have it in their foreground, the mask
/// dilated by 2 pixels; a component is kept when ≥ half of up to 200 of its vertices are), and
/// without masks the components of at least `min_area` of the mesh's area. Returns the kept mesh
/// and (components, kept).
pub fn filter_components(
    mesh: &IsoMesh,
    filter: MeshFilter,
    scene: &Scene,
    train_views: &[usize],
    use_masks: bool,
    min_area: f64,
) -> (IsoMesh, usize, usize) {
    let (labels, count) = mesh.component_labels();
    let keep: Vec<bool> = match filter {
        MeshFilter::All => vec![true; count],
        MeshFilter::Largest => {
            let kept = mesh.largest_component();
            let n = usize::from(!kept.triangles.is_empty());
            return (kept, count, n);
        }
        MeshFilter::Supported if use_masks => {
            let masks: Vec<(camera_geom::PinholeCamera, datasets::images::Mask)> =
                train_views.iter().filter_map(|&v| scene.views[v].mask.as_ref().map(|m| (scene.views[v].camera, dilate(m, 2)))).collect();
            // Up to 200 vertices per component, spread over its triangles.
            let mut members: Vec<Vec<u32>> = vec![Vec::new(); count];
            for (t, &l) in mesh.triangles.iter().zip(&labels) {
                members[l as usize].push(t[0]);
            }
            members
                .iter()
                .map(|vertices| {
                    let step = vertices.len().div_ceil(200).max(1);
                    let sample: Vec<u32> = vertices.iter().copied().step_by(step).collect();
                    let in_hull = sample
                        .iter()
                        .filter(|&&v| {
                            let p = mesh.vertices[v as usize].as_dvec3();
                            let (mut seen, mut fg) = (0usize, 0usize);
                            for (camera, mask) in &masks {
                                let x = camera.pixel_space_from_world(p);
                                if x.z <= 0.0 {
                                    continue;
                                }
                                if let Some((c, r)) = camera.nearest_pixel(x.truncate()) {
                                    seen += 1;
                                    fg += usize::from(mask.get(c, r));
                                }
                            }
                            seen > 0 && fg * 10 >= seen * 9
                        })
                        .count();
                    in_hull * 2 >= sample.len()
                })
                .collect()
        }
        MeshFilter::Supported => {
            let areas = mesh.component_areas(&labels, count);
            let total: f64 = areas.iter().sum();
            areas.iter().map(|a| *a >= min_area * total).collect()
        }
    };
    let mut keep = keep;
    if filter == MeshFilter::Supported && count > 0 {
        let mut triangles = vec![0usize; count];
        for &l in &labels {
            triangles[l as usize] += 1;
        }
        let largest = (0..count).max_by_key(|&c| (triangles[c], std::cmp::Reverse(c))).expect("count > 0");
        keep[largest] = true;
    }
    let kept = keep.iter().filter(|k| **k).count();
    (mesh.select_components(&labels, &keep), count, kept)
}

/// A mask dilated by a square of half-width `r` pixels.
pub fn dilate(mask: &datasets::images::Mask, r: u32) -> datasets::images::Mask {
    let (w, h) = (mask.width, mask.height);
    let mut out = datasets::images::Mask::new(w, h);
    for y in 0..h {
        for x in 0..w {
            if mask.get(x, y) {
                for yy in y.saturating_sub(r)..(y + r + 1).min(h) {
                    for xx in x.saturating_sub(r)..(x + r + 1).min(w) {
                        out.set(xx, yy, true);
                    }
                }
            }
        }
    }
    out
}

/// The mesh's bytes in each format, in the input's world units (`world_from_normalized`
/// applied; a reflection flips the winding so that normals stay outward): (format, bytes).
pub fn mesh_files(mesh: &IsoMesh, world_from_normalized: &DMat4, colors: Option<&[[u8; 3]]>, formats: &[MeshFormat]) -> Vec<(MeshFormat, Vec<u8>)> {
    let positions: Vec<Vec3> = mesh.vertices.iter().map(|p| world_from_normalized.transform_point3(p.as_dvec3()).as_vec3()).collect();
    let flip = world_from_normalized.determinant() < 0.0;
    let faces: Vec<[u32; 3]> = mesh.triangles.iter().map(|t| if flip { [t[0], t[2], t[1]] } else { *t }).collect();
    formats.iter().map(|&f| (f, mesh_bytes(f, &positions, &faces, colors))).collect()
}

/// The mesh's surface sampled every `spacing` (normalised frame), as the metrics compare it
/// (the floor's truth mesh: no normals needed, none computed).
fn mesh_points(mesh: &IsoMesh, spacing: f64) -> Result<Vec<[f32; 3]>> {
    let v: Vec<[f32; 3]> = mesh.vertices.iter().map(|p| p.to_array()).collect();
    Ok(eval_metrics::sample_mesh(&v, &mesh.triangles, spacing, crate::evaluation::PRED_SAMPLING_SEED)?)
}

/// [`mesh_points`] with their triangles' normals (the same points).
fn oriented_mesh_points(mesh: &IsoMesh, spacing: f64) -> Result<eval_metrics::OrientedPoints> {
    let v: Vec<[f32; 3]> = mesh.vertices.iter().map(|p| p.to_array()).collect();
    Ok(eval_metrics::sample_mesh_oriented(&v, &mesh.triangles, spacing, crate::evaluation::PRED_SAMPLING_SEED)?)
}

/// Completeness and recall of a mesh (`pred`: its surface points) on each part of `shape` (one
/// entry per part of a union; none for a single primitive): `gt` (the shape's surface points)
/// grouped by the part nearest, at the protocol's `max_dist` and `tau`; and the accuracy of the
/// mesh's points nearest each part.
pub fn part_metrics(
    shape: &prob_grid::Shape,
    pred: &[[f32; 3]],
    gt: &[[f32; 3]],
    nearest: &eval_metrics::Nearest,
    max_dist: f64,
    tau: f64,
) -> Vec<PartMetrics> {
    let parts = shape.parts();
    if parts.len() < 2 {
        return Vec::new();
    }
    // The nearest distances (one search, `nearest`) of each part's points.
    let by_part = |points: &[[f32; 3]], distances: &[(f32, usize)]| {
        let mut groups = vec![Vec::new(); parts.len()];
        for (p, (d, _)) in points.iter().zip(distances) {
            groups[shape.nearest_part(glam::Vec3::from_array(*p).as_dvec3())].push(*d);
        }
        groups
    };
    let (truth_groups, mesh_groups) = (by_part(gt, &nearest.gt_to_pred), by_part(pred, &nearest.pred_to_gt));
    let finite = crate::metrics::finite;
    parts
        .iter()
        .zip(truth_groups.iter().zip(&mesh_groups))
        .filter(|(_, (group, _))| !group.is_empty())
        .map(|(part, (group, near))| {
            let c = eval_metrics::coverage_of(group.iter().copied(), max_dist, tau);
            let accuracy = (!near.is_empty()).then(|| eval_metrics::coverage_of(near.iter().copied(), max_dist, tau).mean).and_then(finite);
            PartMetrics { part: part.describe(), completeness: finite(c.mean), recall: c.within, accuracy }
        })
        .collect()
}

/// The unit normals of a mesh's sampled points and of the truth's points, one per point, in the
/// order of a [`eval_metrics::Nearest`]'s two sets.
pub type NormalPairs<'a> = (&'a [[f32; 3]], &'a [[f32; 3]]);

/// The normals of a mesh's oriented sample and of a truth, where the truth has them.
pub fn normal_pairs<'a>(mesh: &'a eval_metrics::OrientedPoints, truth: &'a crate::data::Truth) -> Option<NormalPairs<'a>> {
    truth.normals.as_deref().map(|gt_normals| (mesh.normals.as_slice(), gt_normals))
}

/// [`eval_metrics::Nearest::normal_consistency`] of `normals` over `nearest`'s pairs within
/// `max_dist` (with `observed`: over what the views observed); `None` without normals or pairs.
pub fn normal_consistency(
    nearest: &eval_metrics::Nearest,
    normals: Option<NormalPairs>,
    max_dist: f64,
    observed: Option<&[bool]>,
) -> Result<Option<f64>> {
    Ok(normals.map(|(p, g)| nearest.normal_consistency(p, g, max_dist, observed)).transpose()?.flatten())
}

/// What a mesh measured against a run's ground truth ([`run_geometry`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RunGeometry {
    /// Chamfer and F-score.
    pub metrics: eval_metrics::GeometryMetrics,
    /// [`eval_metrics::Nearest::normal_consistency`] over the whole truth (`None`: the truth has
    /// no normals, or no pair lies within the outlier distance).
    pub normal_consistency: Option<f64>,
    /// The truth's own mesh at the resolution asked for ([`shape_floor`]), for an analytic truth.
    pub floor: Option<f64>,
    /// [`part_metrics`] of an analytic truth (empty otherwise).
    pub parts: Vec<PartMetrics>,
    /// The same over what the training views observed ([`crate::observation`]), for an analytic
    /// truth when observers were given.
    pub observed: Option<ObservedMetrics>,
}

/// Chamfer and F-score of `mesh` against `data`'s ground truth with a run's protocol
/// (`output.chamfer_spacing`, `chamfer_max_dist`, `fscore_tau`), and per part of an analytic
/// truth; `None` when the data has no ground truth or the mesh no triangles. With `floor_at`,
/// also the floor: the truth's own marching-cubes mesh at that resolution ([`shape_floor`]) against
/// the same truth points. With
/// `observers` (the training cameras) and an analytic truth, also the figures over what they
/// observe. What the periodic metrics and the snapshots measure.
pub fn run_geometry(
    data: &crate::data::SceneData,
    output: &crate::config::OutputConfig,
    mesh: &IsoMesh,
    floor_at: Option<u32>,
    observers: &[camera_geom::PinholeCamera],
) -> Result<Option<RunGeometry>> {
    let Some(truth) = data.oriented_ground_truth(output.chamfer_spacing)? else { return Ok(None) };
    if mesh.triangles.is_empty() {
        return Ok(None);
    }
    let (spacing, max_dist, tau) = (output.chamfer_spacing, output.chamfer_max_dist, output.fscore_tau);
    let oriented = oriented_mesh_points(mesh, spacing)?;
    let (pred, gt) = (&oriented.points, &truth.points);
    let nearest = eval_metrics::Nearest::new(pred, gt)?;
    let normals = normal_pairs(&oriented, &truth);
    let normal_consistency = normal_consistency(&nearest, normals, max_dist, None)?;
    let shape = data.builtin_shape.as_ref();
    let floor = match (shape, floor_at) {
        (Some(shape), Some(resolution)) => Some(shape_floor(shape, gt, resolution, spacing)?),
        _ => None,
    };
    let parts = match shape {
        Some(shape) => part_metrics(shape, pred, gt, &nearest, max_dist, tau),
        None => Vec::new(),
    };
    let observed = match shape {
        Some(shape) if !observers.is_empty() => Some(observed_metrics(shape, observers, gt, &nearest, (max_dist, tau), floor.as_ref(), normals)?),
        _ => None,
    };
    let floor = floor.map(|f| f.chamfer(max_dist, tau).chamfer);
    Ok(Some(RunGeometry { metrics: nearest.chamfer(max_dist, tau), normal_consistency, floor, parts, observed }))
}

/// The truth's own marching-cubes mesh: `shape` at `resolution` cells per side of the bound's
/// cube, what a floor measures.
fn truth_mesh(shape: &prob_grid::Shape, resolution: u32) -> Result<IsoMesh> {
    let config = prob_grid::MarchingCubesConfig { resolution, block: 16, ..Default::default() };
    Ok(prob_grid::marching_cubes(shape, &config)?.0)
}

/// The floor: the truth's own mesh at `resolution` (`truth_mesh`), sampled every `spacing`,
/// against `gt` (that shape's truth points) — its Chamfer over the whole truth and, with the
/// flags of what the views observe, over that ([`observed_metrics`]).
pub fn shape_floor(shape: &prob_grid::Shape, gt: &[[f32; 3]], resolution: u32, spacing: f64) -> Result<eval_metrics::Nearest> {
    Ok(eval_metrics::Nearest::new(&mesh_points(&truth_mesh(shape, resolution)?, spacing)?, gt)?)
}

/// The figures over what `observers` see of `shape` ([`crate::observation`]): a mesh's nearest
/// neighbours against the truth points `gt` ([`eval_metrics::Nearest`]) by the protocol's (max
/// distance, τ), and with `floor` (the truth's own mesh against `gt`, [`shape_floor`]) its floor
/// measured the same way; with `normals` (the mesh's points', the truth's) the normal
/// consistency over the same pairs.
pub fn observed_metrics(
    shape: &prob_grid::Shape,
    observers: &[camera_geom::PinholeCamera],
    gt: &[[f32; 3]],
    nearest: &eval_metrics::Nearest,
    (max_dist, tau): (f64, f64),
    floor: Option<&eval_metrics::Nearest>,
    normals: Option<NormalPairs>,
) -> Result<ObservedMetrics> {
    let flags = crate::observation::observed(shape, observers, gt);
    let m = nearest.chamfer_observed(&flags, max_dist, tau)?;
    let floor = floor.map(|f| f.chamfer_observed(&flags, max_dist, tau).map(|m| m.chamfer)).transpose()?;
    let normal_consistency = normal_consistency(nearest, normals, max_dist, Some(&flags))?;
    Ok(ObservedMetrics { normal_consistency, ..ObservedMetrics::new(&m, flags.iter().filter(|f| **f).count() as f64 / flags.len() as f64, floor) })
}

/// The widest view of the mesh's picture, in pixels: a picture for people (a DTU view at full
/// resolution, 1600 × 1200, is drawn at 800 × 600).
pub const MESH_PICTURE_WIDTH: u32 = 800;

/// The downscale that draws a view `width` pixels wide at most [`MESH_PICTURE_WIDTH`] wide.
pub fn mesh_picture_downscale(width: u32) -> u32 {
    width.div_ceil(MESH_PICTURE_WIDTH).max(1)
}

/// The mesh (normalised frame) seen from `cameras`, shaded by its normals, side by side.
pub fn mesh_picture(mesh: &IsoMesh, cameras: &[camera_geom::PinholeCamera]) -> RgbImage {
    use datasets::golden::{mesh_io::TexturedMesh, render::Geometry};
    let n = mesh.triangles.len();
    let geometry = Geometry::from_mesh(TexturedMesh {
        mesh: prob_grid::TriangleMesh::new(mesh.vertices.clone(), mesh.triangles.clone()),
        uvs: None,
        triangle_texture: vec![u32::MAX; n],
        textures: Vec::new(),
    });
    let (w, h) = (cameras.iter().map(|c| c.width).sum::<u32>(), cameras.iter().map(|c| c.height).max().unwrap_or(1));
    let mut img = RgbImage::new(w.max(1), h);
    let mut x0 = 0;
    for cam in cameras {
        let r = datasets::golden::render::render_view(&geometry, cam, datasets::golden::Backdrop::None);
        for y in 0..cam.height {
            for x in 0..cam.width {
                let nrm = r.normal[(y * cam.width + x) as usize];
                let rgb = if r.mask.get(x, y) { nrm.map(|v| v * 0.5 + 0.5) } else { [1.0; 3] };
                img.set_f32(x0 + x, y, rgb);
            }
        }
        x0 += cam.width;
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;
    use prob_grid::Shape;

    /// A full-resolution DTU view (1600 wide) is drawn at 800 × 600 in the mesh's picture: drawn
    /// at its own size, the picture held ≈ 130 MB more than the memory model printed.
    #[test]
    fn the_mesh_picture_draws_a_wide_view_at_most_800_pixels_wide() {
        for (width, downscale) in [(200, 1), (800, 1), (801, 2), (1600, 2), (2400, 3), (0, 1)] {
            assert_eq!(mesh_picture_downscale(width), downscale, "{width}");
            assert!(width / downscale <= MESH_PICTURE_WIDTH, "{width}");
        }
    }

    fn surface_points(shape: &Shape, resolution: u32) -> Vec<[f32; 3]> {
        let config = prob_grid::MarchingCubesConfig { resolution, block: 16, ..Default::default() };
        let (mesh, _) = prob_grid::marching_cubes(shape, &config).unwrap();
        mesh_points(&mesh, 0.004).unwrap()
    }

    /// Guards the per-part figures that say whether the built-in scene kept its thin ring: the
    /// truth's own mesh covers every part; a mesh without the ring covers the body and the foot
    /// but not the ring.
    #[test]
    fn part_metrics_see_a_missing_thin_ring_and_where_the_mesh_is_off() {
        let parts_of = |shape: &Shape, pred: &[[f32; 3]], gt: &[[f32; 3]]| {
            part_metrics(shape, pred, gt, &eval_metrics::Nearest::new(pred, gt).unwrap(), 0.1, 0.01)
        };
        let composite = Shape::composite();
        let gt = crate::data::analytic_truth(&composite, 0.004);
        let whole = parts_of(&composite, &surface_points(&composite, 160), &gt);
        assert_eq!(whole.len(), 3);
        assert!(whole.iter().all(|p| p.recall > 0.95 && p.accuracy.unwrap() < 0.004), "{whole:?}");
        let parts = composite.parts();
        let ringless = Shape::Union(vec![parts[0].clone(), parts[2].clone()]);
        let without = parts_of(&composite, &surface_points(&ringless, 160), &gt);
        assert_eq!(without[1].part, "torus 0.58 × 0.04");
        assert!(without[1].recall < 0.05, "{without:?}");
        assert!(without[0].recall > 0.95 && without[2].recall > 0.9, "{without:?}");
        assert_eq!(without[1].accuracy, None, "no point of the mesh is nearest the ring");
        assert!(parts_of(&parts[1], &surface_points(&composite, 64), &gt).is_empty(), "one primitive: no parts");
    }
}
