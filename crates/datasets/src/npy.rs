//! NPY arrays and NPZ archives (the `.npy` format, version 1–3, little-endian, C order).
//!
//! Small and dependency-free apart from `zip`: we read `cameras_sphere.npz` and write it for
//! golden scenes, and write depth/normal maps as `.npy`.

use crate::error::{DatasetError, Result, io_err};
use std::io::{Read, Seek, Write};
use std::path::Path;

/// An n-dimensional array read from an `.npy`, values widened to f64.
#[derive(Debug, Clone, PartialEq)]
pub struct NpyArray {
    /// Shape, C order.
    pub shape: Vec<usize>,
    /// Values in C order.
    pub data: Vec<f64>,
}

fn corrupt(path: &Path, message: impl Into<String>) -> DatasetError {
    DatasetError::Corrupt { path: path.to_path_buf(), kind: "npy array", message: message.into() }
}

/// What an NPY header says: the element reader, the shape, the element count and the byte
/// where the data start.
struct NpyHeader {
    size: usize,
    read: fn(&[u8]) -> f64,
    shape: Vec<usize>,
    count: usize,
    data_start: usize,
}

/// The largest NPY header we read (NumPy's are ~128 bytes; version 1 allows 65 535).
const MAX_NPY_HEADER: usize = 1 << 16;

/// Parses the header of an `.npy` from its first bytes (the data need not be there).
fn parse_npy_header(bytes: &[u8], path: &Path) -> Result<NpyHeader> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(corrupt(path, "not an NPY array (bad magic)"));
    }
    let (header_len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        v => return Err(corrupt(path, format!("unsupported NPY version {v}"))),
    };
    if header_len > MAX_NPY_HEADER {
        return Err(corrupt(path, format!("header of {header_len} bytes (at most {MAX_NPY_HEADER})")));
    }
    let header = bytes.get(start..start + header_len).ok_or_else(|| corrupt(path, "truncated header"))?;
    let header = std::str::from_utf8(header).map_err(|_| corrupt(path, "header is not text"))?;
    let field = |key: &str| -> Result<&str> {
        let at = header.find(&format!("'{key}'")).ok_or_else(|| corrupt(path, format!("header lacks '{key}'")))?;
        let rest = &header[at + key.len() + 2..];
        let colon = rest.find(':').ok_or_else(|| corrupt(path, "malformed header"))?;
        Ok(rest[colon + 1..].trim_start())
    };
    let descr = field("descr")?;
    let descr = descr.trim_start_matches(['\'', '"']);
    let descr = &descr[..descr.find(['\'', '"']).ok_or_else(|| corrupt(path, "malformed descr"))?];
    if field("fortran_order")?.starts_with("True") {
        return Err(corrupt(path, "Fortran-ordered arrays are not supported"));
    }
    let shape_text = field("shape")?;
    let shape_text = shape_text.strip_prefix('(').and_then(|t| t.split_once(')')).ok_or_else(|| corrupt(path, "malformed shape"))?.0;
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse().map_err(|_| corrupt(path, format!("bad shape entry {s:?}"))))
        .collect::<Result<_>>()?;
    let count = shape.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d)).ok_or_else(|| corrupt(path, format!("shape {shape:?} overflows")))?;
    let (size, read): (usize, fn(&[u8]) -> f64) = match descr {
        "<f8" => (8, |b| f64::from_le_bytes(b.try_into().unwrap())),
        "<f4" => (4, |b| f32::from_le_bytes(b.try_into().unwrap()) as f64),
        "<i8" => (8, |b| i64::from_le_bytes(b.try_into().unwrap()) as f64),
        "<i4" => (4, |b| i32::from_le_bytes(b.try_into().unwrap()) as f64),
        "|u1" => (1, |b| b[0] as f64),
        other => return Err(corrupt(path, format!("unsupported dtype {other}"))),
    };
    Ok(NpyHeader { size, read, shape, count, data_start: start + header_len })
}

/// Parses an `.npy` byte buffer. `path` is only used in error messages (e.g. `file.npz/key.npy`).
pub fn parse_npy(bytes: &[u8], path: &Path) -> Result<NpyArray> {
    let h = parse_npy_header(bytes, path)?;
    let body = &bytes[h.data_start..];
    let need = h.count.checked_mul(h.size).filter(|&n| n <= body.len()).ok_or_else(|| {
        corrupt(path, format!("shape {:?} of {}-byte values needs more than the {} data bytes present", h.shape, h.size, body.len()))
    })?;
    let data = body[..need].chunks_exact(h.size).map(h.read).collect();
    Ok(NpyArray { shape: h.shape, data })
}

/// Element types the writer supports.
pub trait NpyElement: Copy {
    /// NumPy `descr`.
    const DESCR: &'static str;
    /// Little-endian bytes.
    fn write_le(self, out: &mut Vec<u8>);
}
impl NpyElement for f64 {
    const DESCR: &'static str = "<f8";
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}
impl NpyElement for f32 {
    const DESCR: &'static str = "<f4";
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

/// Serialises an array (C order) as NPY version 1.0.
pub fn npy_bytes<T: NpyElement>(shape: &[usize], data: &[T]) -> Vec<u8> {
    assert_eq!(shape.iter().product::<usize>(), data.len(), "npy_bytes: shape does not match data");
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 { format!("({},)", dims[0]) } else { format!("({})", dims.join(", ")) };
    let mut header = format!("{{'descr': '{}', 'fortran_order': False, 'shape': {shape_text}, }}", T::DESCR);
    // Magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 8);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        v.write_le(&mut out);
    }
    out
}

/// The largest array an `.npz` entry may hold (camera files hold a few kilobytes; widened to
/// f64 it takes at most 8× this): a larger declared size is an error, not an allocation.
pub const MAX_NPZ_ENTRY_BYTES: u64 = 16 << 20;

