//! Atomic file writes, mesh writers (binary PLY, OBJ, binary glTF) and a PLY reader (points and
//! triangles).

use crate::error::{Result, io_err};
use glam::Vec3;
use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed, then
/// renamed over `path`, so a crash never leaves a half-written file in place of a good one.
///
/// Only a regular file (or nothing) is ever replaced: a symbolic link, folder, FIFO or device
/// at `path` is an error. The temporary file has an unpredictable name, is created exclusively
/// (`O_EXCL`: an existing file or link of that name is never followed or reused), and the
/// folder is synced after the rename. [`remove_stale_temporaries`] clears what a killed writer
/// left.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, &mut |w| w.write_all(bytes))
}

/// The infix of [`write_atomic`]'s temporary files: `.NAME.psneus-tmp-RANDOM`.
const TEMPORARY_INFIX: &str = ".psneus-tmp-";

/// [`write_atomic`] with the contents streamed by `fill` (large files need no copy in memory).
/// On any error the temporary file is removed and `path` is left as it was.
pub fn write_atomic_with(path: &Path, fill: &mut dyn FnMut(&mut dyn Write) -> std::io::Result<()>) -> Result<()> {
    use std::hash::{BuildHasher, Hasher};
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    match std::fs::symlink_metadata(path) {
        Ok(meta) if !meta.file_type().is_file() => {
            let what = if meta.file_type().is_symlink() {
                "a symbolic link"
            } else if meta.is_dir() {
                "a folder"
            } else {
                "not a regular file (a device, FIFO or socket)"
            };
            return Err(io_err(path)(std::io::Error::new(std::io::ErrorKind::AlreadyExists, format!("refusing to replace it: it is {what}"))));
        }
        _ => {}
    }
    let (tmp, file) = (|| {
        for _ in 0..16 {
            let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
            hasher.write_u32(std::process::id());
            let tmp = dir.join(format!(".{name}{TEMPORARY_INFIX}{:016x}", hasher.finish()));
            match std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp) {
                Ok(file) => return Ok((tmp, file)),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => continue,
                Err(e) => return Err(e),
            }
        }
        Err(std::io::Error::new(std::io::ErrorKind::AlreadyExists, "no free temporary name"))
    })()
    .map_err(io_err(path))?;
    let result = (|| {
        let mut w = std::io::BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        std::fs::rename(&tmp, path)?;
        // The rename itself is durable once the folder is synced.
        std::fs::File::open(dir)?.sync_all()
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io_err(path))
}

/// Removes the temporary files that a killed [`write_atomic`] left in `dir` (not recursive);
/// returns how many. Only names of the form `.NAME.psneus-tmp-…` (and `.NAME.tmpPID` of
/// earlier versions) that are regular files are removed.
pub fn remove_stale_temporaries(dir: &Path) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let earlier = name.rsplit_once(".tmp").is_some_and(|(_, pid)| !pid.is_empty() && pid.bytes().all(|b| b.is_ascii_digit()));
        let ours = name.starts_with('.') && (name.contains(TEMPORARY_INFIX) || earlier);
        if ours && entry.file_type().is_ok_and(|t| t.is_file()) && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// The mesh formats psneus writes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshFormat {
    /// Binary little-endian PLY (vertex colours as uchar red/green/blue).
    Ply,
    /// Wavefront OBJ (vertex colours as the `v x y z r g b` extension).
    Obj,
    /// Binary glTF 2.0 (positions and indices).
    Glb,
}

impl MeshFormat {
    /// The file extension, without the dot.
    pub fn extension(self) -> &'static str {
        match self {
            MeshFormat::Ply => "ply",
            MeshFormat::Obj => "obj",
            MeshFormat::Glb => "glb",
        }
    }
}

