//! The targets: valid seed inputs made in memory for every parser of user input, and the call
//! that feeds one mutated input to its parser.

use super::*;

/// Image size the fuzzed camera files claim for their images.
pub(super) const IMAGE_SIZE: (u32, u32) = (64, 48);

/// `camera_from_world` of fuzz camera `i`: on a circle of radius 3 around the origin, looking at it.
pub(super) fn seed_camera(i: usize) -> (DMat3, DVec3) {
    let angle = 0.4 * i as f64 - 0.6;
    (DMat3::from_rotation_y(angle), DVec3::new(0.0, 0.0, 3.0))
}

pub(super) fn seeds_ply() -> Vec<Vec<u8>> {
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

pub(super) fn seeds_npy() -> Vec<Vec<u8>> {
    vec![npy_bytes(&[4, 4], &[1.0f64; 16]), npy_bytes(&[3], &[1.5f32, -2.0, 3.25]), npy_bytes(&[2, 1, 2], &[0.0f64; 4])]
}

pub(super) fn npz_of(entries: &[(String, Vec<u8>)]) -> std::result::Result<Vec<u8>, String> {
    write_npz(Cursor::new(Vec::new()), entries).map(Cursor::into_inner).map_err(|e| format!("not an archive: {e}"))
}

/// IDR arrays of three cameras: `world_mat_i` = K [R | t] and `scale_mat_i`.
pub(super) fn idr_arrays() -> Vec<(String, Vec<u8>)> {
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

pub(super) fn seeds_npz() -> Vec<Vec<u8>> {
    [npz_of(&idr_arrays()[..2]), npz_of(&[("a".into(), npy_bytes(&[2], &[1.0f32, 2.0]))])].map(|r| r.expect("distinct names")).to_vec()
}

pub(super) fn seeds_idr() -> Vec<Vec<u8>> {
    let arrays = idr_arrays();
    // Name and bytes of each array, as alternating files.
    vec![join_files(&arrays.iter().flat_map(|(n, b)| [n.as_bytes().to_vec(), b.clone()]).collect::<Vec<_>>())]
}

pub(super) fn seeds_transforms() -> Vec<Vec<u8>> {
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
pub(super) fn colmap_seed(binary: bool) -> [Vec<u8>; 3] {
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

pub(super) fn seeds_colmap_binary() -> Vec<Vec<u8>> {
    vec![join_files(&colmap_seed(true))]
}

pub(super) fn seeds_colmap_text() -> Vec<Vec<u8>> {
    vec![join_files(&colmap_seed(false))]
}

pub(super) fn seeds_image() -> Vec<Vec<u8>> {
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

pub(super) fn seeds_config() -> Vec<Vec<u8>> {
    vec![trainer::config::TrainConfig::default().to_toml().into_bytes()]
}

pub(super) fn seeds_overrides() -> Vec<Vec<u8>> {
    vec![
        b"steps=7\nguide.scene.partition=1\nsampler=uniform\nguide.extra=log\nmodel.preset=neus-cpu\n".to_vec(),
        b"time_budget_s=30\nrender.rays=64\noutput.mesh_formats=[\"obj\", \"glb\"]\nmodel.background=[0.1, 0.2, 0.3]\n".to_vec(),
    ]
}

/// The tiny run the checkpoint target restores into (a 40 × 30 built-in scene, neus-cpu).
pub(super) fn tiny_trainer() -> Result<trainer::trainer::Trainer> {
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
    let config = trainer::config::TrainConfig::load(None, &overrides)?;
    let data = trainer::data::SceneData::load(&config, None)?;
    let mut trainer = trainer::trainer::Trainer::new(config, data)?;
    trainer.step()?;
    Ok(trainer)
}

/// Tiny runs the checkpoint target restores into, one per worker (taken and put back per case).
pub(super) static TRAINERS: Mutex<Vec<trainer::trainer::Trainer>> = Mutex::new(Vec::new());

/// Builds `n` tiny runs for the checkpoint target (before the allocation cap is set).
pub fn prepare_checkpoint_runs(n: usize) -> Result<()> {
    let mut pool = TRAINERS.lock().expect("trainer pool");
    while pool.len() < n {
        pool.push(tiny_trainer().context("building the checkpoint target's tiny run")?);
    }
    Ok(())
}

pub(super) fn seeds_checkpoint() -> Vec<Vec<u8>> {
    let trainer = tiny_trainer().expect("the tiny built-in run builds");
    let mut bytes = Vec::new();
    trainer.write_checkpoint(&mut bytes).expect("writing to memory");
    vec![bytes]
}

pub(super) fn seeds_obj() -> Vec<Vec<u8>> {
    let (positions, faces) = ([Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z], [[0, 1, 2], [0, 2, 3], [1, 2, 3]]);
    let quads = "mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl a\nf 1/1 2/2 3/3 4/4\nf -1 -2 -3\n";
    vec![datasets::io::mesh_bytes(MeshFormat::Obj, &positions, &faces, None), quads.as_bytes().to_vec()]
}

pub(super) fn run_obj(b: &[u8]) -> Verdict {
    verdict(datasets::parse::obj(b, Path::new("mesh.obj")))
}

pub(super) fn seeds_gltf() -> Vec<Vec<u8>> {
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
pub(super) fn base64(bytes: &[u8]) -> String {
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

pub(super) fn run_gltf(b: &[u8]) -> Verdict {
    verdict(datasets::parse::gltf(b, Path::new("mesh.gltf")))
}

pub(super) fn run_ply(b: &[u8]) -> Verdict {
    verdict(datasets::parse::ply(b, Path::new("mesh.ply")))
}

pub(super) fn run_npy(b: &[u8]) -> Verdict {
    verdict(datasets::parse::npy(b, Path::new("array.npy")))
}

pub(super) fn run_npz(b: &[u8]) -> Verdict {
    verdict(datasets::parse::npz(b, Path::new("cameras.npz")))
}

pub(super) fn run_idr(b: &[u8]) -> Verdict {
    let files = split_files(b);
    let entries: Vec<(String, Vec<u8>)> =
        files.chunks(2).filter(|p| p.len() == 2).map(|p| (String::from_utf8_lossy(p[0]).into_owned(), p[1].to_vec())).collect();
    // Mutated names may repeat: the zip writer refuses, and so does the case.
    let archive = npz_of(&entries)?;
    let options = LoadOptions { downscale: 1 + (b.len() % 2) as u32, ..LoadOptions::default() };
    verdict(datasets::parse::idr_cameras(&archive, Path::new("scene/cameras_sphere.npz"), IMAGE_SIZE, b.len().is_multiple_of(3), &options))
}

pub(super) fn run_transforms(b: &[u8]) -> Verdict {
    let ngp = b.windows(4).any(|w| w == b"aabb" || w == b"sphe");
    let format = if ngp { Format::InstantNgp } else { Format::NerfSynthetic };
    verdict(datasets::parse::transforms_cameras(b, Path::new("scene/transforms.json"), format, IMAGE_SIZE, &LoadOptions::default()))
}

pub(super) fn run_colmap(b: &[u8], encoding: ModelEncoding) -> Verdict {
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

pub(super) fn run_colmap_binary(b: &[u8]) -> Verdict {
    run_colmap(b, ModelEncoding::Binary)
}

pub(super) fn run_colmap_text(b: &[u8]) -> Verdict {
    run_colmap(b, ModelEncoding::Text)
}

pub(super) fn run_image(b: &[u8]) -> Verdict {
    let downscale = 1 + (b.len() % 2) as u32;
    let image = verdict(datasets::parse::image(b, Path::new("image/000.png"), downscale, [1.0; 3]));
    let mask = verdict(datasets::parse::mask(b, Path::new("mask/000.png"), downscale));
    image.and(mask)
}

pub(super) fn run_config(b: &[u8]) -> Verdict {
    let text = std::str::from_utf8(b).map_err(|e| e.to_string())?;
    verdict(trainer::config::TrainConfig::from_toml(text))
}

pub(super) fn run_overrides(b: &[u8]) -> Verdict {
    let lines: Vec<String> = String::from_utf8_lossy(b).lines().map(String::from).collect();
    verdict(trainer::config::TrainConfig::load(None, &lines))
}

pub(super) fn run_checkpoint(b: &[u8]) -> Verdict {
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
