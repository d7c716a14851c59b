//! What a run shows and leaves: validation renders, pdf heat maps, the mesh (PLY/OBJ/GLB in
//! the input's world units, optional vertex colours), and the metrics.

use super::config::TrainConfig;
use super::rays::base_ray;
use crate::draw::colormap;
use anyhow::{Context, Result};
use datasets::images::RgbImage;
use datasets::io::{PlyData, write_atomic};
use datasets::{Scene, View};
use glam::{DMat4, Vec3};
use prob_grid::{IsoMesh, MarchingCubesConfig, marching_cubes};
use rayon::prelude::*;
use sdf_backbone::{Backbone, NoSampleLoss, RayInput, RayOutput};
use std::path::Path;

/// Renders rays in parallel chunks (forward only).
pub fn render(backbone: &Backbone, params: &[f32], rays: &[RayInput<f32>]) -> Vec<RayOutput<f32>> {
    rays.par_chunks(64).flat_map_iter(|c| backbone.loss(params, c, None, &NoSampleLoss).1).collect()
}

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

/// Renders `view` at 1/`downscale` resolution (coarse + up-sampled samples, no jitter).
pub fn render_view(config: &TrainConfig, backbone: &Backbone, params: &[f32], view: &View, downscale: u32) -> ViewRender {
    let k = view.camera.intrinsics.downscaled(downscale, view.camera.pixel_centers);
    let image = view.image.downscaled(downscale);
    let mask = view.mask.as_ref().map(|m| m.downscaled(downscale));
    let (width, height) = (image.width, image.height);
    let camera = camera_geom::PinholeCamera { intrinsics: k, width, height, ..view.camera };
    let mut rays: Vec<RayInput<f32>> = (0..height)
        .flat_map(|r| (0..width).map(move |c| (c, r)))
        .map(|(c, r)| base_ray(&camera, c, r, image.get_f32(c, r), None, config.render.coarse, 0.5))
        .collect();
    backbone.upsample(params, &mut rays, config.render.fine, config.render.upsample_rounds, config.render.upsample_s);
    let outputs = render(backbone, params, &rays);
    let target = rays.iter().map(|r| r.target).collect();
    let mask = mask.map(|m| (0..height).flat_map(|r| (0..width).map(move |c| (c, r))).map(|(c, r)| m.get(c, r)).collect());
    ViewRender { width, height, outputs, target, mask }
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

/// Extracts the zero level set in the normalised frame (block-wise marching cubes over
/// [−1, 1]³), optionally keeping the largest component.
pub fn extract_mesh(config: &TrainConfig, backbone: &Backbone, params: &[f32]) -> Result<IsoMesh> {
    let mc = MarchingCubesConfig { resolution: config.output.mesh_resolution, block: 16, ..Default::default() };
    let (mesh, _) = marching_cubes(&backbone.field(params), &mc)?;
    Ok(if config.output.largest_component { mesh.largest_component() } else { mesh })
}

/// Vertex colours: each vertex rendered by a short ray coming to it along its normal.
pub fn vertex_colors(backbone: &Backbone, params: &[f32], mesh: &IsoMesh) -> Vec<[u8; 3]> {
    let mut normals = vec![Vec3::ZERO; mesh.vertices.len()];
    for t in &mesh.triangles {
        let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
        let n = (b - a).cross(c - a);
        for i in t {
            normals[*i as usize] += n;
        }
    }
    let rays: Vec<RayInput<f32>> = mesh
        .vertices
        .iter()
        .zip(&normals)
        .map(|(p, n)| {
            let n = n.normalize_or(Vec3::Z);
            RayInput {
                origin: (*p + 0.05 * n).to_array(),
                direction: (-n).to_array(),
                depths: (0..=16).map(|i| i as f32 * 0.1 / 16.0).collect(),
                target: [0.0; 3],
                mask: None,
            }
        })
        .collect();
    render(backbone, params, &rays).iter().map(|o| o.color.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)).collect()
}

