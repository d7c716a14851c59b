//! `cargo xtask fuzz`: every parser of user input fed mutated bytes — PLY, NPY, NPZ, IDR camera
//! archives, transforms JSON, COLMAP models (binary and text), images and masks, OBJ and
//! glTF/GLB meshes, training configurations and `key=value` overrides, checkpoints. A parser must answer any bytes with a
//! value or an error: a panic, an allocation beyond the memory cap, or a case slower than the
//! time-out is a finding, saved with its input under `OUT/findings/`.
//!
//! Cases are generated, not evolved: case `i` takes a seed input of its target (valid files made
//! in memory) and applies 1–8 mutations drawn from its own RNG stream (`stream_seed(seed, i)`),
//! so any case is reproduced from `(seed, i)` alone, whatever the thread count. Mutations:
//! bit flips, interesting bytes and integers (0, −1, 2³¹, 2³², 2⁶³ …) written over 1/2/4/8
//! bytes, truncation, deletion, insertion, duplication, splicing with another seed, and for text
//! numbers replaced by extreme ones (1e308, NaN, −0, 2⁶⁴ …) and structural characters inserted.
//!
//! The command runs the cases in a worker process under an allocation cap (the binary's global
//! allocator is `cap::Cap`): an allocation over the cap aborts the worker, and a stuck case is
//! ended by a watchdog; each worker thread first writes its case to `OUT/inflight/`, so that
//! the supervisor can name the input that killed the worker and confirm it by replaying it
//! (`--replay FILE`).