/// An opened `.npz` archive (a file, or any seekable reader such as bytes in memory).
pub struct Npz<R = std::io::BufReader<std::fs::File>> {
    path: std::path::PathBuf,
    archive: zip::ZipArchive<R>,
}

impl Npz {
    /// Opens an archive.
    pub fn open(path: &Path) -> Result<Npz> {
        let file = std::fs::File::open(path).map_err(io_err(path))?;
        Npz::from_reader(std::io::BufReader::new(file), path)
    }
}

impl<R: Read + Seek> Npz<R> {
    /// Reads the directory of an archive from `reader` (`path` names it in errors).
    pub fn from_reader(reader: R, path: &Path) -> Result<Npz<R>> {
        let archive = zip::ZipArchive::new(reader).map_err(|e| DatasetError::Corrupt {
            path: path.to_path_buf(),
            kind: "npz archive",
            message: e.to_string(),
        })?;
        Ok(Npz { path: path.to_path_buf(), archive })
    }

    /// Names of the arrays (without `.npy`).
    pub fn keys(&self) -> Vec<String> {
        self.archive.file_names().filter_map(|n| n.ok()).map(|n| n.trim_end_matches(".npy").to_string()).collect()
    }

    /// Reads one array, `None` if the key is absent. Entries declaring more than
    /// [`MAX_NPZ_ENTRY_BYTES`] are errors; an entry is never read past its declared size.
    pub fn get(&mut self, key: &str) -> Result<Option<NpyArray>> {
        self.get_shaped(key, &|_| true, "any shape")
    }

    /// Reads one array whose shape `accept`s (else an error quoting `expected`), `None` if the
    /// key is absent. The shape is read from the header before the data, so a huge array of
    /// the wrong shape is refused without being read.
    pub fn get_shaped(&mut self, key: &str, accept: &dyn Fn(&[usize]) -> bool, expected: &str) -> Result<Option<NpyArray>> {
        let name = format!("{key}.npy");
        let entry_path = self.path.join(&name);
        let corrupt = |path: &Path, message: String| DatasetError::Corrupt { path: path.to_path_buf(), kind: "npz archive", message };
        let mut entry = match self.archive.by_name(&name) {
            Ok(e) => e,
            Err(zip::result::ZipError::FileNotFound) => return Ok(None),
            Err(e) => return Err(corrupt(&self.path, format!("{name}: {e}"))),
        };
        let size = entry.size();
        if size > MAX_NPZ_ENTRY_BYTES {
            return Err(corrupt(&self.path, format!("{name}: declares {size} bytes, more than the {MAX_NPZ_ENTRY_BYTES} a camera array may hold")));
        }
        // The header first (grown as bytes arrive: a size declared but not held allocates nothing).
        let mut bytes = Vec::new();
        let head = size.min(12 + MAX_NPY_HEADER as u64);
        (&mut entry).take(head).read_to_end(&mut bytes).map_err(|e| corrupt(&self.path, format!("{name}: {e}")))?;
        let header = parse_npy_header(&bytes, &entry_path)?;
        if !accept(&header.shape) {
            return Err(DatasetError::InvalidValue {
                path: self.path.clone(),
                entry: key.into(),
                message: format!("shape {:?}, expected {expected}", header.shape),
            });
        }
        entry.take(size - head).read_to_end(&mut bytes).map_err(|e| corrupt(&self.path, format!("{name}: {e}")))?;
        parse_npy(&bytes, &entry_path).map(Some)
    }
}

/// Writes `(key, npy bytes)` entries into a new `.npz` (stored, uncompressed) in `writer`.
pub fn write_npz<W: Write + Seek>(writer: W, entries: &[(String, Vec<u8>)]) -> zip::result::ZipResult<W> {
    let mut zip = zip::ZipWriter::new(writer);
    let options = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    for (key, bytes) in entries {
        zip.start_file(format!("{key}.npy"), options)?;
        zip.write_all(bytes)?;
    }
    zip.finish()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_f64_and_f32() {
        let data: Vec<f64> = (0..12).map(|i| i as f64 * 0.5 - 1.0).collect();
        let bytes = npy_bytes(&[3, 4], &data);
        assert_eq!(bytes.len() % 64, (12 * 8) % 64);
        let a = parse_npy(&bytes, Path::new("x.npy")).unwrap();
        assert_eq!(a.shape, vec![3, 4]);
        assert_eq!(a.data, data);
        let f: Vec<f32> = vec![1.5, -2.0, 3.25];
        let a = parse_npy(&npy_bytes(&[3], &f), Path::new("x.npy")).unwrap();
        assert_eq!(a.shape, vec![3]);
        assert_eq!(a.data, vec![1.5, -2.0, 3.25]);
    }

    #[test]
    fn npz_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.npz");
        let entries = vec![("m".to_string(), npy_bytes(&[2, 2], &[1.0f64, 2.0, 3.0, 4.0]))];
        write_npz(std::fs::File::create(&path).unwrap(), &entries).unwrap();
        let mut npz = Npz::open(&path).unwrap();
        assert_eq!(npz.keys(), vec!["m".to_string()]);
        assert_eq!(npz.get("m").unwrap().unwrap().data, vec![1.0, 2.0, 3.0, 4.0]);
        assert!(npz.get("absent").unwrap().is_none());
    }

    #[test]
    fn truncated_npy_is_an_error_naming_the_file() {
        let bytes = npy_bytes(&[4, 4], &[0.0f64; 16]);
        let err = parse_npy(&bytes[..bytes.len() - 8], Path::new("cams.npz/world_mat_0.npy")).unwrap_err();
        assert!(err.to_string().contains("cams.npz/world_mat_0.npy"), "{err}");
    }
}