/// A triangle mesh's bytes in `format`: `positions`, counter-clockwise `faces`, optional
/// per-vertex `colors` (PLY and OBJ keep them; glTF drops them).
pub fn mesh_bytes(format: MeshFormat, positions: &[Vec3], faces: &[[u32; 3]], colors: Option<&[[u8; 3]]>) -> Vec<u8> {
    match format {
        MeshFormat::Ply => PlyData {
            positions: positions.to_vec(),
            colors: colors.map(<[_]>::to_vec).unwrap_or_default(),
            faces: faces.to_vec(),
            ..Default::default()
        }
        .to_bytes(),
        MeshFormat::Obj => {
            use std::fmt::Write as _;
            let mut s = String::from("# psneus mesh\n");
            for (i, p) in positions.iter().enumerate() {
                let _ = match colors {
                    Some(c) => {
                        let [r, g, b] = c[i].map(|v| f32::from(v) / 255.0);
                        writeln!(s, "v {} {} {} {r} {g} {b}", p.x, p.y, p.z)
                    }
                    None => writeln!(s, "v {} {} {}", p.x, p.y, p.z),
                };
            }
            for t in faces {
                let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
            }
            s.into_bytes()
        }
        MeshFormat::Glb => glb_bytes(positions, faces),
    }
}

/// A minimal binary glTF 2.0: one mesh of positions and indices.
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
    let mut json = serde_json::to_vec(&json).expect("a JSON value serialises");
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

/// What a PLY file holds: vertices with optional normals and colours, faces, edges.
#[derive(Debug, Default, Clone)]
pub struct PlyData {
    /// Vertex positions.
    pub positions: Vec<Vec3>,
    /// Per-vertex normals (empty or one per vertex).
    pub normals: Vec<Vec3>,
    /// Per-vertex colours (empty or one per vertex).
    pub colors: Vec<[u8; 3]>,
    /// Triangles.
    pub faces: Vec<[u32; 3]>,
    /// Line segments (shown by MeshLab and CloudCompare).
    pub edges: Vec<[u32; 2]>,
}

impl PlyData {
    /// Binary little-endian PLY bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let n = self.positions.len();
        assert!(self.normals.is_empty() || self.normals.len() == n, "one normal per vertex");
        assert!(self.colors.is_empty() || self.colors.len() == n, "one colour per vertex");
        let mut header = format!("ply\nformat binary_little_endian 1.0\ncomment psneus\nelement vertex {n}\n");
        header += "property float x\nproperty float y\nproperty float z\n";
        if !self.normals.is_empty() {
            header += "property float nx\nproperty float ny\nproperty float nz\n";
        }
        if !self.colors.is_empty() {
            header += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
        }
        if !self.faces.is_empty() {
            header += &format!("element face {}\nproperty list uchar int vertex_indices\n", self.faces.len());
        }
        if !self.edges.is_empty() {
            header += &format!("element edge {}\nproperty int vertex1\nproperty int vertex2\n", self.edges.len());
        }
        header += "end_header\n";
        let mut out = header.into_bytes();
        for i in 0..n {
            for v in self.positions[i].to_array() {
                out.extend_from_slice(&v.to_le_bytes());
            }
            if let Some(nrm) = self.normals.get(i) {
                for v in nrm.to_array() {
                    out.extend_from_slice(&v.to_le_bytes());
                }
            }
            if let Some(c) = self.colors.get(i) {
                out.extend_from_slice(c);
            }
        }
        for f in &self.faces {
            out.push(3);
            for i in f {
                out.extend_from_slice(&(*i as i32).to_le_bytes());
            }
        }
        for e in &self.edges {
            for i in e {
                out.extend_from_slice(&(*i as i32).to_le_bytes());
            }
        }
        out
    }

    /// Writes the PLY atomically.
    pub fn write(&self, path: &Path) -> Result<()> {
        write_atomic(path, &self.to_bytes())
    }

    /// Reads vertex positions (x, y, z) and triangles (polygons are fanned) from an ASCII or
    /// binary little-endian PLY; other properties and elements are skipped.
    pub fn read(path: &Path) -> Result<PlyData> {
        let bytes = std::fs::read(path).map_err(io_err(path))?;
        PlyData::parse(&bytes, path)
    }

    /// Parses the bytes of a PLY file (`path` names it in errors).
    pub fn parse(bytes: &[u8], path: &Path) -> Result<PlyData> {
        parse_ply(bytes).map_err(|message| crate::error::DatasetError::Corrupt { path: path.to_path_buf(), kind: "PLY file", message })
    }
}

fn type_size(t: &str) -> std::result::Result<usize, String> {
    Ok(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        other => return Err(format!("unknown property type {other:?}")),
    })
}