use anyhow::{Context, Result, bail};
use datasets::colmap::{ModelEncoding, ModelFiles};
use datasets::io::{MeshFormat, PlyData};
use datasets::npy::{npy_bytes, write_npz};
use datasets::{Format, LoadOptions};
use glam::{DMat3, DMat4, DVec3, Vec3};
use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
use std::cell::RefCell;
use std::io::{BufRead, Cursor, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::Instant;

/// Options of `cargo xtask fuzz`.
#[derive(clap::Args, Debug, Clone)]
pub struct FuzzArgs {
    /// Cases in all (targets take turns).
    #[arg(long, default_value_t = 1_000_000)]
    pub cases: u64,
    /// Stop after this long (e.g. 10m) even if cases remain.
    #[arg(long)]
    pub time: Option<String>,
    /// Targets (repeat); default all. `--list` names them.
    #[arg(long)]
    pub target: Vec<String>,
    /// List the targets and exit.
    #[arg(long)]
    pub list: bool,
    /// Seed of the case streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// First case index (to continue a stream).
    #[arg(long, default_value_t = 0)]
    pub first_case: u64,
    /// Output folder: findings, in-flight cases.
    #[arg(long, default_value = "out/fuzz")]
    pub out: PathBuf,
    /// Allocation cap of the worker (live heap bytes), e.g. 2G, 512M.
    #[arg(long, default_value = "2G")]
    pub max_memory: String,
    /// A case running longer than this is a finding (seconds).
    #[arg(long, default_value_t = 10.0)]
    pub case_timeout: f64,
    /// Replay saved inputs (with --target) instead of fuzzing; exit 0 when each is accepted or
    /// rejected cleanly.
    #[arg(long)]
    pub replay: Vec<PathBuf>,
    /// Internal: run the cases in this process (the supervisor starts workers with it).
    #[arg(long, hide = true)]
    pub worker: bool,
}

/// What a target returns: `Ok` when the bytes were accepted, `Err(message)` when rejected
/// cleanly.
pub type Verdict = std::result::Result<(), String>;

/// A parser under test.
pub struct Target {
    /// Name on the command line.
    pub name: &'static str,
    /// What it drives.
    pub about: &'static str,
    /// Valid inputs the mutations start from.
    pub seeds: fn() -> Vec<Vec<u8>>,
    /// Runs the parser on bytes.
    pub run: fn(&[u8]) -> Verdict,
}

/// Separates the files of a multi-file input (COLMAP's three files, an IDR archive's arrays).
const FILE_MARK: &[u8] = b"\n\0--file--\0\n";

fn split_files(bytes: &[u8]) -> Vec<&[u8]> {
    let mut out = Vec::new();
    let mut rest = bytes;
    while let Some(at) = rest.windows(FILE_MARK.len()).position(|w| w == FILE_MARK) {
        out.push(&rest[..at]);
        rest = &rest[at + FILE_MARK.len()..];
    }
    out.push(rest);
    out
}

fn join_files(files: &[Vec<u8>]) -> Vec<u8> {
    files.join(FILE_MARK)
}

fn verdict<T, E: std::fmt::Display>(r: std::result::Result<T, E>) -> Verdict {
    r.map(|_| ()).map_err(|e| e.to_string())
}

// ----- seeds -------------------------------------------------------------------------------

/// Image size the fuzzed camera files claim for their images.
const IMAGE_SIZE: (u32, u32) = (64, 48);

/// `camera_from_world` of fuzz camera `i`: on a circle of radius 3 around the origin, looking at it.
fn seed_camera(i: usize) -> (DMat3, DVec3) {
    let angle = 0.4 * i as f64 - 0.6;
    (DMat3::from_rotation_y(angle), DVec3::new(0.0, 0.0, 3.0))
}

fn seeds_ply() -> Vec<Vec<u8>> {
    let ply = PlyData {
        positions: vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
        normals: vec![Vec3::Z; 4],
        colors: vec![[200, 10, 10]; 4],
        faces: vec![[0, 1, 2], [0, 2, 3]],
        ..Default::default()
    };
    let ascii = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
                 element face 2\nproperty list uchar int vertex_indices\nend_header\n\
                 0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n4 0 1 2 3\n";
    vec![ply.to_bytes(), ascii.as_bytes().to_vec()]
}

fn seeds_npy() -> Vec<Vec<u8>> {
    vec![npy_bytes(&[4, 4], &[1.0f64; 16]), npy_bytes(&[3], &[1.5f32, -2.0, 3.25]), npy_bytes(&[2, 1, 2], &[0.0f64; 4])]
}

fn npz_of(entries: &[(String, Vec<u8>)]) -> std::result::Result<Vec<u8>, String> {
    write_npz(Cursor::new(Vec::new()), entries).map(Cursor::into_inner).map_err(|e| format!("not an archive: {e}"))
}

/// IDR arrays of three cameras: `world_mat_i` = K [R | t] and `scale_mat_i`.
fn idr_arrays() -> Vec<(String, Vec<u8>)> {
    let k = DMat4::from_cols_array(&[60.0, 0.0, 0.0, 0.0, 0.0, 60.0, 0.0, 0.0, 32.0, 24.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0]);
    let mut entries = Vec::new();
    for i in 0..3 {
        let (r, t) = seed_camera(i);
        let rt = DMat4::from_cols(r.x_axis.extend(0.0), r.y_axis.extend(0.0), r.z_axis.extend(0.0), t.extend(1.0));
        let p = k * rt;
        let rows = |m: DMat4| -> Vec<f64> { (0..4).flat_map(|r| (0..4).map(move |c| m.col(c)[r])).collect() };
        entries.push((format!("world_mat_{i}"), npy_bytes(&[4, 4], &rows(p))));
        let scale = DMat4::from_scale(DVec3::splat(1.2));
        entries.push((format!("scale_mat_{i}"), npy_bytes(&[4, 4], &rows(scale))));
    }
    entries
}

fn seeds_npz() -> Vec<Vec<u8>> {
    [npz_of(&idr_arrays()[..2]), npz_of(&[("a".into(), npy_bytes(&[2], &[1.0f32, 2.0]))])].map(|r| r.expect("distinct names")).to_vec()
}

fn seeds_idr() -> Vec<Vec<u8>> {
    let arrays = idr_arrays();
    // Name and bytes of each array, as alternating files.
    vec![join_files(&arrays.iter().flat_map(|(n, b)| [n.as_bytes().to_vec(), b.clone()]).collect::<Vec<_>>())]
}

fn seeds_transforms() -> Vec<Vec<u8>> {
    let matrix = |i: usize| {
        // OpenGL camera-to-world of fuzz camera i (flip y, z of the OpenCV camera).
        let (r, t) = seed_camera(i);
        let rotation = r.transpose() * DMat3::from_diagonal(DVec3::new(1.0, -1.0, -1.0));
        let centre = -(r.transpose() * t);
        format!(
            "[[{},{},{},{}],[{},{},{},{}],[{},{},{},{}],[0,0,0,1]]",
            rotation.x_axis.x,
            rotation.y_axis.x,
            rotation.z_axis.x,
            centre.x,
            rotation.x_axis.y,
            rotation.y_axis.y,
            rotation.z_axis.y,
            centre.y,
            rotation.x_axis.z,
            rotation.y_axis.z,
            rotation.z_axis.z,
            centre.z
        )
    };
    let frames = |extra: &str| {
        (0..3).map(|i| format!("{{\"file_path\": \"./train/r_{i}\"{extra}, \"transform_matrix\": {}}}", matrix(i))).collect::<Vec<_>>().join(",")
    };
    vec![
        format!("{{\"camera_angle_x\": 0.69, \"frames\": [{}]}}", frames("")).into_bytes(),
        format!(
            "{{\"fl_x\": 60, \"fl_y\": 61, \"cx\": 32, \"cy\": 24, \"w\": 64, \"h\": 48, \"aabb\": [[-1,-1,-1],[1,1,1]], \"frames\": [{}]}}",
            frames(", \"fl_x\": 59")
        )
        .into_bytes(),
        format!("{{\"fl_x\": 60, \"sphere_center\": [0, 0, 0], \"sphere_radius\": 1.5, \"k1\": 0, \"frames\": [{}]}}", frames("")).into_bytes(),
    ]
}

/// A small COLMAP model: a PINHOLE and an OPENCV camera, four images, eight points seen by
/// three images each; `(cameras, images, points3D)` as binary or text.
fn colmap_seed(binary: bool) -> [Vec<u8>; 3] {
    let cameras: [(u32, i32, &str, Vec<f64>); 2] =
        [(1, 1, "PINHOLE", vec![60.0, 60.0, 32.0, 24.0]), (2, 4, "OPENCV", vec![60.0, 61.0, 32.0, 24.0, -0.05, 0.01, 0.001, -0.001])];
    let images: Vec<(u32, [f64; 4], DVec3, u32, String)> = (0..4)
        .map(|i| {
            let (r, t) = seed_camera(i);
            let q = glam::DQuat::from_mat3(&r);
            (i as u32 + 1, [q.w, q.x, q.y, q.z], t, 1 + (i as u32 % 2), format!("{i:03}.png"))
        })
        .collect();
    let points: Vec<(u64, DVec3)> =
        (0..8).map(|i| (i as u64 + 1, DVec3::new((i % 2) as f64 - 0.5, ((i / 2) % 2) as f64 - 0.5, (i / 4) as f64 - 0.5) * 0.6)).collect();
    let track = |p: usize| -> Vec<(u32, u32)> { (0..3).map(|j| (((p + j) % 4) as u32 + 1, p as u32)).collect() };
    if binary {
        let mut c = (cameras.len() as u64).to_le_bytes().to_vec();
        for (id, model, _, params) in &cameras {
            c.extend(id.to_le_bytes());
            c.extend(model.to_le_bytes());
            c.extend((IMAGE_SIZE.0 as u64).to_le_bytes());
            c.extend((IMAGE_SIZE.1 as u64).to_le_bytes());
            params.iter().for_each(|p| c.extend(p.to_le_bytes()));
        }
        let mut im = (images.len() as u64).to_le_bytes().to_vec();
        for (id, q, t, camera, name) in &images {
            im.extend(id.to_le_bytes());
            q.iter().for_each(|v| im.extend(v.to_le_bytes()));
            t.to_array().iter().for_each(|v| im.extend(v.to_le_bytes()));
            im.extend(camera.to_le_bytes());
            im.extend(name.as_bytes());
            im.push(0);
            im.extend(2u64.to_le_bytes());
            for k in 0..2 {
                im.extend((10.0 * k as f64).to_le_bytes());
                im.extend(20.0f64.to_le_bytes());
                im.extend((k as i64 - 1).to_le_bytes());
            }
        }
        let mut pt = (points.len() as u64).to_le_bytes().to_vec();
        for (p, (id, xyz)) in points.iter().enumerate() {
            pt.extend(id.to_le_bytes());
            xyz.to_array().iter().for_each(|v| pt.extend(v.to_le_bytes()));
            pt.extend([120, 130, 140]);
            pt.extend(0.5f64.to_le_bytes());
            let tr = track(p);
            pt.extend((tr.len() as u64).to_le_bytes());
            for (image, index) in tr {
                pt.extend(image.to_le_bytes());
                pt.extend(index.to_le_bytes());
            }
        }
        [c, im, pt]
    } else {
        let mut c = String::from("# Camera list\n");
        for (id, _, name, params) in &cameras {
            let params: Vec<String> = params.iter().map(|p| p.to_string()).collect();
            c += &format!("{id} {name} {} {} {}\n", IMAGE_SIZE.0, IMAGE_SIZE.1, params.join(" "));
        }
        let mut im = String::from("# Image list\n");
        for (id, q, t, camera, name) in &images {
            im += &format!("{id} {} {} {} {} {} {} {} {camera} {name}\n0 20 -1 10 20 0\n", q[0], q[1], q[2], q[3], t.x, t.y, t.z);
        }
        let mut pt = String::from("# 3D point list\n");
        for (p, (id, xyz)) in points.iter().enumerate() {
            let tr: Vec<String> = track(p).iter().map(|(i, k)| format!("{i} {k}")).collect();
            pt += &format!("{id} {} {} {} 120 130 140 0.5 {}\n", xyz.x, xyz.y, xyz.z, tr.join(" "));
        }
        [c.into_bytes(), im.into_bytes(), pt.into_bytes()]
    }
}

fn seeds_colmap_binary() -> Vec<Vec<u8>> {
    vec![join_files(&colmap_seed(true))]
}

fn seeds_colmap_text() -> Vec<Vec<u8>> {
    vec![join_files(&colmap_seed(false))]
}

fn seeds_image() -> Vec<Vec<u8>> {
    let (w, h) = (8u32, 6u32);
    let rgb: Vec<u8> = (0..w * h * 3).map(|i| (i * 37 % 256) as u8).collect();
    let rgba: Vec<u8> = (0..w * h * 4).map(|i| (i * 53 % 256) as u8).collect();
    let grey: Vec<u8> = (0..w * h).map(|i| if i % 3 == 0 { 255 } else { 0 }).collect();
    use image::ExtendedColorType as C;
    [(rgb, C::Rgb8), (rgba, C::Rgba8), (grey, C::L8)]
        .into_iter()
        .map(|(pixels, color)| datasets::images::png_bytes(&pixels, w, h, color).expect("encoding in memory"))
        .collect()
}

fn seeds_config() -> Vec<Vec<u8>> {
    vec![crate::config::TrainConfig::default().to_toml().into_bytes()]
}

fn seeds_overrides() -> Vec<Vec<u8>> {
    vec![
        b"steps=7\nguide.scene.partition=1\nsampler=uniform\nguide.extra=log\nmodel.preset=neus-cpu\n".to_vec(),
        b"time_budget_s=30\nrender.rays=64\noutput.mesh_formats=[\"obj\", \"glb\"]\nmodel.background=[0.1, 0.2, 0.3]\n".to_vec(),
    ]
}

/// The tiny run the checkpoint target restores into (a 40 × 30 built-in scene, neus-cpu).
fn tiny_trainer() -> Result<crate::trainer::Trainer> {
    let overrides: Vec<String> = [
        "steps=4",
        "model.preset=neus-cpu",
        "data.builtin.width=40",
        "data.builtin.views=6",
        "render.rays=16",
        "guide.scene.resolution=8",
        "guide.camera.ru=4",
        "guide.camera.rv=4",
        "guide.camera.rl=8",
        "render.skip_empty=true",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect();
    let config = crate::config::TrainConfig::load(None, &overrides)?;
    let data = crate::data::SceneData::load(&config, None)?;
    let mut trainer = crate::trainer::Trainer::new(config, data)?;
    trainer.step()?;
    Ok(trainer)
}

/// Tiny runs the checkpoint target restores into, one per worker (taken and put back per case).
static TRAINERS: Mutex<Vec<crate::trainer::Trainer>> = Mutex::new(Vec::new());

/// Builds `n` tiny runs for the checkpoint target (before the allocation cap is set).
pub fn prepare_checkpoint_runs(n: usize) -> Result<()> {
    let mut pool = TRAINERS.lock().expect("trainer pool");
    while pool.len() < n {
        pool.push(tiny_trainer().context("building the checkpoint target's tiny run")?);
    }
    Ok(())
}

fn seeds_checkpoint() -> Vec<Vec<u8>> {
    let trainer = tiny_trainer().expect("the tiny built-in run builds");
    let mut bytes = Vec::new();
    trainer.write_checkpoint(&mut bytes).expect("writing to memory");
    vec![bytes]
}

// ----- targets ------------------------------------------------------------------------------

fn seeds_obj() -> Vec<Vec<u8>> {
    let (positions, faces) = ([Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z], [[0, 1, 2], [0, 2, 3], [1, 2, 3]]);
    let quads = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3 4/4\nf -1 -2 -3\n";
    vec![datasets::io::mesh_bytes(MeshFormat::Obj, &positions, &faces, None), quads.as_bytes().to_vec()]
}

fn run_obj(b: &[u8]) -> Verdict {
    verdict(datasets::parse::obj(b, Path::new("mesh.obj")))
}

fn seeds_gltf() -> Vec<Vec<u8>> {
    let (positions, faces) = ([Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z], [[0, 1, 2], [0, 2, 3], [1, 2, 3]]);
    // A JSON glTF with a data URI, a node hierarchy and indices.
    let mut buffer = Vec::new();
    for p in positions {
        buffer.extend(p.to_array().iter().flat_map(|c| c.to_le_bytes()));
    }
    buffer.extend(faces.iter().flatten().flat_map(|&i: &u32| (i as u16).to_le_bytes()));
    let json = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"children":[1],"translation":[0,0,1]}},{{"mesh":0,"scale":[2,2,2]}}],"meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],"accessors":[{{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,1]}},{{"bufferView":1,"componentType":5123,"count":9,"type":"SCALAR"}}],"bufferViews":[{{"buffer":0,"byteLength":48}},{{"buffer":0,"byteOffset":48,"byteLength":18}}],"buffers":[{{"byteLength":66,"uri":"data:application/octet-stream;base64,{}"}}]}}"#,
        base64(&buffer)
    );
    vec![datasets::io::mesh_bytes(MeshFormat::Glb, &positions, &faces, None), json.into_bytes()]
}

