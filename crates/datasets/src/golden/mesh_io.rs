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
    let bytes = std::fs::read(path).map_err(crate::error::io_err(path))?;
    let dir = path.parent().unwrap_or(Path::new("."));
    // The MTL and its textures are named inside the OBJ: they must lie in its folder.
    let mtl = |name: &Path| -> tobj::MTLLoadResult {
        let name = name.to_string_lossy();
        let file = crate::contain::join_inside(dir, &name, path, "mtllib").map_err(|_| tobj::LoadError::OpenFileFailed)?;
        let file = crate::contain::inside(dir, file, path, "mtllib").map_err(|_| tobj::LoadError::OpenFileFailed)?;
        tobj::load_mtl(file)
    };
    let texture = |name: &str| -> Result<RgbImage> {
        let file = crate::contain::join_inside(dir, name, path, "map_Kd of the MTL")?;
        let file = crate::contain::inside(dir, file, path, "map_Kd of the MTL")?;
        let img = image::open(&file).map_err(|e| corrupt(&file, "texture image", e))?.into_rgb8();
        Ok(RgbImage { width: img.width(), height: img.height(), data: img.into_raw() })
    };
    parse_obj(&bytes, path, &mtl, &texture)
}

/// An OBJ from its bytes; `mtl` reads a material library, `texture` a diffuse texture, both
/// by the name the file gives (the fuzzer gives neither: the geometry is what it tests).
pub(crate) fn parse_obj(
    bytes: &[u8],
    path: &Path,
    mtl: &dyn Fn(&Path) -> tobj::MTLLoadResult,
    texture: &dyn Fn(&str) -> Result<RgbImage>,
) -> Result<TexturedMesh> {
    let options = tobj::LoadOptions { single_index: true, triangulate: true, ignore_points: true, ignore_lines: true };
    let (models, materials) = tobj::load_obj_buf(&mut std::io::Cursor::new(bytes), &options, mtl).map_err(|e| corrupt(path, "OBJ mesh", e))?;
    // A missing or broken MTL only costs the texture: geometry is what golden scenes need.
    let materials = materials.unwrap_or_default();
    let mut textures = Vec::new();
    let mut material_texture = vec![u32::MAX; materials.len()];
    for (m, material) in materials.iter().enumerate() {
        if let Some(name) = &material.diffuse_texture {
            material_texture[m] = textures.len() as u32;
            textures.push(texture(name)?);
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
        let Ok(count) = u32::try_from(positions.len()).map(|end| end - base) else {
            return Err(corrupt(path, "OBJ mesh", "more than 2³² vertices"));
        };
        if all_have_uvs {
            uvs.extend(m.texcoords.chunks_exact(2).map(|t| Vec2::new(t[0], t[1])));
        }
        let tex = m.material_id.and_then(|id| material_texture.get(id).copied()).unwrap_or(u32::MAX);
        // An index beyond the model's vertices is caught by check_mesh (u32::MAX here).
        let at = |i: u32| if i < count { base + i } else { u32::MAX };
        for t in m.indices.chunks_exact(3) {
            triangles.push([at(t[0]), at(t[1]), at(t[2])]);
            triangle_texture.push(tex);
        }
    }
    check_mesh(path, "OBJ mesh", &positions, &triangles)?;
    let uvs = (all_have_uvs && uvs.len() == positions.len()).then_some(uvs);
    Ok(TexturedMesh { mesh: TriangleMesh::new(positions, triangles), uvs, triangle_texture, textures })
}

/// `uri` percent-decoded, when that gives UTF-8 (gltf 1.4 panics on one that does not).
fn percent_decoded(uri: &str) -> Option<String> {
    let bytes = uri.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let hex = |b: u8| (b as char).to_digit(16);
        match (bytes[i], bytes.get(i + 1).copied().and_then(hex), bytes.get(i + 2).copied().and_then(hex)) {
            (b'%', Some(hi), Some(lo)) => {
                out.push((hi * 16 + lo) as u8);
                i += 3;
            }
            (b, _, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8(out).ok()
}

fn load_gltf(path: &Path) -> Result<TexturedMesh> {
    let bytes = std::fs::read(path).map_err(crate::error::io_err(path))?;
    parse_gltf(&bytes, path, path.parent().or(Some(Path::new("."))))
}

/// A glTF or GLB from its bytes. Buffers are embedded (GLB's, `data:` URIs) or, with `dir`,
/// files named relative to it that lie inside it; images are not read (geometry only).
///
/// gltf 1.4.1 panics on some malformed files (found by `cargo xtask fuzz`: a POSITION accessor
/// index out of range in its validation, a GLB length below its header's, an accessor of count
/// 0); such a panic is caught here and returned as the file's error, so that a bad file is never
/// a crash of the program.
pub(crate) fn parse_gltf(bytes: &[u8], path: &Path, dir: Option<&Path>) -> Result<TexturedMesh> {
    std::panic::catch_unwind(|| parse_gltf_unguarded(bytes, path, dir)).unwrap_or_else(|panic| {
        let message = panic.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| panic.downcast_ref::<String>().cloned()).unwrap_or_default();
        Err(corrupt(path, "glTF file", format!("the glTF reader failed on it ({message})")))
    })
}

fn parse_gltf_unguarded(bytes: &[u8], path: &Path, dir: Option<&Path>) -> Result<TexturedMesh> {
    let gltf::Gltf { document, blob } = gltf::Gltf::from_slice(bytes).map_err(|e| corrupt(path, "glTF file", e))?;
    for buffer in document.buffers() {
        if let gltf::buffer::Source::Uri(uri) = buffer.source() {
            if uri.starts_with("data:") {
                continue;
            }
            let entry = format!("buffers[{}].uri", buffer.index());
            let Some(name) = percent_decoded(uri).filter(|n| !n.contains(':')) else {
                return Err(corrupt(path, "glTF file", format!("{entry} {uri:?}: only data: URIs and relative paths are read")));
            };
            let Some(dir) = dir else {
                return Err(corrupt(path, "glTF file", format!("{entry} {uri:?}: an external buffer (no folder to read it from)")));
            };
            let file = crate::contain::join_inside(dir, &name, path, &entry)?;
            crate::contain::inside(dir, file, path, &entry)?;
        }
    }
    let buffers = gltf::import_buffers(&document, dir, blob).map_err(|e| corrupt(path, "glTF file", e))?;
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
