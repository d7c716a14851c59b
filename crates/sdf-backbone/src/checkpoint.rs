//! Checkpoints as safetensors files (readable from Python with `safetensors.numpy.load_file`):
//! named 1-D f32 tensors (and BF16 ones: Adam's compact moments) and string metadata.
//!
//! Both directions stream: [`CheckpointWriter`] writes tensors from borrowed slices and
//! [`CheckpointReader`] reads each tensor straight into the caller's slice, so a checkpoint of
//! paper-scale Neuralangelo (parameters and Adam's moments, 6.4 GB) costs no copy of them in
//! memory. The reader checks every length and offset against the file before it allocates or
//! reads anything: a truncated or corrupt file is an error, never a panic or a huge allocation.
//!
//! Format: an 8-byte little-endian header length N, N bytes of JSON (`{"__metadata__": {…},
//! "name": {"dtype": "F32", "shape": [len], "data_offsets": [begin, end]}, …}`, padded with spaces
//! to a multiple of 8), then the tensors' little-endian bytes.

use crate::backbone::BackboneError;
use crate::optim::Adam;
use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Seek, SeekFrom, Write};

/// The largest header accepted (the JSON of a few tensors and the configuration is far below).
const MAX_HEADER: u64 = 100 << 20;

fn err(message: impl Into<String>) -> BackboneError {
    BackboneError::Checkpoint(message.into())
}

/// A tensor to write, borrowed.
#[derive(Debug, Clone, Copy)]
enum Tensor<'a> {
    F32(&'a [f32]),
    /// bf16 bit patterns.
    Bf16(&'a [u16]),
}

impl Tensor<'_> {
    /// The safetensors dtype, the bytes per element and the element count.
    fn shape(&self) -> (&'static str, usize, usize) {
        match self {
            Tensor::F32(v) => ("F32", 4, v.len()),
            Tensor::Bf16(v) => ("BF16", 2, v.len()),
        }
    }
}

/// A checkpoint to write: tensors borrowed from the caller, in name order.
#[derive(Debug, Default)]
pub struct CheckpointWriter<'a> {
    tensors: BTreeMap<String, Tensor<'a>>,
    metadata: BTreeMap<String, String>,
}

impl<'a> CheckpointWriter<'a> {
    /// An empty checkpoint.
    pub fn new() -> Self {
        CheckpointWriter::default()
    }

    /// The model and optimiser state: `params`, `adam.m`, `adam.v` (and, with compact moments,
    /// `adam.m_bf16`, `adam.v_bf16` for the leading parameters), metadata `adam_step`.
    pub fn with_state(params: &'a [f32], adam: &'a Adam) -> Self {
        let mut w = CheckpointWriter::new();
        w.tensor("params", params);
        w.tensor("adam.m", &adam.m);
        w.tensor("adam.v", &adam.v);
        if let Some(c) = &adam.compact {
            w.tensors.insert("adam.m_bf16".into(), Tensor::Bf16(&c.m));
            w.tensors.insert("adam.v_bf16".into(), Tensor::Bf16(&c.v));
        }
        w.meta("adam_step", adam.step.to_string());
        w
    }

    /// Adds (or replaces) a tensor.
    pub fn tensor(&mut self, name: &str, values: &'a [f32]) -> &mut Self {
        self.tensors.insert(name.to_string(), Tensor::F32(values));
        self
    }

    /// Adds (or replaces) a metadata entry.
    pub fn meta(&mut self, key: &str, value: impl Into<String>) -> &mut Self {
        self.metadata.insert(key.to_string(), value.into());
        self
    }

    fn header(&self) -> Vec<u8> {
        let mut header = serde_json::Map::new();
        if !self.metadata.is_empty() {
            header.insert("__metadata__".into(), serde_json::json!(self.metadata));
        }
        let mut offset = 0usize;
        for (name, values) in &self.tensors {
            let (dtype, width, len) = values.shape();
            let end = offset + width * len;
            header.insert(name.clone(), serde_json::json!({"dtype": dtype, "shape": [len], "data_offsets": [offset, end]}));
            offset = end;
        }
        let mut bytes = serde_json::to_vec(&serde_json::Value::Object(header)).expect("a JSON map serialises");
        while !bytes.len().is_multiple_of(8) {
            bytes.push(b' ');
        }
        bytes
    }