/// Standard base64 with padding (the seed's data URI).
fn base64(bytes: &[u8]) -> String {
    const T: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = u32::from(c[0]) << 16 | u32::from(*c.get(1).unwrap_or(&0)) << 8 | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            s.push(if k <= c.len() { T[(n >> (18 - 6 * k) & 63) as usize] as char } else { '=' });
        }
    }
    s
}

fn run_gltf(b: &[u8]) -> Verdict {
    verdict(datasets::parse::gltf(b, Path::new("mesh.gltf")))
}

fn run_ply(b: &[u8]) -> Verdict {
    verdict(datasets::parse::ply(b, Path::new("mesh.ply")))
}

fn run_npy(b: &[u8]) -> Verdict {
    verdict(datasets::parse::npy(b, Path::new("array.npy")))
}

fn run_npz(b: &[u8]) -> Verdict {
    verdict(datasets::parse::npz(b, Path::new("cameras.npz")))
}

fn run_idr(b: &[u8]) -> Verdict {
    let files = split_files(b);
    let entries: Vec<(String, Vec<u8>)> =
        files.chunks(2).filter(|p| p.len() == 2).map(|p| (String::from_utf8_lossy(p[0]).into_owned(), p[1].to_vec())).collect();
    // Mutated names may repeat: the zip writer refuses, and so does the case.
    let archive = npz_of(&entries)?;
    let options = LoadOptions { downscale: 1 + (b.len() % 2) as u32, ..LoadOptions::default() };
    verdict(datasets::parse::idr_cameras(&archive, Path::new("scene/cameras_sphere.npz"), IMAGE_SIZE, b.len().is_multiple_of(3), &options))
}

