//! Atomic file writes and a binary PLY writer.

use crate::error::{Result, io_err};
use glam::Vec3;
use std::io::Write;
use std::path::Path;

/// Writes `bytes` to `path` atomically: a temporary file in the same folder, flushed, then
/// renamed over `path`, so a crash never leaves a half-written file in place of a good one.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.map_err(io_err(path))
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
}

#[cfg(test)]
mod tests {
    use super::*;

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