fn read_scalar(t: &str, b: &[u8]) -> f64 {
    match t {
        "char" | "int8" => b[0] as i8 as f64,
        "uchar" | "uint8" => b[0] as f64,
        "short" | "int16" => i16::from_le_bytes([b[0], b[1]]) as f64,
        "ushort" | "uint16" => u16::from_le_bytes([b[0], b[1]]) as f64,
        "int" | "int32" => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "uint" | "uint32" => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        "float" | "float32" => f32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f64,
        _ => f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]),
    }
}

/// (name, scalar type, list count type).
type Property = (String, String, Option<String>);

/// The body of a PLY file: ASCII tokens (reversed, popped from the end) or binary bytes.
struct Body<'a> {
    ascii: bool,
    tokens: Vec<&'a str>,
    bytes: &'a [u8],
    pos: usize,
}

impl Body<'_> {
    /// The next scalar of type `t`.
    fn next(&mut self, t: &str) -> std::result::Result<f64, String> {
        if self.ascii {
            self.tokens.pop().ok_or("file ends early")?.parse::<f64>().map_err(|e| e.to_string())
        } else {
            let n = type_size(t)?;
            let b = self.bytes.get(self.pos..self.pos + n).ok_or("file ends early")?;
            self.pos += n;
            Ok(read_scalar(t, b))
        }
    }

    /// Tokens or bytes left.
    fn left(&self) -> usize {
        if self.ascii { self.tokens.len() } else { self.bytes.len() - self.pos }
    }
}

/// A list length or vertex index: a non-negative integer below 2^32.
fn index(v: f64, what: &str) -> std::result::Result<u32, String> {
    if (0.0..4294967296.0).contains(&v) && v.fract() == 0.0 { Ok(v as u32) } else { Err(format!("{what} {v} is not an index")) }
}