fn run_transforms(b: &[u8]) -> Verdict {
    let ngp = b.windows(4).any(|w| w == b"aabb" || w == b"sphe");
    let format = if ngp { Format::InstantNgp } else { Format::NerfSynthetic };
    verdict(datasets::parse::transforms_cameras(b, Path::new("scene/transforms.json"), format, IMAGE_SIZE, &LoadOptions::default()))
}

fn run_colmap(b: &[u8], encoding: ModelEncoding) -> Verdict {
    let files = split_files(b);
    let [cameras, images, points] = [0, 1, 2].map(|i| files.get(i).copied().unwrap_or_default());
    let ext = if encoding == ModelEncoding::Binary { "bin" } else { "txt" };
    let names = ModelFiles {
        cameras: format!("sparse/0/cameras.{ext}").into(),
        images: format!("sparse/0/images.{ext}").into(),
        points3d: format!("sparse/0/points3D.{ext}").into(),
        encoding,
    };
    verdict(datasets::parse::colmap_model(names, cameras, images, points))
}

fn run_colmap_binary(b: &[u8]) -> Verdict {
    run_colmap(b, ModelEncoding::Binary)
}

fn run_colmap_text(b: &[u8]) -> Verdict {
    run_colmap(b, ModelEncoding::Text)
}

fn run_image(b: &[u8]) -> Verdict {
    let downscale = 1 + (b.len() % 2) as u32;
    let image = verdict(datasets::parse::image(b, Path::new("image/000.png"), downscale, [1.0; 3]));
    let mask = verdict(datasets::parse::mask(b, Path::new("mask/000.png"), downscale));
    image.and(mask)
}

fn run_config(b: &[u8]) -> Verdict {
    let text = std::str::from_utf8(b).map_err(|e| e.to_string())?;
    verdict(crate::config::TrainConfig::from_toml(text))
}

fn run_overrides(b: &[u8]) -> Verdict {
    let lines: Vec<String> = String::from_utf8_lossy(b).lines().map(String::from).collect();
    verdict(crate::config::TrainConfig::load(None, &lines))
}

fn run_checkpoint(b: &[u8]) -> Verdict {
    let taken = TRAINERS.lock().map_err(|_| "trainer pool poisoned".to_string())?.pop();
    let mut trainer = match taken {
        Some(t) => t,
        None => tiny_trainer().map_err(|e| format!("building the tiny run: {e:#}"))?,
    };
    let mut input = Cursor::new(b);
    let verdict = match sdf_backbone::CheckpointReader::open(&mut input, b.len() as u64) {
        Ok(reader) => verdict(trainer.restore(&reader, &mut input).map_err(|e| format!("{e:#}"))),
        Err(e) => Err(e.to_string()),
    };
    if let Ok(mut pool) = TRAINERS.lock() {
        pool.push(trainer);
    }
    verdict
}

/// Every target.
pub fn targets() -> Vec<Target> {
    vec![
        Target { name: "ply", about: "PLY meshes (ASCII, binary little-endian)", seeds: seeds_ply, run: run_ply },
        Target { name: "npy", about: "NPY arrays", seeds: seeds_npy, run: run_npy },
        Target { name: "npz", about: "NPZ archives (zip of NPY arrays, entry sizes capped)", seeds: seeds_npz, run: run_npz },
        Target { name: "idr", about: "IDR/NeuS/DTU camera archives: world_mat_i, scale_mat_i → cameras", seeds: seeds_idr, run: run_idr },
        Target {
            name: "transforms", about: "transforms JSON (NeRF-synthetic, instant-ngp) → cameras", seeds: seeds_transforms, run: run_transforms
        },
        Target { name: "colmap-bin", about: "COLMAP binary models → views and bound sphere", seeds: seeds_colmap_binary, run: run_colmap_binary },
        Target { name: "colmap-txt", about: "COLMAP text models → views and bound sphere", seeds: seeds_colmap_text, run: run_colmap_text },
        Target { name: "image", about: "image and mask files (PNG seeds; any format the decoder detects)", seeds: seeds_image, run: run_image },
        Target { name: "config", about: "training configurations (TOML) with validation", seeds: seeds_config, run: run_config },
        Target { name: "overrides", about: "key=value overrides of the command line", seeds: seeds_overrides, run: run_overrides },
        Target { name: "obj", about: "OBJ meshes (geometry; material libraries are files of their own)", seeds: seeds_obj, run: run_obj },
        Target { name: "gltf", about: "glTF and GLB meshes with embedded buffers (node graph, accessors)", seeds: seeds_gltf, run: run_gltf },
        Target {
            name: "checkpoint",
            about: "checkpoints (safetensors header, tensors, restore into a run)",
            seeds: seeds_checkpoint,
            run: run_checkpoint,
        },
    ]
}

