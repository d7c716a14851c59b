//! Reading meshes for golden scenes: OBJ (tobj, with a diffuse texture from the MTL) and
//! glTF / GLB (gltf; geometry only).

use crate::error::{DatasetError, Result};
use crate::images::RgbImage;
use glam::{Vec2, Vec3};
use prob_grid::TriangleMesh;
use std::path::Path;

/// A triangle mesh with optional per-vertex texture coordinates and one texture per triangle group.
#[derive(Debug, Clone)]
pub struct TexturedMesh {
    /// Geometry (with its BVH).
    pub mesh: TriangleMesh,
    /// Per-vertex texture coordinates (OBJ convention: v = 0 at the bottom), if the file has them.
    pub uvs: Option<Vec<Vec2>>,
    /// Per-triangle index into `textures` (`u32::MAX`: no texture).
    pub triangle_texture: Vec<u32>,
    /// Diffuse textures.
    pub textures: Vec<RgbImage>,
}

fn corrupt(path: &Path, kind: &'static str, message: impl ToString) -> DatasetError {
    DatasetError::Corrupt { path: path.to_path_buf(), kind, message: message.to_string() }
}

/// Loads an OBJ, glTF or GLB file by extension.
pub fn load_mesh(path: &Path) -> Result<TexturedMesh> {
    match path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase).as_deref() {
        Some("obj") => load_obj(path),
        Some("gltf" | "glb") => load_gltf(path),
        _ => Err(DatasetError::Unsupported { path: path.to_path_buf(), message: "mesh format (use .obj, .gltf or .glb)".into() }),
    }
}

fn check_mesh(path: &Path, kind: &'static str, positions: &[Vec3], triangles: &[[u32; 3]]) -> Result<()> {
    if triangles.is_empty() {
        return Err(corrupt(path, kind, "no triangles"));
    }
    if !positions.iter().all(|p| p.is_finite()) {
        return Err(corrupt(path, kind, "non-finite vertex position"));
    }
    let n = positions.len() as u32;
    if triangles.iter().flatten().any(|&i| i >= n) {
        return Err(corrupt(path, kind, "vertex index out of range"));
    }
    Ok(())
}

fn load_obj(path: &Path) -> Result<TexturedMesh> {
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let (models, materials) = tobj::load_obj(path, &options).map_err(|e| corrupt(path, "OBJ mesh", e))?;
    // A missing or broken MTL only costs the texture: geometry is what golden scenes need.
    let materials = materials.unwrap_or_default();
    let dir = path.parent().unwrap_or(Path::new("."));
    let mut textures = Vec::new();
    let mut material_texture = vec![u32::MAX; materials.len()];
    for (m, material) in materials.iter().enumerate() {
        if let Some(name) = &material.diffuse_texture {
            let tex_path = dir.join(name);
            let img = image::open(&tex_path).map_err(|e| corrupt(&tex_path, "texture image", e))?.into_rgb8();
            material_texture[m] = textures.len() as u32;
            textures.push(RgbImage { width: img.width(), height: img.height(), data: img.into_raw() });
        }
    }
    let mut positions = Vec::new();
    let mut uvs = Vec::new();
    let mut triangles = Vec::new();
    let mut triangle_texture = Vec::new();
    let all_have_uvs = models.iter().all(|m| !m.mesh.texcoords.is_empty());
    for model in &models {
        let m = &model.mesh;
        let base = positions.len() as u32;
        positions.extend(m.positions.chunks_exact(3).map(|p| Vec3::new(p[0], p[1], p[2])));
        if all_have_uvs {
            uvs.extend(m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], t[1])));
        }
        let tex = m.material_id.and_then(|id| material_texture.get(id).copied()).unwrap_or(u32::MAX);
        for t in m.indices.chunks_exact(3) {
            triangles.push([base + t[0], base + t[1], base + t[2]]);
            triangle_texture.push(tex);
        }
    }
    check_mesh(path, "OBJ mesh", &positions, &triangles)?;
    let uvs = (all_have_uvs && uvs.len() == positions.len()).then_some(uvs);
    Ok(TexturedMesh { mesh: TriangleMesh::new(positions, triangles), uvs, triangle_texture, textures })
}

fn load_gltf(path: &Path) -> Result<TexturedMesh> {
    let (document, buffers, _images) = gltf::import(path).map_err(|e| corrupt(path, "glTF file", e))?;
    let mut positions = Vec::new();
    let mut triangles = Vec::new();
    // Walk the default scene's nodes so that node transforms are applied.
    let scene = document.default_scene().or_else(|| document.scenes().next()).ok_or_else(|| corrupt(path, "glTF file", "no scene"))?;
    let mut stack: Vec<(gltf::Node, glam::Mat4)> = scene.nodes().map(|n| (n, glam::Mat4::IDENTITY)).collect();
    // glTF's nodes form a forest: a node reached twice (a cycle, or a node with two parents)
    // is an error, not an endless or exponential walk.
    let mut visited = vec![false; document.nodes().len()];
    while let Some((node, parent)) = stack.pop() {
        if std::mem::replace(&mut visited[node.index()], true) {
            return Err(corrupt(path, "glTF file", format!("node {} is reached twice (the node graph must be a tree)", node.index())));
        }
        let world = parent * glam::Mat4::from_cols_array_2d(&node.transform().matrix());
        if let Some(mesh) = node.mesh() {
            for primitive in mesh.primitives() {
                if primitive.mode() != gltf::mesh::Mode::Triangles {
                    continue;
                }
                let reader = primitive.reader(|b| buffers.get(b.index()).map(|d| &d.0[..]));
                let Some(pos) = reader.read_positions() else { continue };
                let base = positions.len() as u32;
                positions.extend(pos.map(|p| world.transform_point3(Vec3::from_array(p))));
                let Ok(end) = u32::try_from(positions.len()) else {
                    return Err(corrupt(path, "glTF file", "more than 2³² vertices"));
                };
                let count = end - base;
                match reader.read_indices() {
                    Some(idx) => {
                        let idx: Vec<u32> = idx.into_u32().collect();
                        // An index beyond the primitive's vertices is caught by check_mesh (u32::MAX here).
                        let at = |i: u32| if i < count { base + i } else { u32::MAX };
                        triangles.extend(idx.chunks_exact(3).map(|t| [at(t[0]), at(t[1]), at(t[2])]));
                    }
                    None => triangles.extend((0..count / 3).map(|t| [base + 3 * t, base + 3 * t + 1, base + 3 * t + 2])),
                }
            }
        }
        stack.extend(node.children().map(|c| (c, world)));
    }
    check_mesh(path, "glTF file", &positions, &triangles)?;
    let n = triangles.len();
    Ok(TexturedMesh { mesh: TriangleMesh::new(positions, triangles), uvs: None, triangle_texture: vec![u32::MAX; n], textures: Vec::new() })
}
