//! Checkpoints as safetensors files (readable from Python with `safetensors.numpy.load_file`):
//! named 1-D f32 tensors and string metadata.
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

/// A checkpoint to write: tensors borrowed from the caller, in name order.
#[derive(Debug, Default)]
pub struct CheckpointWriter<'a> {
    tensors: BTreeMap<String, &'a [f32]>,
    metadata: BTreeMap<String, String>,
}

impl<'a> CheckpointWriter<'a> {
    /// An empty checkpoint.
    pub fn new() -> Self {
        CheckpointWriter::default()
    }

    /// The model and optimiser state: `params`, `adam.m`, `adam.v`, metadata `adam_step`.
    pub fn with_state(params: &'a [f32], adam: &'a Adam) -> Self {
        let mut w = CheckpointWriter::new();
        w.tensor("params", params);
        w.tensor("adam.m", &adam.m);
        w.tensor("adam.v", &adam.v);
        w.meta("adam_step", adam.step.to_string());
        w
    }

    /// Adds (or replaces) a tensor.
    pub fn tensor(&mut self, name: &str, values: &'a [f32]) -> &mut Self {
        self.tensors.insert(name.to_string(), values);
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
            let end = offset + 4 * values.len();
            header.insert(name.clone(), serde_json::json!({"dtype": "F32", "shape": [values.len()], "data_offsets": [offset, end]}));
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
            // f32 → little-endian bytes, a block at a time (no copy of the whole tensor).
            for block in values.chunks(1 << 16) {
                let bytes: Vec<u8> = block.iter().flat_map(|v| v.to_le_bytes()).collect();
                out.write_all(&bytes)?;
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

/// A checkpoint being read: its header parsed and checked; tensors are read on demand.
#[derive(Debug, Clone)]
pub struct CheckpointReader {
    /// Metadata (step, configuration, …).
    pub metadata: HashMap<String, String>,
    /// Tensors: name → (byte offset in the file, values).
    entries: HashMap<String, (u64, usize)>,
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
            let dtype = value["dtype"].as_str().unwrap_or("?");
            if dtype != "F32" {
                return Err(err(format!("tensor {name:?} is {dtype}, expected F32")));
            }
            let offsets =
                value["data_offsets"].as_array().filter(|a| a.len() == 2).ok_or_else(|| err(format!("tensor {name:?}: bad data_offsets")))?;
            let (begin, end) = (offsets[0].as_u64().unwrap_or(u64::MAX), offsets[1].as_u64().unwrap_or(u64::MAX));
            let count: u64 = value["shape"]
                .as_array()
                .ok_or_else(|| err(format!("tensor {name:?}: no shape")))?
                .iter()
                .map(|d| d.as_u64().ok_or_else(|| err(format!("tensor {name:?}: bad shape"))))
                .try_fold(1u64, |acc, d| d.map(|d| acc.saturating_mul(d)))?;
            if begin > end || end > data_len || (end - begin) != count.saturating_mul(4) {
                return Err(err(format!("tensor {name:?}: offsets {begin}..{end} and shape disagree or exceed the file: truncated or corrupt")));
            }
            entries.insert(name, (data_start + begin, count as usize));
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

    /// Reads tensor `name` into `dest`, which must have exactly its length.
    pub fn read_into(&self, input: &mut (impl Read + Seek), name: &str, dest: &mut [f32]) -> Result<(), BackboneError> {
        let &(offset, count) = self.entries.get(name).ok_or_else(|| err(format!("no tensor {name:?}")))?;
        if count != dest.len() {
            return Err(BackboneError::SizeMismatch { name: name.into(), found: count, expected: dest.len() });
        }
        input.seek(SeekFrom::Start(offset)).map_err(|e| err(format!("tensor {name:?}: {e}")))?;
        let mut bytes = vec![0u8; 4 << 16];
        for block in dest.chunks_mut(1 << 16) {
            let b = &mut bytes[..4 * block.len()];
            input.read_exact(b).map_err(|_| err(format!("tensor {name:?} is cut short: truncated")))?;
            for (v, c) in block.iter_mut().zip(b.chunks_exact(4)) {
                *v = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
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

    /// Restores `params` and `adam` (sizes must match the model) from `params`, `adam.m`,
    /// `adam.v` and the metadata `adam_step`.
    pub fn restore_state(&self, input: &mut (impl Read + Seek), params: &mut [f32], adam: &mut Adam) -> Result<(), BackboneError> {
        self.read_into(input, "params", params)?;
        self.read_into(input, "adam.m", &mut adam.m)?;
        self.read_into(input, "adam.v", &mut adam.v)?;
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
}