// ----- mutations ----------------------------------------------------------------------------

const INTERESTING_BYTES: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, b'\n', b'-', b'9'];
const INTERESTING_INTS: [u64; 14] =
    [0, 1, 2, 3, 255, 65535, 0x7fff_ffff, 0x8000_0000, 0xffff_ffff, 1 << 32, 1 << 40, i64::MAX as u64, 1 << 63, u64::MAX];
const INTERESTING_NUMBERS: [&str; 16] = [
    "0",
    "-0",
    "-1",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "4294967296",
    "18446744073709551616",
    "99999999999999999999",
    "2147483648",
    "0.5",
    "1e9",
];
const INTERESTING_TEXT: [&str; 12] = ["{", "}", "[", "]", "\"", ",", "\n", " ", "\0", "é", "=", "#"];

/// Writes a mutant of `base` into `out`: 1–8 stacked mutations.
pub fn mutate(rng: &mut Xoshiro256PlusPlus, base: &[u8], others: &[Vec<u8>], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(base);
    let rounds = 1 + rng.random_range(0..8usize).min(rng.random_range(0..8usize));
    for _ in 0..rounds {
        let len = out.len();
        let at = if len == 0 { 0 } else { rng.random_range(0..len) };
        match rng.random_range(0..11u32) {
            0 if len > 0 => out[at] ^= 1 << rng.random_range(0..8),
            1 if len > 0 => out[at] = INTERESTING_BYTES[rng.random_range(0..INTERESTING_BYTES.len())],
            2 => {
                let v = INTERESTING_INTS[rng.random_range(0..INTERESTING_INTS.len())];
                let v = if rng.random::<bool>() { v.wrapping_neg() } else { v };
                let width = [1usize, 2, 4, 8][rng.random_range(0..4)];
                let bytes = v.to_le_bytes();
                for (k, b) in bytes.iter().take(width).enumerate() {
                    if let Some(slot) = out.get_mut(at + k) {
                        *slot = *b;
                    }
                }
            }
            3 => out.truncate(at),
            4 if len > 0 => {
                let n = rng.random_range(1..=(len - at).min(64));
                out.drain(at..at + n);
            }
            5 => {
                let n = rng.random_range(1..=16);
                let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                out.splice(at..at, bytes);
            }
            6 if len > 0 => {
                let n = rng.random_range(1..=(len - at).min(256));
                let chunk = out[at..at + n].to_vec();
                let to = rng.random_range(0..=len);
                out.splice(to..to, chunk);
            }
            7 if !others.is_empty() => {
                let other = &others[rng.random_range(0..others.len())];
                if !other.is_empty() {
                    let from = rng.random_range(0..other.len());
                    let n = rng.random_range(1..=(other.len() - from).min(256));
                    let end = (at + n).min(len);
                    out.splice(at..end, other[from..from + n].iter().copied());
                }
            }
            8 | 9 => {
                // A number in text replaced by an extreme one.
                if let Some((start, end)) = number_near(out, at) {
                    let v = INTERESTING_NUMBERS[rng.random_range(0..INTERESTING_NUMBERS.len())];
                    out.splice(start..end, v.bytes());
                }
            }
            _ => {
                let t = INTERESTING_TEXT[rng.random_range(0..INTERESTING_TEXT.len())];
                out.splice(at..at, t.bytes());
            }
        }
    }
}

/// The byte range of the first ASCII number at or after `from`.
fn number_near(bytes: &[u8], from: usize) -> Option<(usize, usize)> {
    let is_num = |b: u8| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'e';
    let start = from + bytes.get(from..)?.iter().position(|b| b.is_ascii_digit())?;
    let start = (0..start).rev().take_while(|&i| is_num(bytes[i])).last().unwrap_or(start);
    let end = start + bytes[start..].iter().take_while(|b| is_num(**b)).count();
    Some((start, end))
}

// ----- running ------------------------------------------------------------------------------

/// A case that panicked (in-process findings; aborts and hangs are found by the supervisor).
#[derive(Debug, Clone)]
pub struct Finding {
    /// Target name.
    pub target: String,
    /// Case index.
    pub case: u64,
    /// The panic message and location.
    pub message: String,
    /// The input.
    pub input: Vec<u8>,
}

/// Counts per target.
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// Cases run.
    pub cases: u64,
    /// Cases the parser accepted (the rest were rejected with an error).
    pub accepted: u64,
    /// Time spent in the parser, seconds (all threads).
    pub seconds: f64,
    /// The slowest case, seconds.
    pub slowest: f64,
}

/// What a fuzzing run found.
#[derive(Debug, Default)]
pub struct Report {
    /// Per target, in the order given.
    pub tallies: Vec<(String, Tally)>,
    /// Panics, first per (target, location).
    pub findings: Vec<Finding>,
    /// Wall time of the cases.
    pub seconds: f64,
    /// Order-free digest of every case's input and verdict (the same for any thread count).
    pub digest: u64,
}