    /// Writes the safetensors bytes to `out`.
    pub fn write_to(&self, out: &mut dyn Write) -> std::io::Result<()> {
        let header = self.header();
        out.write_all(&(header.len() as u64).to_le_bytes())?;
        out.write_all(&header)?;
        for values in self.tensors.values() {
            match values {
                Tensor::F32(values) => write_le(out, values, f32::to_le_bytes)?,
                Tensor::Bf16(values) => write_le(out, values, u16::to_le_bytes)?,
            }
        }
        Ok(())
    }

    /// The safetensors bytes in memory (small checkpoints and tests).
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.write_to(&mut out).expect("writing to memory does not fail");
        out
    }
}

/// Little-endian bytes of `values`, a block at a time (no copy of the whole tensor).
fn write_le<T: Copy, const N: usize>(out: &mut dyn Write, values: &[T], bytes: impl Fn(T) -> [u8; N]) -> std::io::Result<()> {
    for block in values.chunks(1 << 16) {
        out.write_all(&block.iter().flat_map(|v| bytes(*v)).collect::<Vec<u8>>())?;
    }
    Ok(())
}

/// A checkpoint being read: its header parsed and checked; tensors are read on demand.
#[derive(Debug, Clone)]
pub struct CheckpointReader {
    /// Metadata (step, configuration, …).
    pub metadata: HashMap<String, String>,
    /// Tensors: name → (byte offset in the file, values, bytes per value: 4 for F32, 2 for BF16).
    entries: HashMap<String, (u64, usize, u64)>,
}

impl CheckpointReader {
    /// Parses and checks the header of a checkpoint of `file_len` bytes read from `input`.
    pub fn open(input: &mut (impl Read + Seek), file_len: u64) -> Result<CheckpointReader, BackboneError> {
        let mut len = [0u8; 8];
        input.read_exact(&mut len).map_err(|_| err("shorter than its 8-byte header length: truncated or not a checkpoint"))?;
        let header_len = u64::from_le_bytes(len);
        if header_len > MAX_HEADER || header_len > file_len.saturating_sub(8) {
            return Err(err(format!("header length {header_len} does not fit the file of {file_len} bytes: truncated or corrupt")));
        }
        let mut header = vec![0u8; header_len as usize];
        input.read_exact(&mut header).map_err(|_| err("the header is cut short"))?;
        let json: serde_json::Map<String, serde_json::Value> =
            serde_json::from_slice(&header).map_err(|e| err(format!("the header is not valid JSON ({e})")))?;
        let data_start = 8 + header_len;
        let data_len = file_len - data_start;
        let mut metadata = HashMap::new();
        let mut entries = HashMap::new();
        for (name, value) in json {
            if name == "__metadata__" {
                let map = value.as_object().ok_or_else(|| err("__metadata__ is not a map"))?;
                for (k, v) in map {
                    metadata.insert(k.clone(), v.as_str().ok_or_else(|| err(format!("metadata {k:?} is not a string")))?.to_string());
                }
                continue;
            }
            let width: u64 = match value["dtype"].as_str().unwrap_or("?") {
                "F32" => 4,
                "BF16" => 2,
                dtype => return Err(err(format!("tensor {name:?} is {dtype}, expected F32 or BF16"))),
            };
            let offsets =
                value["data_offsets"].as_array().filter(|a| a.len() == 2).ok_or_else(|| err(format!("tensor {name:?}: bad data_offsets")))?;
            let (begin, end) = (offsets[0].as_u64().unwrap_or(u64::MAX), offsets[1].as_u64().unwrap_or(u64::MAX));
            let count: u64 = value["shape"]
                .as_array()
                .ok_or_else(|| err(format!("tensor {name:?}: no shape")))?
                .iter()
                .map(|d| d.as_u64().ok_or_else(|| err(format!("tensor {name:?}: bad shape"))))
                .try_fold(1u64, |acc, d| d.map(|d| acc.saturating_mul(d)))?;
            if begin > end || end > data_len || (end - begin) != count.saturating_mul(width) {
                return Err(err(format!("tensor {name:?}: offsets {begin}..{end} and shape disagree or exceed the file: truncated or corrupt")));
            }
            entries.insert(name, (data_start + begin, count as usize, width));
        }
        Ok(CheckpointReader { metadata, entries })
    }