/// Writes the mesh in the input's world units (`world_from_normalized` applied) in each format.
pub fn write_mesh(out: &Path, mesh: &IsoMesh, world_from_normalized: &DMat4, colors: Option<&[[u8; 3]]>, formats: &[String]) -> Result<Vec<String>> {
    let positions: Vec<Vec3> = mesh.vertices.iter().map(|p| world_from_normalized.transform_point3(p.as_dvec3()).as_vec3()).collect();
    // A reflection in world_from_normalized would turn the triangles inside out.
    let flip = world_from_normalized.determinant() < 0.0;
    let faces: Vec<[u32; 3]> = mesh.triangles.iter().map(|t| if flip { [t[0], t[2], t[1]] } else { *t }).collect();
    let mut written = Vec::new();
    for f in formats {
        let path = out.join(format!("mesh.{f}"));
        match f.as_str() {
            "ply" => PlyData {
                positions: positions.clone(),
                colors: colors.map(<[_]>::to_vec).unwrap_or_default(),
                faces: faces.clone(),
                ..Default::default()
            }
            .write(&path)?,
            "obj" => {
                let mut s = String::from("# psneus mesh\n");
                for (i, p) in positions.iter().enumerate() {
                    match colors {
                        Some(c) => {
                            s += &format!(
                                "v {} {} {} {} {} {}\n",
                                p.x,
                                p.y,
                                p.z,
                                c[i][0] as f32 / 255.0,
                                c[i][1] as f32 / 255.0,
                                c[i][2] as f32 / 255.0
                            )
                        }
                        None => s += &format!("v {} {} {}\n", p.x, p.y, p.z),
                    }
                }
                for t in &faces {
                    s += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
                }
                write_atomic(&path, s.as_bytes())?;
            }
            "glb" => write_atomic(&path, &glb_bytes(&positions, &faces))?,
            other => anyhow::bail!("unknown mesh format {other:?}"),
        }
        written.push(path.display().to_string());
    }
    Ok(written)
}

/// A minimal binary glTF 2.0 (one mesh: positions + indices).
fn glb_bytes(positions: &[Vec3], faces: &[[u32; 3]]) -> Vec<u8> {
    let mut bin: Vec<u8> = positions.iter().flat_map(|p| p.to_array()).flat_map(f32::to_le_bytes).collect();
    let pos_len = bin.len();
    bin.extend(faces.iter().flatten().flat_map(|i| i.to_le_bytes()));
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let (lo, hi) = positions.iter().fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(a, b), p| (a.min(*p), b.max(*p)));
    let json = serde_json::json!({
        "asset": {"version": "2.0", "generator": "psneus"},
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"byteLength": bin.len()}],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos_len, "target": 34962},
            {"buffer": 0, "byteOffset": pos_len, "byteLength": faces.len() * 12, "target": 34963}
        ],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": positions.len(), "type": "VEC3", "min": lo.to_array(), "max": hi.to_array()},
            {"bufferView": 1, "componentType": 5125, "count": faces.len() * 3, "type": "SCALAR"}
        ]
    });
    let mut json = serde_json::to_vec(&json).expect("json");
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    out
}

/// Ground-truth points in the normalised frame, if the data has them: the built-in scene's
/// surface samples, or `gt_points.ply` / `gt_mesh.ply` (input world units) in the data folder.
pub fn ground_truth(data: Option<&Path>, scene: &Scene, builtin: Option<&[glam::DVec3]>, spacing: f64) -> Result<Option<Vec<[f32; 3]>>> {
    if let Some(points) = builtin {
        return Ok(Some(points.iter().map(|p| p.as_vec3().to_array()).collect()));
    }
    let Some(dir) = data else { return Ok(None) };
    let normalized_from_world = scene.world_from_normalized.inverse();
    let to_normalized = |p: &Vec3| normalized_from_world.transform_point3(p.as_dvec3()).as_vec3().to_array();
    let mesh_path = dir.join("gt_mesh.ply");
    if mesh_path.exists() {
        let ply = PlyData::read(&mesh_path).with_context(|| format!("ground-truth mesh {}", mesh_path.display()))?;
        let v: Vec<[f32; 3]> = ply.positions.iter().map(to_normalized).collect();
        return Ok(Some(eval_metrics::sample_mesh(&v, &ply.faces, spacing as f32, 7)));
    }
    let points_path = dir.join("gt_points.ply");
    if points_path.exists() {
        let ply = PlyData::read(&points_path).with_context(|| format!("ground-truth points {}", points_path.display()))?;
        return Ok(Some(ply.positions.iter().map(to_normalized).collect()));
    }
    Ok(None)
}

/// Chamfer and F-score of a mesh (normalised frame) against ground-truth points.
pub fn geometry_metrics(config: &TrainConfig, mesh: &IsoMesh, gt: &[[f32; 3]]) -> Result<eval_metrics::GeometryMetrics> {
    let v: Vec<[f32; 3]> = mesh.vertices.iter().map(|p| p.to_array()).collect();
    let pred = eval_metrics::sample_mesh(&v, &mesh.triangles, config.output.chamfer_spacing as f32, 11);
    Ok(eval_metrics::chamfer(&pred, gt, config.output.chamfer_max_dist, config.output.fscore_tau)?)
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
        let r = datasets::golden::render::render_view(&geometry, cam, false);
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