thread_local! {
    static PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// How many fuzz runs are under way in this process (panics are recorded, not printed, while > 0).
static QUIET_PANICS: AtomicUsize = AtomicUsize::new(0);

/// Per worker thread: when its running case started ([`clock_ms`], ≥ 1), 0 when idle.
static RUNNING: [AtomicU64; 64] = [const { AtomicU64::new(0) }; 64];

/// Milliseconds on a monotonic clock (from the first call).
fn clock_ms() -> u64 {
    static ORIGIN: std::sync::OnceLock<Instant> = std::sync::OnceLock::new();
    ORIGIN.get_or_init(Instant::now).elapsed().as_millis() as u64
}

/// Installs (once) a panic hook that records panics of fuzz cases instead of printing them.
fn install_panic_hook() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        let default = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if QUIET_PANICS.load(Ordering::SeqCst) > 0 {
                let location = info.location().map_or("?".into(), |l| format!("{}:{}", l.file(), l.line()));
                let payload = info.payload();
                let message =
                    payload.downcast_ref::<&str>().map(|s| s.to_string()).or_else(|| payload.downcast_ref::<String>().cloned()).unwrap_or_default();
                PANIC.with(|p| *p.borrow_mut() = Some(format!("{message} at {location}")));
            } else {
                default(info);
            }
        }));
    });
}

/// Writes a worker's case to its in-flight file before running it (target index, case index,
/// bytes); the file is emptied when the case returns, so a non-empty file after the worker died
/// is the case it died on.
fn write_inflight(file: &mut std::fs::File, target: usize, case: u64, input: &[u8]) {
    use std::os::unix::fs::FileExt;
    let mut head = [0u8; 16];
    head[..8].copy_from_slice(&(target as u64).to_le_bytes());
    head[8..].copy_from_slice(&case.to_le_bytes());
    let _ = file.write_all_at(input, 16);
    let _ = file.write_all_at(&head, 0);
    let _ = file.set_len(16 + input.len() as u64);
}

/// A run of cases: where, how many, on how many threads.
#[derive(Debug, Clone)]
pub struct CaseRange {
    /// Seed of the case streams.
    pub seed: u64,
    /// First case index.
    pub first: u64,
    /// Number of cases.
    pub cases: u64,
    /// Worker threads (each takes chunks of 256 cases in turn).
    pub threads: usize,
}

/// Cases `first .. first + cases` over `targets` (case `i` → target `i mod n`, its input from
/// `seeds` of that target) on `range.threads` worker threads of our own — not rayon's pool, so
/// that a parser's own parallel work can never run another case on the same thread — until
/// `deadline`. `inflight`: folder where each worker writes its case before running it and
/// clears it after (supervised workers); `progress(done)` is called about every 4096 cases.
pub fn run_cases(
    targets: &[Target],
    seeds: &[Vec<Vec<u8>>],
    range: &CaseRange,
    deadline: Option<Instant>,
    inflight: Option<&Path>,
    progress: &(dyn Fn(u64) + Sync),
) -> Report {
    install_panic_hook();
    // Per target: cases, accepted, nanoseconds, slowest case (ns).
    let tallies: Vec<[AtomicU64; 4]> = targets.iter().map(|_| std::array::from_fn(|_| AtomicU64::new(0))).collect();
    let findings: Mutex<Vec<Finding>> = Mutex::new(Vec::new());
    let digest = AtomicU64::new(0);
    let next_chunk = AtomicU64::new(0);
    let done = AtomicU64::new(0);
    let started = Instant::now();
    QUIET_PANICS.fetch_add(1, Ordering::SeqCst);
    const CHUNK: u64 = 256;
    let chunks = range.cases.div_ceil(CHUNK);
    let threads = range.threads.clamp(1, RUNNING.len());
    std::thread::scope(|scope| {
        for worker in 0..threads {
            let (tallies, findings, digest, next_chunk, done) = (&tallies, &findings, &digest, &next_chunk, &done);
            scope.spawn(move || {
                let mut inflight_file = inflight.and_then(|dir| std::fs::File::create(dir.join(format!("thread-{worker}.case"))).ok());
                let mut input = Vec::new();
                loop {
                    let chunk = next_chunk.fetch_add(1, Ordering::Relaxed);
                    if chunk >= chunks || deadline.is_some_and(|d| Instant::now() >= d) {
                        break;
                    }
                    let end = ((chunk + 1) * CHUNK).min(range.cases);
                    for offset in chunk * CHUNK..end {
                        let case = range.first + offset;
                        let t = (case % targets.len() as u64) as usize;
                        let mut rng = Xoshiro256PlusPlus::seed_from_u64(view_sampler::stream_seed(range.seed, case, 0xF022));
                        let pool = &seeds[t];
                        let base = rng.random_range(0..pool.len());
                        mutate(&mut rng, &pool[base], pool, &mut input);
                        if let Some(file) = inflight_file.as_mut() {
                            write_inflight(file, t, case, &input);
                        }
                        let begun = Instant::now();
                        RUNNING[worker].store(clock_ms().max(1), Ordering::Relaxed);
                        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (targets[t].run)(&input)));
                        RUNNING[worker].store(0, Ordering::Relaxed);
                        if let Some(file) = inflight_file.as_mut() {
                            let _ = file.set_len(0);
                        }
                        let ns = begun.elapsed().as_nanos() as u64;
                        tallies[t][0].fetch_add(1, Ordering::Relaxed);
                        tallies[t][2].fetch_add(ns, Ordering::Relaxed);
                        tallies[t][3].fetch_max(ns, Ordering::Relaxed);
                        let verdict = match outcome {
                            Ok(Ok(())) => {
                                tallies[t][1].fetch_add(1, Ordering::Relaxed);
                                1
                            }
                            Ok(Err(_)) => 2,
                            Err(_) => {
                                let message = PANIC.with(|p| p.borrow_mut().take()).unwrap_or_else(|| "panic".into());
                                let mut f = findings.lock().expect("findings lock");
                                let location = message.rsplit(" at ").next().unwrap_or("").to_string();
                                if !f.iter().any(|x| x.target == targets[t].name && x.message.ends_with(&location)) {
                                    f.push(Finding { target: targets[t].name.into(), case, message, input: input.clone() });
                                }
                                3
                            }
                        };
                        // Order-free digest of (case, input, verdict): equal for any thread count.
                        digest.fetch_add(view_sampler::stream_seed(fnv1a(&input), case, verdict), Ordering::Relaxed);
                    }
                    let n = done.fetch_add(end - chunk * CHUNK, Ordering::Relaxed) + (end - chunk * CHUNK);
                    if n % 4096 < CHUNK {
                        progress(n);
                    }
                }
            });
        }
    });
    QUIET_PANICS.fetch_sub(1, Ordering::SeqCst);
    Report {
        tallies: targets
            .iter()
            .zip(&tallies)
            .map(|(t, [c, a, ns, max])| {
                let tally = Tally {
                    cases: c.load(Ordering::Relaxed),
                    accepted: a.load(Ordering::Relaxed),
                    seconds: ns.load(Ordering::Relaxed) as f64 * 1e-9,
                    slowest: max.load(Ordering::Relaxed) as f64 * 1e-9,
                };
                (t.name.to_string(), tally)
            })
            .collect(),
        findings: findings.into_inner().expect("findings lock"),
        seconds: started.elapsed().as_secs_f64(),
        digest: digest.load(Ordering::Relaxed),
    }
}