    /// Values of tensor `name`, if it exists.
    pub fn len(&self, name: &str) -> Option<usize> {
        self.entries.get(name).map(|e| e.1)
    }

    /// Whether the checkpoint holds no tensor.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Names of the tensors.
    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.entries.keys().map(String::as_str)
    }

    /// Reads F32 tensor `name` into `dest`, which must have exactly its length.
    pub fn read_into(&self, input: &mut (impl Read + Seek), name: &str, dest: &mut [f32]) -> Result<(), BackboneError> {
        self.read_le(input, name, dest, f32::from_le_bytes)
    }

    /// Reads BF16 tensor `name` (bit patterns) into `dest`, which must have exactly its length.
    pub fn read_into_bf16(&self, input: &mut (impl Read + Seek), name: &str, dest: &mut [u16]) -> Result<(), BackboneError> {
        self.read_le(input, name, dest, u16::from_le_bytes)
    }

    /// Reads tensor `name` of `N`-byte little-endian values into `dest` after checking its
    /// element width and length.
    fn read_le<T, const N: usize>(
        &self,
        input: &mut (impl Read + Seek),
        name: &str,
        dest: &mut [T],
        value: impl Fn([u8; N]) -> T,
    ) -> Result<(), BackboneError> {
        let &(offset, count, width) = self.entries.get(name).ok_or_else(|| err(format!("no tensor {name:?}")))?;
        if width != N as u64 {
            let dtype = |w: u64| if w == 2 { "BF16" } else { "F32" };
            return Err(err(format!("tensor {name:?} is {}, expected {}", dtype(width), dtype(N as u64))));
        }
        if count != dest.len() {
            return Err(BackboneError::SizeMismatch { name: name.into(), found: count, expected: dest.len() });
        }
        input.seek(SeekFrom::Start(offset)).map_err(|e| err(format!("tensor {name:?}: {e}")))?;
        let mut bytes = vec![0u8; N << 16];
        for block in dest.chunks_mut(1 << 16) {
            let b = &mut bytes[..N * block.len()];
            input.read_exact(b).map_err(|_| err(format!("tensor {name:?} is cut short: truncated")))?;
            for (v, c) in block.iter_mut().zip(b.chunks_exact(N)) {
                *v = value(std::array::from_fn(|k| c[k]));
            }
        }
        Ok(())
    }

    /// Reads tensor `name` into a new vector.
    pub fn read_vec(&self, input: &mut (impl Read + Seek), name: &str) -> Result<Vec<f32>, BackboneError> {
        let count = self.len(name).ok_or_else(|| err(format!("no tensor {name:?}")))?;
        let mut v = vec![0.0f32; count];
        self.read_into(input, name, &mut v)?;
        Ok(v)
    }

    /// Restores `params` and `adam` (sizes must match the model, and the moments' storage
    /// `adam`'s) from `params`, `adam.m`, `adam.v` (`adam.m_bf16`, `adam.v_bf16`) and the
    /// metadata `adam_step`.
    pub fn restore_state(&self, input: &mut (impl Read + Seek), params: &mut [f32], adam: &mut Adam) -> Result<(), BackboneError> {
        let stored = self.entries.contains_key("adam.m_bf16");
        if stored != adam.compact.is_some() {
            let kind = |bf16: bool| if bf16 { "bf16 table moments" } else { "f32 moments only" };
            return Err(err(format!(
                "the checkpoint has {}, this run keeps {} (the optimiser setting differs)",
                kind(stored),
                kind(adam.compact.is_some())
            )));
        }
        self.read_into(input, "params", params)?;
        self.read_into(input, "adam.m", &mut adam.m)?;
        self.read_into(input, "adam.v", &mut adam.v)?;
        if let Some(c) = &mut adam.compact {
            self.read_into_bf16(input, "adam.m_bf16", &mut c.m)?;
            self.read_into_bf16(input, "adam.v_bf16", &mut c.v)?;
        }
        adam.step = self.metadata.get("adam_step").and_then(|s| s.parse().ok()).ok_or_else(|| err("missing or bad metadata adam_step"))?;
        Ok(())
    }

    /// The metadata entry `key`.
    pub fn meta(&self, key: &str) -> Result<&str, BackboneError> {
        self.metadata.get(key).map(String::as_str).ok_or_else(|| err(format!("no metadata {key:?}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Cursor;

    #[test]
    fn checkpoints_round_trip_and_damage_is_an_error() {
        let params: Vec<f32> = (0..1000).map(|i| i as f32 * 0.5 - 3.0).collect();
        let mut adam = Adam::new(1000);
        adam.m.iter_mut().enumerate().for_each(|(i, m)| *m = i as f32 * 1e-3);
        adam.step = 7;
        let grid = vec![0.25f32; 10];
        let mut w = CheckpointWriter::with_state(&params, &adam);
        w.tensor("grid", &grid).meta("step", "3");
        let bytes = w.to_bytes();
        let mut input = Cursor::new(&bytes);
        let r = CheckpointReader::open(&mut input, bytes.len() as u64).unwrap();
        let (mut p, mut a) = (vec![0.0; 1000], Adam::new(1000));
        r.restore_state(&mut input, &mut p, &mut a).unwrap();
        assert_eq!((p, a.m, a.step), (params.clone(), adam.m.clone(), 7));
        assert_eq!(r.read_vec(&mut input, "grid").unwrap(), grid);
        assert_eq!(r.meta("step").unwrap(), "3");
        // Another model's size is refused with the tensor named.
        let e = r.restore_state(&mut input, &mut vec![0.0; 999], &mut Adam::new(999)).unwrap_err();
        assert!(e.to_string().contains("params"), "{e}");
        // Truncated anywhere, corrupted, or not a checkpoint: errors, never panics.
        for cut in [0, 4, 8, 20, bytes.len() / 2, bytes.len() - 1] {
            let b = &bytes[..cut];
            let mut c = Cursor::new(b);
            let ok = CheckpointReader::open(&mut c, b.len() as u64).and_then(|r| r.restore_state(&mut c, &mut vec![0.0; 1000], &mut Adam::new(1000)));
            assert!(ok.is_err(), "cut at {cut}");
        }
        let mut huge = bytes.clone();
        huge[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(CheckpointReader::open(&mut Cursor::new(&huge), huge.len() as u64).is_err());
        assert!(CheckpointReader::open(&mut Cursor::new(b"not a checkpoint"), 16).is_err());
        // The standard reader accepts what we write.
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        assert_eq!(st.tensor("grid").unwrap().shape(), &[10]);
    }

    #[test]
    fn compact_moments_round_trip_and_a_storage_mismatch_is_named() {
        let params: Vec<f32> = (0..100).map(|i| i as f32).collect();
        let mut adam = Adam::with_compact_prefix(100, 60);
        let c = adam.compact.as_mut().unwrap();
        c.m.iter_mut().enumerate().for_each(|(i, m)| *m = i as u16 * 3);
        c.v.iter_mut().enumerate().for_each(|(i, v)| *v = 0x3F80 + i as u16);
        adam.m.iter_mut().enumerate().for_each(|(i, m)| *m = i as f32 * 0.25);
        adam.step = 4;
        let bytes = CheckpointWriter::with_state(&params, &adam).to_bytes();
        let mut input = Cursor::new(&bytes);
        let r = CheckpointReader::open(&mut input, bytes.len() as u64).unwrap();
        let (mut p, mut a) = (vec![0.0; 100], Adam::with_compact_prefix(100, 60));
        r.restore_state(&mut input, &mut p, &mut a).unwrap();
        assert_eq!((p, &a.m, a.step), (params.clone(), &adam.m, 4));
        assert_eq!(
            (&a.compact.as_ref().unwrap().m, &a.compact.as_ref().unwrap().v),
            (&adam.compact.as_ref().unwrap().m, &adam.compact.as_ref().unwrap().v)
        );
        let e = r.restore_state(&mut input, &mut vec![0.0; 100], &mut Adam::new(100)).unwrap_err();
        assert!(e.to_string().contains("bf16 table moments"), "{e}");
        let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        assert_eq!(st.tensor("adam.v_bf16").unwrap().dtype(), safetensors::Dtype::BF16);
    }
}