fn parse_ply(bytes: &[u8]) -> std::result::Result<PlyData, String> {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").ok_or("no end_header line")? + 11;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| "header is not text")?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err("not a PLY file (first line is not 'ply')".into());
    }
    let mut format = "";
    let mut elements: Vec<(String, usize, Vec<Property>)> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.as_slice() {
            ["format", f, ..] => format = f,
            ["element", name, count] => {
                elements.push((name.to_string(), count.parse().map_err(|_| format!("bad element count {count:?}"))?, Vec::new()))
            }
            ["property", "list", c, t, name] => {
                elements.last_mut().ok_or("property before element")?.2.push((name.to_string(), t.to_string(), Some(c.to_string())))
            }
            ["property", t, name] => elements.last_mut().ok_or("property before element")?.2.push((name.to_string(), t.to_string(), None)),
            _ => {}
        }
    }
    let ascii = match format {
        "ascii" => true,
        "binary_little_endian" => false,
        other => return Err(format!("unsupported PLY format {other:?} (ascii or binary_little_endian)")),
    };
    let mut out = PlyData::default();
    let body = &bytes[end..];
    let mut tokens =
        if ascii { std::str::from_utf8(body).map_err(|_| "ASCII body is not text")?.split_whitespace().collect::<Vec<_>>() } else { Vec::new() };
    tokens.reverse();
    let mut body = Body { ascii, tokens, bytes: body, pos: 0 };
    for (name, count, props) in &elements {
        // Every record takes at least one byte (binary) or one token (ASCII): a count beyond
        // what is left is corrupt, and must not drive a loop or an allocation.
        let left = body.left();
        if *count > left {
            return Err(format!("element {name:?} declares {count} records, the file has room for at most {left}"));
        }
        if props.is_empty() && *count > 0 {
            return Err(format!("element {name:?} declares {count} records without properties"));
        }
        for record in 0..*count {
            let mut xyz = [0.0f32; 3];
            for (pname, t, list) in props {
                if let Some(ct) = list {
                    let k = index(body.next(ct)?, "list length")? as usize;
                    let idx: Vec<u32> = (0..k).map(|_| body.next(t).and_then(|v| index(v, "list entry"))).collect::<std::result::Result<_, _>>()?;
                    if name == "face" && pname.starts_with("vertex_ind") {
                        for j in 1..k.saturating_sub(1) {
                            out.faces.push([idx[0], idx[j], idx[j + 1]]);
                        }
                    }
                } else {
                    let v = body.next(t)?;
                    if name == "vertex" {
                        match pname.as_str() {
                            "x" => xyz[0] = v as f32,
                            "y" => xyz[1] = v as f32,
                            "z" => xyz[2] = v as f32,
                            _ => {}
                        }
                    }
                }
            }
            if name == "vertex" {
                if !xyz.iter().all(|v| v.is_finite()) {
                    return Err(format!("vertex {record} has a non-finite coordinate {xyz:?}"));
                }
                out.positions.push(Vec3::from_array(xyz));
            }
        }
    }
    if let Some(bad) = out.faces.iter().flatten().find(|&&i| i as usize >= out.positions.len()) {
        return Err(format!("face index {bad} ≥ vertex count {}", out.positions.len()));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn write_atomic_replaces_only_regular_files() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.txt");
        write_atomic(&file, b"one").unwrap();
        write_atomic(&file, b"two").unwrap();
        assert_eq!(std::fs::read(&file).unwrap(), b"two");
        // A link is not followed nor replaced; its target is untouched.
        let target = dir.path().join("target.txt");
        std::fs::write(&target, b"precious").unwrap();
        let link = dir.path().join("link.txt");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let err = write_atomic(&link, b"x").unwrap_err().to_string();
        assert!(err.contains("symbolic link") && err.contains("link.txt"), "{err}");
        assert_eq!(std::fs::read(&target).unwrap(), b"precious");
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        // Nor a folder, nor a device.
        assert!(write_atomic(dir.path(), b"x").unwrap_err().to_string().contains("folder"));
        let err = write_atomic(Path::new("/dev/null"), b"x").unwrap_err().to_string();
        assert!(err.contains("not a regular file"), "{err}");
        // No temporary is left behind.
        let names: Vec<String> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        assert!(names.iter().all(|n| !n.contains("tmp")), "{names:?}");
    }

    #[test]
    fn stale_temporaries_of_a_killed_writer_are_removed() {
        let dir = tempfile::tempdir().unwrap();
        for name in [".checkpoint.safetensors.psneus-tmp-0123456789abcdef", ".mesh.ply.tmp4242", "keep.tmp", ".hidden"] {
            std::fs::write(dir.path().join(name), b"x").unwrap();
        }
        assert_eq!(remove_stale_temporaries(dir.path()), 2);
        let mut names: Vec<String> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        names.sort();
        assert_eq!(names, [".hidden", "keep.tmp"]);
    }

    #[test]
    fn ply_header_and_size_match_contents() {
        let ply = PlyData {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y],
            colors: vec![[1, 2, 3]; 3],
            faces: vec![[0, 1, 2]],
            edges: vec![[0, 1]],
            ..Default::default()
        };
        let bytes = ply.to_bytes();
        let text = String::from_utf8_lossy(&bytes);
        let header_end = text.find("end_header\n").unwrap() + "end_header\n".len();
        assert!(text.contains("element vertex 3") && text.contains("element face 1") && text.contains("element edge 1"));
        assert_eq!(bytes.len() - header_end, 3 * (12 + 3) + (1 + 12) + 8);
    }

    #[test]
    fn ply_reads_back_what_it_writes_and_reads_ascii() {
        let ply = PlyData {
            positions: vec![Vec3::ZERO, Vec3::X, Vec3::new(0.5, 2.0, -1.0)],
            colors: vec![[1, 2, 3]; 3],
            faces: vec![[0, 1, 2]],
            ..Default::default()
        };
        let back = parse_ply(&ply.to_bytes()).unwrap();
        assert_eq!((back.positions, back.faces), (ply.positions.clone(), ply.faces.clone()));
        let ascii = b"ply\nformat ascii 1.0\nelement vertex 4\nproperty double x\nproperty double y\nproperty double z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
        let q = parse_ply(ascii).unwrap();
        assert_eq!(q.positions.len(), 4);
        assert_eq!(q.faces, vec![[0, 1, 2], [0, 2, 3]]);
        assert!(parse_ply(b"ply\nformat binary_big_endian 1.0\nend_header\n").unwrap_err().contains("big"));
        assert!(parse_ply(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend_header\n1\n").unwrap_err().contains("room"));
        assert!(
            parse_ply(b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nend_header\n1 2 3\n")
                .unwrap_err()
                .contains("early")
        );
    }

    #[test]
    fn atomic_write_replaces_and_leaves_no_temporary() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.txt");
        write_atomic(&p, b"one").unwrap();
        write_atomic(&p, b"two").unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"two");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
        let err = write_atomic(&dir.path().join("missing/a.txt"), b"x").unwrap_err();
        assert!(err.to_string().contains("missing/a.txt"), "{err}");
    }
}