/// FNV-1a of bytes (names saved inputs and feeds the run digest).
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ *b as u64).wrapping_mul(0x100_0000_01b3))
}

/// The seed inputs of `targets`.
pub fn seeds_of(targets: &[Target]) -> Vec<Vec<Vec<u8>>> {
    targets.iter().map(|t| (t.seeds)()).collect()
}

/// The targets named (all when none).
pub fn select(names: &[String]) -> Result<Vec<Target>> {
    let all = targets();
    if names.is_empty() {
        return Ok(all);
    }
    let known: Vec<&str> = all.iter().map(|t| t.name).collect();
    for n in names {
        if !known.contains(&n.as_str()) {
            bail!("unknown fuzz target {n:?}; targets: {}", known.join(", "));
        }
    }
    Ok(all.into_iter().filter(|t| names.iter().any(|n| n == t.name)).collect())
}

fn save_finding(out: &Path, target: &str, kind: &str, message: &str, input: &[u8]) -> Result<PathBuf> {
    let dir = out.join("findings");
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let path = dir.join(format!("{target}-{kind}-{:016x}.bin", fnv1a(input)));
    datasets::io::write_atomic(&path, input)?;
    datasets::io::write_atomic(&path.with_extension("txt"), format!("target {target}\n{kind}: {message}\n").as_bytes())?;
    Ok(path)
}

/// What only the binary may do: cap its heap, and end the process (a hung case cannot be
/// unwound).
pub struct ProcessHooks {
    /// Sets the allocation cap (bytes); false when the heap in use already exceeds it.
    pub memory_cap: fn(usize) -> bool,
    /// Ends the process with this code.
    pub end_process: fn(i32) -> !,
}

/// The command.
pub fn run(args: &FuzzArgs, hooks: &ProcessHooks) -> Result<bool> {
    if args.list {
        for t in targets() {
            println!("{:12} {}", t.name, t.about);
        }
        return Ok(true);
    }
    let targets = select(&args.target)?;
    if !(args.case_timeout.is_finite() && args.case_timeout > 0.0) {
        bail!("--case-timeout {}: expected seconds > 0", args.case_timeout);
    }
    if args.first_case.checked_add(args.cases).is_none() {
        bail!("--first-case {} + --cases {} overflows", args.first_case, args.cases);
    }
    if !args.replay.is_empty() {
        if targets.iter().any(|t| t.name == "checkpoint") {
            prepare_checkpoint_runs(1)?;
        }
        if !(hooks.memory_cap)(crate::memory::parse_size(&args.max_memory)? as usize) {
            bail!("--max-memory {}: below the heap already in use", args.max_memory);
        }
        return replay(args, &targets, hooks);
    }
    if args.worker {
        return worker(args, &targets, hooks);
    }
    supervise(args, &targets)
}

/// A thread that ends the process (exit 3) when a case has run longer than `timeout` seconds,
/// first writing the thread's slot to `inflight/hung`.
fn start_watchdog(timeout: f64, inflight: Option<PathBuf>, end_process: fn(i32) -> !) {
    let timeout_ms = (timeout * 1000.0) as u64;
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(std::time::Duration::from_millis(200));
            let now = clock_ms();
            let hung = RUNNING.iter().position(|r| {
                let started = r.load(Ordering::Relaxed);
                started != 0 && now.saturating_sub(started) > timeout_ms
            });
            if let Some(slot) = hung {
                eprintln!("fuzz: a case has run for more than {timeout} s");
                if let Some(dir) = &inflight {
                    let _ = std::fs::write(dir.join("hung"), slot.to_string());
                }
                end_process(3);
            }
        }
    });
}

fn replay(args: &FuzzArgs, targets: &[Target], hooks: &ProcessHooks) -> Result<bool> {
    if targets.len() != 1 {
        bail!("--replay needs one --target");
    }
    install_panic_hook();
    start_watchdog(args.case_timeout, None, hooks.end_process);
    let mut clean = true;
    for path in &args.replay {
        let input = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        QUIET_PANICS.fetch_add(1, Ordering::SeqCst);
        RUNNING[0].store(clock_ms().max(1), Ordering::Relaxed);
        let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| (targets[0].run)(&input)));
        RUNNING[0].store(0, Ordering::Relaxed);
        QUIET_PANICS.fetch_sub(1, Ordering::SeqCst);
        match outcome {
            Ok(Ok(())) => println!("{}: accepted", path.display()),
            Ok(Err(e)) => println!("{}: rejected: {e}", path.display()),
            Err(_) => {
                clean = false;
                println!("{}: PANIC: {}", path.display(), PANIC.with(|p| p.borrow_mut().take()).unwrap_or_default());
            }
        }
    }
    Ok(clean)
}

/// Runs the cases in this process; prints `progress N` lines and a final JSON report.
fn worker(args: &FuzzArgs, targets: &[Target], hooks: &ProcessHooks) -> Result<bool> {
    let inflight = args.out.join("inflight");
    std::fs::create_dir_all(&inflight).with_context(|| format!("creating {}", inflight.display()))?;
    let deadline = args.time.as_deref().map(crate::config::parse_duration).transpose()?.map(|d| Instant::now() + d);
    // Seeds and the checkpoint target's runs are built before the cap (they train a tiny run).
    let seeds = seeds_of(targets);
    let threads = rayon::current_num_threads();
    if targets.iter().any(|t| t.name == "checkpoint") {
        prepare_checkpoint_runs(threads)?;
    }
    let cap = crate::memory::parse_size(&args.max_memory)? as usize;
    if !(hooks.memory_cap)(cap) {
        bail!("--max-memory {}: below the heap already in use after building the seeds", args.max_memory);
    }
    start_watchdog(args.case_timeout, Some(inflight.clone()), hooks.end_process);
    let out = std::io::stdout();
    let range = CaseRange { seed: args.seed, first: args.first_case, cases: args.cases, threads };
    let report = run_cases(targets, &seeds, &range, deadline, Some(&inflight), &|n| {
        let mut o = out.lock();
        let _ = writeln!(o, "progress {n}");
        let _ = o.flush();
    });
    let _ = std::fs::remove_dir_all(&inflight);
    let mut saved = Vec::new();
    for f in &report.findings {
        saved.push(save_finding(&args.out, &f.target, "panic", &f.message, &f.input)?.display().to_string());
    }
    let json = serde_json::json!({
        "seconds": report.seconds,
        "tallies": report.tallies.iter().map(|(n, t)| serde_json::json!({"target": n, "cases": t.cases, "accepted": t.accepted, "seconds": t.seconds, "slowest_s": t.slowest})).collect::<Vec<_>>(),
        "findings": report.findings.iter().zip(&saved).map(|(f, p)| serde_json::json!({"target": f.target, "case": f.case, "message": f.message, "saved": p})).collect::<Vec<_>>(),
    });
    println!("report {json}");
    Ok(report.findings.is_empty())
}

/// Starts a worker, follows its progress, and names the input of a worker that died.
fn supervise(args: &FuzzArgs, targets: &[Target]) -> Result<bool> {
    let exe = std::env::current_exe().context("locating the xtask binary")?;
    let inflight = args.out.join("inflight");
    let _ = std::fs::remove_dir_all(&inflight);
    let mut command = std::process::Command::new(&exe);
    command.arg("fuzz").arg("--worker").args(["--cases", &args.cases.to_string(), "--seed", &args.seed.to_string()]);
    command.args(["--first-case", &args.first_case.to_string(), "--max-memory", &args.max_memory, "--case-timeout", &args.case_timeout.to_string()]);
    command.arg("--out").arg(&args.out);
    if let Some(t) = &args.time {
        command.args(["--time", t]);
    }
    for t in targets {
        command.args(["--target", t.name]);
    }
    eprintln!(
        "fuzz: {} cases over {} targets ({}), seed {}, allocation cap {}, case time-out {} s",
        args.cases,
        targets.len(),
        targets.iter().map(|t| t.name).collect::<Vec<_>>().join(", "),
        args.seed,
        args.max_memory,
        args.case_timeout
    );
    let mut child = command.stdout(std::process::Stdio::piped()).spawn().context("starting the fuzz worker")?;
    let bar = indicatif::ProgressBar::new(args.cases);
    bar.set_style(indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} cases, {per_sec}, {eta} left").expect("a valid template"));
    let mut report = None;
    for line in std::io::BufReader::new(child.stdout.take().expect("piped")).lines() {
        let line = line?;
        if let Some(n) = line.strip_prefix("progress ") {
            bar.set_position(n.parse().unwrap_or(0));
        } else if let Some(json) = line.strip_prefix("report ") {
            report = Some(serde_json::from_str::<serde_json::Value>(json)?);
        }
    }
    let status = child.wait()?;
    bar.finish_and_clear();
    if let Some(r) = &report {
        let seconds = r["seconds"].as_f64().unwrap_or(0.0);
        let total: u64 = r["tallies"].as_array().map_or(0, |a| a.iter().filter_map(|t| t["cases"].as_u64()).sum());
        println!("{total} cases in {seconds:.1} s ({:.0} cases/s)", total as f64 / seconds.max(1e-9));
        println!("| target | cases | accepted | rejected cleanly | µs / case | slowest case (ms) |\n|---|---|---|---|---|---|");
        for t in r["tallies"].as_array().into_iter().flatten() {
            let (c, a) = (t["cases"].as_u64().unwrap_or(0), t["accepted"].as_u64().unwrap_or(0));
            let per = t["seconds"].as_f64().unwrap_or(0.0) / c.max(1) as f64 * 1e6;
            let slowest = t["slowest_s"].as_f64().unwrap_or(0.0) * 1e3;
            println!("| {} | {c} | {a} | {} | {per:.1} | {slowest:.1} |", t["target"].as_str().unwrap_or("?"), c - a);
        }
        for f in r["findings"].as_array().into_iter().flatten() {
            println!("FINDING {} case {}: {} (input: {})", f["target"], f["case"], f["message"], f["saved"]);
        }
    }
    if let Some(r) = &report {
        return Ok(status.success() && r["findings"].as_array().is_some_and(|f| f.is_empty()));
    }
    // The worker died (allocation over the cap, a hang, an abort): the in-flight cases (only
    // the stuck thread's after a hang).
    let hung = std::fs::read_to_string(inflight.join("hung")).ok();
    let mut named = false;
    for e in std::fs::read_dir(&inflight).into_iter().flatten().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(slot) = name.strip_prefix("thread-").and_then(|n| n.strip_suffix(".case")) else { continue };
        if hung.as_deref().is_some_and(|h| h.trim() != slot) {
            continue;
        }
        let bytes = std::fs::read(e.path())?;
        if bytes.len() < 16 {
            continue;
        }
        let t = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
        let case = u64::from_le_bytes(bytes[8..16].try_into().expect("8 bytes"));
        let Some(target) = targets.get(t) else { continue };
        let kind = if hung.is_some() { "hang" } else { "died" };
        let path = save_finding(&args.out, target.name, kind, &format!("case {case}: worker exit {status}"), &bytes[16..])?;
        // Confirm in a fresh process: does this input alone kill it?
        let replay = std::process::Command::new(&exe)
            .args(["fuzz", "--target", target.name, "--max-memory", &args.max_memory, "--case-timeout", &args.case_timeout.to_string(), "--replay"])
            .arg(&path)
            .output()?;
        let verdict = if replay.status.success() { "does not reproduce alone" } else { "reproduces" };
        println!("FINDING {} case {case}: worker {kind} ({status}); in-flight input {} — replayed: {verdict}", target.name, path.display());
        named = true;
    }
    if !named {
        println!("the worker died ({status}) with no case in flight");
    }
    Ok(false)
}
