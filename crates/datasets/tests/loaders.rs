//! Loader tests: golden round trips through every format, and one test per kind of bad input
//! (each checks that the message names the file at fault).

use camera_geom::{PinholeCamera, PixelCenters};
use datasets::golden::{self, GeometrySource, GoldenScene, GoldenSpec, rig::Rig};
use datasets::npy::{npy_bytes, write_npz};
use datasets::{DatasetError, LoadOptions, load_scene, read_cameras};
use glam::{DVec2, DVec3};
use std::path::{Path, PathBuf};

fn small_spec(geometry: GeometrySource) -> GoldenSpec {
    let mut spec = GoldenSpec::new(geometry);
    spec.rig.count = 4;
    spec.rig.width = 48;
    spec.rig.height = 36;
    spec.rig.rig = Rig::Random;
    spec.surface_points = 2000;
    spec
}

fn composite() -> GoldenScene {
    golden::generate(&small_spec(GeometrySource::Shape(prob_grid::ShapeName::Composite))).unwrap()
}

fn written_composite() -> (tempfile::TempDir, GoldenScene) {
    let dir = tempfile::tempdir().unwrap();
    let g = composite();
    golden::write_idr(&g, dir.path()).unwrap();
    (dir, g)
}

fn assert_same_camera(a: &PinholeCamera, b: &PinholeCamera, tol: f64) {
    for p in [DVec3::new(0.1, -0.2, 0.3), DVec3::new(-0.5, 0.4, 0.0), DVec3::ZERO] {
        let (pa, pb) = (a.pixel_space_from_world(p), b.pixel_space_from_world(p));
        assert!((pa - pb).length() < tol, "{pa} vs {pb}");
    }
    assert_eq!((a.width, a.height), (b.width, b.height));
}

fn assert_names(err: DatasetError, needle: &Path) {
    let msg = err.to_string();
    assert!(msg.contains(&needle.display().to_string()), "message {msg:?} does not name {}", needle.display());
}

#[test]
fn idr_golden_round_trip_is_exact() {
    let (dir, g) = written_composite();
    let scene = load_scene(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(scene.views.len(), 4);
    for (a, b) in scene.views.iter().zip(&g.scene.views) {
        assert_same_camera(&a.camera, &b.camera, 1e-9);
        assert_eq!(a.image, b.image);
        assert_eq!(a.mask, b.mask);
    }
}

fn write_cube_obj(dir: &Path) -> PathBuf {
    let path = dir.join("cube.obj");
    let mut s = String::new();
    for i in 0..8 {
        // A 2×4×6 box centred at (10, 20, 30): normalisation must scale and shift it.
        let x = 10.0 + if i & 1 == 1 { 1.0 } else { -1.0 };
        let y = 20.0 + if i & 2 == 2 { 2.0 } else { -2.0 };
        let z = 30.0 + if i & 4 == 4 { 3.0 } else { -3.0 };
        s += &format!("v {x} {y} {z}\n");
    }
    for q in [[1, 3, 4, 2], [5, 6, 8, 7], [1, 2, 6, 5], [3, 7, 8, 4], [1, 5, 7, 3], [2, 4, 8, 6]] {
        s += &format!("f {} {} {}\nf {} {} {}\n", q[0], q[1], q[2], q[0], q[2], q[3]);
    }
    std::fs::write(&path, s).unwrap();
    path
}

#[test]
fn mesh_golden_keeps_world_units_through_scale_mat() {
    let dir = tempfile::tempdir().unwrap();
    let obj = write_cube_obj(dir.path());
    let g = golden::generate(&small_spec(GeometrySource::Mesh(obj))).unwrap();
    let out = dir.path().join("scene");
    golden::write_idr(&g, &out).unwrap();
    let scene = load_scene(&out, &LoadOptions::default()).unwrap();
    // Surface points in world units lie on the original box.
    for p in g.surface_points.iter().take(200) {
        let w = scene.point_in_input_world(*p) - DVec3::new(10.0, 20.0, 30.0);
        let d = (w.abs() - DVec3::new(1.0, 2.0, 3.0)).max_element();
        assert!(d.abs() < 1e-4, "{w}");
    }
    for (a, b) in scene.views.iter().zip(&g.scene.views) {
        assert_same_camera(&a.camera, &b.camera, 1e-6);
        assert!(a.mask.as_ref().unwrap().count() > 20);
    }
    assert!(out.join("gt_mesh.ply").is_file() && out.join("gt_points.ply").is_file());
}

#[test]
fn gltf_meshes_load_like_obj() {
    // A single triangle as an embedded glTF (base64 buffer).
    let dir = tempfile::tempdir().unwrap();
    let mut buf = Vec::new();
    for v in [0.0f32, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    let b64 = base64_encode(&buf);
    let gltf = format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],"nodes":[{{"mesh":0,"translation":[0,0,5]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}}}}]}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}}],
        "bufferViews":[{{"buffer":0,"byteLength":36}}],
        "buffers":[{{"byteLength":36,"uri":"data:application/octet-stream;base64,{b64}"}}]}}"#
    );
    let path = dir.path().join("tri.gltf");
    std::fs::write(&path, gltf).unwrap();
    let m = golden::mesh_io::load_mesh(&path).unwrap();
    assert_eq!(m.mesh.triangles.len(), 1);
    assert_eq!(m.mesh.positions[1], glam::Vec3::new(1.0, 0.0, 5.0), "node translation applied");
    // A node that is its own child: an error naming the node, not an endless walk.
    let cyclic = std::fs::read_to_string(&path).unwrap().replace(r#""translation":[0,0,5]"#, r#""translation":[0,0,5],"children":[0]"#);
    let path = dir.path().join("cycle.gltf");
    std::fs::write(&path, cyclic).unwrap();
    let err = golden::mesh_io::load_mesh(&path).unwrap_err().to_string();
    assert!(err.contains("cycle.gltf") && err.contains("node 0 is reached twice"), "{err}");
}

fn base64_encode(bytes: &[u8]) -> String {
    const T: &[u8] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n = (c[0] as u32) << 16 | (*c.get(1).unwrap_or(&0) as u32) << 8 | *c.get(2).unwrap_or(&0) as u32;
        for k in 0..4 {
            if k <= c.len() {
                s.push(T[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// Writes a golden scene as NeRF-synthetic (RGBA, OpenGL camera-to-world, half-integer centres).
fn write_as_transforms(g: &GoldenScene, dir: &Path, file: &str, extra: serde_json::Value) {
    std::fs::create_dir_all(dir.join("train")).unwrap();
    let mut frames = Vec::new();
    for (i, v) in g.scene.views.iter().enumerate() {
        let (w, h) = (v.camera.width, v.camera.height);
        let mut rgba = Vec::new();
        for row in 0..h {
            for col in 0..w {
                let k = 3 * (row * w + col) as usize;
                let fg = v.mask.as_ref().unwrap().get(col, row);
                rgba.extend_from_slice(&v.image.data[k..k + 3]);
                rgba.push(if fg { 255 } else { 0 });
            }
        }
        image::save_buffer(dir.join(format!("train/r_{i}.png")), &rgba, w, h, image::ExtendedColorType::Rgba8).unwrap();
        let world_from_camera = v.camera.world_from_camera();
        let r = world_from_camera.rotation;
        let t = world_from_camera.translation * 1.5; // NeRF-synthetic default bound radius 1.5
        // OpenCV → OpenGL: negate the camera's y and z axes.
        let m: Vec<Vec<f64>> =
            (0..4).map(|i| if i < 3 { vec![r.col(0)[i], -r.col(1)[i], -r.col(2)[i], t[i]] } else { vec![0.0, 0.0, 0.0, 1.0] }).collect();
        frames.push(serde_json::json!({"file_path": format!("./train/r_{i}"), "transform_matrix": m}));
    }
    let k = g.scene.views[0].camera.intrinsics;
    let w = g.scene.views[0].camera.width as f64;
    let mut json = serde_json::json!({
        // Half-integer centres: the IDR principal point shifts by +0.5.
        "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx + 0.5, "cy": k.cy + 0.5,
        "camera_angle_x": 2.0 * (0.5 * w / k.fx).atan(),
        "frames": frames,
    });
    for (key, value) in extra.as_object().unwrap() {
        json[key] = value.clone();
    }
    std::fs::write(dir.join(file), serde_json::to_string(&json).unwrap()).unwrap();
}

#[test]
fn nerf_synthetic_round_trip_converts_opengl_poses_and_alpha() {
    let g = composite();
    let dir = tempfile::tempdir().unwrap();
    write_as_transforms(&g, dir.path(), "transforms_train.json", serde_json::json!({}));
    let scene = load_scene(dir.path(), &LoadOptions { background: [0.0; 3], ..LoadOptions::default() }).unwrap();
    assert_eq!(scene.views.len(), 4);
    for (a, b) in scene.views.iter().zip(&g.scene.views) {
        assert_eq!(a.camera.pixel_centers, PixelCenters::HalfInteger);
        // Same rays through the same pixels: the centre of pixel (3, 5) in both conventions.
        let (ra, rb) = (a.camera.ray_through_pixel_index(3, 5), b.camera.ray_through_pixel_index(3, 5));
        assert!((ra.direction - rb.direction).length() < 1e-9);
        assert!((ra.origin - rb.origin).length() < 1e-9);
        assert_eq!(a.mask, b.mask, "mask from alpha");
        // Background composited over black = the black-background rendering.
        let m = b.mask.as_ref().unwrap();
        for row in 0..b.camera.height {
            for col in 0..b.camera.width {
                let expect = if m.get(col, row) { b.image.get_f32(col, row) } else { [0.0; 3] };
                assert_eq!(a.image.get_f32(col, row), expect);
            }
        }
    }
    assert!((scene.point_in_input_world(DVec3::X) - DVec3::new(1.5, 0.0, 0.0)).length() < 1e-12);
}

#[test]
fn instant_ngp_uses_sphere_bound_and_per_frame_overrides() {
    let g = composite();
    let dir = tempfile::tempdir().unwrap();
    write_as_transforms(&g, dir.path(), "transforms.json", serde_json::json!({"sphere_center": [0, 0, 0], "sphere_radius": 1.5}));
    let a = read_cameras(dir.path(), &LoadOptions::default()).unwrap();
    for (a, b) in a.records.iter().zip(&g.scene.views) {
        assert_same_camera(
            &a.camera,
            &{
                let mut c = b.camera;
                c.pixel_centers = PixelCenters::HalfInteger;
                c.intrinsics.cx += 0.5;
                c.intrinsics.cy += 0.5;
                c
            },
            1e-9,
        );
    }
    // A per-frame focal length overrides the file's.
    let path = dir.path().join("transforms.json");
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    json["frames"][1]["fl_x"] = serde_json::json!(123.0);
    std::fs::write(&path, json.to_string()).unwrap();
    let a = read_cameras(dir.path(), &LoadOptions::default()).unwrap();
    assert_eq!(a.records[1].camera.intrinsics.fx, 123.0);
    assert_ne!(a.records[0].camera.intrinsics.fx, 123.0);
}

#[test]
fn downscaled_masks_agree_with_rendering_at_the_downscaled_camera() {
    let mut spec = small_spec(GeometrySource::Shape(prob_grid::ShapeName::Torus));
    spec.rig.width = 96;
    spec.rig.height = 72;
    let g = golden::generate(&spec).unwrap();
    let dir = tempfile::tempdir().unwrap();
    golden::write_idr(&g, dir.path()).unwrap();
    let scene = load_scene(dir.path(), &LoadOptions { downscale: 4, ..LoadOptions::default() }).unwrap();
    let geometry = &g.geometry;
    for v in &scene.views {
        assert_eq!((v.camera.width, v.camera.height), (24, 18));
        let r = golden::render::render_view(geometry, &v.camera, golden::Backdrop::None);
        let m = v.mask.as_ref().unwrap();
        let mut agree = 0;
        for row in 0..18 {
            for col in 0..24 {
                agree += (m.get(col, row) == r.mask.get(col, row)) as usize;
            }
        }
        // Only silhouette pixels may differ (area average vs point sample).
        assert!(agree as f64 / (24.0 * 18.0) > 0.93, "{agree}/432");
    }
    // The half-pixel shift: a point's pixel coordinate scales as (u − 1.5)/4 for integer centres.
    let full = read_cameras(dir.path(), &LoadOptions::default()).unwrap();
    let (a, b) = (&full.records[0].camera, &scene.views[0].camera);
    let p = DVec3::new(0.1, 0.2, -0.1);
    let (pa, pb) = (a.pixel_space_from_world(p).truncate(), b.pixel_space_from_world(p).truncate());
    assert!((pb - (pa - DVec2::splat(1.5)) / 4.0).length() < 1e-9);
}

// ----- bad input: one test per case, each checking the message names the file ------------------

#[test]
fn unknown_layout_names_the_folder() {
    let dir = tempfile::tempdir().unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::UnknownLayout { .. }));
    assert_names(err, dir.path());
}

#[test]
fn missing_image_names_the_camera_and_folder() {
    let (dir, _) = written_composite();
    std::fs::remove_file(dir.path().join("image/002.png")).unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::MissingImage { camera: 2, .. }), "{err}");
    assert_names(err, &dir.path().join("image"));
}

#[test]
fn extra_images_are_a_count_mismatch() {
    let (dir, _) = written_composite();
    std::fs::copy(dir.path().join("image/000.png"), dir.path().join("image/004.png")).unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::CountMismatch { cameras: 4, found: 5, .. }), "{err}");
    assert_names(err, &dir.path().join("image"));
}

#[test]
fn mask_of_another_size_is_rejected() {
    let (dir, _) = written_composite();
    let path = dir.path().join("mask/001.png");
    image::save_buffer(&path, &[0u8; 20 * 10], 20, 10, image::ExtendedColorType::L8).unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::SizeMismatch { .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn images_of_different_sizes_are_rejected() {
    let (dir, _) = written_composite();
    let path = dir.path().join("image/003.png");
    image::save_buffer(&path, &[0u8; 3 * 20 * 10], 20, 10, image::ExtendedColorType::Rgb8).unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::SizeMismatch { .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn corrupt_png_is_rejected() {
    let (dir, _) = written_composite();
    let path = dir.path().join("image/001.png");
    std::fs::write(&path, b"\x89PNG\r\n\x1a\nthis is not a png").unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Corrupt { .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn corrupt_npz_is_rejected() {
    let (dir, _) = written_composite();
    let path = dir.path().join("cameras_sphere.npz");
    std::fs::write(&path, b"PK\x03\x04 garbage").unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Corrupt { .. }), "{err}");
    assert_names(err, &path);
}

fn rewrite_npz(dir: &Path, edit: impl Fn(usize, &mut [f64; 16])) {
    let path = dir.join("cameras_sphere.npz");
    let mut npz = datasets::npy::Npz::open(&path).unwrap();
    let mut entries = Vec::new();
    for i in 0..4 {
        let mut w: [f64; 16] = npz.get(&format!("world_mat_{i}")).unwrap().unwrap().data.try_into().unwrap();
        edit(i, &mut w);
        let s = npz.get(&format!("scale_mat_{i}")).unwrap().unwrap().data;
        entries.push((format!("world_mat_{i}"), npy_bytes(&[4, 4], &w)));
        entries.push((format!("scale_mat_{i}"), npy_bytes(&[4, 4], &s)));
        // Keys a loader must ignore.
        entries.push((format!("camera_mat_{i}"), npy_bytes(&[4, 4], &[f64::NAN; 16])));
    }
    drop(npz);
    write_npz(std::fs::File::create(&path).unwrap(), &entries).unwrap();
}

#[test]
fn other_npz_keys_are_ignored() {
    let (dir, g) = written_composite();
    rewrite_npz(dir.path(), |_, _| {});
    let cams = read_cameras(dir.path(), &LoadOptions::default()).unwrap();
    assert_same_camera(&cams.records[0].camera, &g.scene.views[0].camera, 1e-9);
}

#[test]
fn a_gap_in_the_camera_numbering_names_the_missing_camera() {
    let (dir, _) = written_composite();
    let path = dir.path().join("cameras_sphere.npz");
    let mut npz = datasets::npy::Npz::open(&path).unwrap();
    let mut entries = Vec::new();
    for i in [0, 1, 3] {
        for key in [format!("world_mat_{i}"), format!("scale_mat_{i}")] {
            let m: [f64; 16] = npz.get(&key).unwrap().unwrap().data.try_into().unwrap();
            entries.push((key, npy_bytes(&[4, 4], &m)));
        }
    }
    drop(npz);
    write_npz(std::fs::File::create(&path).unwrap(), &entries).unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("world_mat_2"), "{err}");
    assert_names(err, &path);
}

#[test]
fn nan_in_world_mat_is_rejected() {
    let (dir, _) = written_composite();
    rewrite_npz(dir.path(), |i, w| {
        if i == 1 {
            w[5] = f64::NAN
        }
    });
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("world_mat_1") && err.to_string().contains("non-finite"), "{err}");
    assert_names(err, &dir.path().join("cameras_sphere.npz"));
}

#[test]
fn infinite_world_mat_is_rejected() {
    let (dir, _) = written_composite();
    rewrite_npz(dir.path(), |i, w| {
        if i == 3 {
            w[3] = f64::INFINITY
        }
    });
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("world_mat_3"), "{err}");
    assert_names(err, &dir.path().join("cameras_sphere.npz"));
}

#[test]
fn singular_projection_is_rejected() {
    let (dir, _) = written_composite();
    // Second row = first row: rank-deficient M.
    rewrite_npz(dir.path(), |i, w| {
        if i == 2 {
            for c in 0..4 {
                w[4 + c] = w[c];
            }
        }
    });
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Camera { source: camera_geom::CameraError::SingularProjection { .. }, .. }), "{err}");
    assert_names(err, &dir.path().join("cameras_sphere.npz"));
}

fn transforms_dir() -> (tempfile::TempDir, PathBuf) {
    let g = composite();
    let dir = tempfile::tempdir().unwrap();
    write_as_transforms(&g, dir.path(), "transforms.json", serde_json::json!({"sphere_center": [0, 0, 0], "sphere_radius": 1.5}));
    let path = dir.path().join("transforms.json");
    (dir, path)
}

fn edit_json(path: &Path, edit: impl Fn(&mut serde_json::Value)) {
    let mut json: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    edit(&mut json);
    std::fs::write(path, json.to_string()).unwrap();
}

#[test]
fn corrupt_json_is_rejected() {
    let (dir, path) = transforms_dir();
    std::fs::write(&path, "{\"frames\": [").unwrap();
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Corrupt { kind: "JSON", .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn pose_that_is_not_a_rotation_is_rejected() {
    let (dir, path) = transforms_dir();
    edit_json(&path, |j| j["frames"][2]["transform_matrix"][0][1] = serde_json::json!(0.5));
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Camera { source: camera_geom::CameraError::NotARotation { .. }, .. }), "{err}");
    assert!(err.to_string().contains("frames[2]"));
    assert_names(err, &path);
}

#[test]
fn zero_focal_length_is_rejected() {
    let (dir, path) = transforms_dir();
    edit_json(&path, |j| j["fl_x"] = serde_json::json!(0.0));
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Camera { source: camera_geom::CameraError::BadFocal { .. }, .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn lens_distortion_is_unsupported_not_ignored() {
    let (dir, path) = transforms_dir();
    edit_json(&path, |j| j["k1"] = serde_json::json!(0.01));
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Unsupported { .. }) && err.to_string().contains("undistort"), "{err}");
    assert_names(err, &path);
}

#[test]
fn a_fractional_image_width_names_the_key_not_an_equal_pair() {
    let (dir, path) = transforms_dir();
    edit_json(&path, |j| j["w"] = serde_json::json!(32.5));
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("32.5 is not a whole number of pixels") && err.to_string().contains(".w"), "{err}");
    assert_names(err, &path);
}

#[test]
fn a_file_path_out_of_the_dataset_is_an_error_naming_the_entry() {
    let (dir, path) = transforms_dir();
    // A copy of an image outside the dataset's folder, named with `..` and absolutely.
    let outside = tempfile::tempdir().unwrap();
    std::fs::copy(dir.path().join("train/r_0.png"), outside.path().join("x.png")).unwrap();
    let relative = format!("../{}/x", outside.path().file_name().unwrap().to_string_lossy());
    for (name, why) in [(relative.as_str(), "climbs out"), (outside.path().join("x").to_str().unwrap(), "absolute")] {
        edit_json(&path, |j| j["frames"][1]["file_path"] = serde_json::json!(name));
        let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
        assert!(err.to_string().contains(why) && err.to_string().contains("frames[1].file_path"), "{err}");
        assert_names(err, &path);
    }
}

#[test]
fn missing_bound_for_instant_ngp_is_an_error() {
    let (dir, path) = transforms_dir();
    edit_json(&path, |j| {
        j.as_object_mut().unwrap().remove("sphere_center");
    });
    let err = load_scene(dir.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::MissingKey { .. }), "{err}");
    assert_names(err, &path);
}

#[test]
fn corrupt_mesh_is_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bad.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 0 0\nf 1 2 9\n").unwrap();
    let err = golden::mesh_io::load_mesh(&path).unwrap_err();
    assert_names(err, &path);
}

// ----- real data (../shared/data); skipped with a message when absent -----------------------

fn shared_data(name: &str) -> Option<PathBuf> {
    let root = std::env::var_os("PSNEUS_SHARED_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data"));
    let p = root.join(name);
    if p.is_dir() {
        Some(p)
    } else {
        eprintln!("skipped: {} not found (set PSNEUS_SHARED_DATA to the shared data folder)", p.display());
        None
    }
}

#[test]
fn dtu_scan24_matches_opencv_decomposition() {
    let Some(dir) = shared_data("dtu_scan24") else { return };
    let cams = read_cameras(&dir, &LoadOptions::default()).unwrap();
    let fixture: serde_json::Value = serde_json::from_str(include_str!("fixtures/dtu_scan24_opencv.json")).unwrap();
    let reference = fixture["cameras"].as_array().unwrap();
    assert_eq!(cams.records.len(), 49);
    assert_eq!(reference.len(), 49);
    let rel = |a: f64, b: f64, scale: f64| (a - b).abs() / scale;
    for (record, r) in cams.records.iter().zip(reference) {
        let c = &record.camera;
        let k = &r["K"];
        let kk = c.intrinsics;
        let get = |m: &serde_json::Value, i: usize, j: usize| m[i][j].as_f64().unwrap();
        for (ours, theirs) in [(kk.fx, get(k, 0, 0)), (kk.fy, get(k, 1, 1)), (kk.cx, get(k, 0, 2)), (kk.cy, get(k, 1, 2)), (kk.skew, get(k, 0, 1))] {
            assert!(rel(ours, theirs, get(k, 0, 0)) < 1e-6, "{} K: {ours} vs {theirs}", record.name);
        }
        let wfc = c.world_from_camera();
        let m = &r["world_from_camera"];
        for i in 0..3 {
            for j in 0..3 {
                assert!((wfc.rotation.col(j)[i] - get(m, i, j)).abs() < 1e-6, "{} R", record.name);
            }
            assert!(rel(wfc.translation[i], get(m, i, 3), 3.0) < 1e-6, "{} centre", record.name);
        }
        let d = c.center_in_world().length();
        assert!((2.76..=2.98).contains(&d), "{d}");
    }
    let fx0 = cams.records[0].camera.intrinsics.fx;
    assert!((fx0 - 2892.3).abs() < 0.1 && (cams.records[0].camera.intrinsics.cx - 823.2).abs() < 0.1);
}

#[test]
fn dtu_scan24_loads_49_views_with_masks_inside_the_unit_sphere() {
    let Some(dir) = shared_data("dtu_scan24") else { return };
    // Downscaled by 4 to keep the test quick; full resolution is measured in BENCHMARKS.md.
    let scene = load_scene(&dir, &LoadOptions { downscale: 4, ..LoadOptions::default() }).unwrap();
    assert_eq!(scene.views.len(), 49);
    assert!(scene.views.iter().all(|v| v.mask.is_some() && (v.camera.width, v.camera.height) == (400, 300)));
    // Every foreground pixel's ray meets the unit sphere (checked on the README of the data).
    for v in scene.views.iter().step_by(6) {
        let m = v.mask.as_ref().unwrap();
        for row in 0..300 {
            for col in 0..400 {
                if m.get(col, row) {
                    let ray = v.camera.ray_through_pixel_index(col, row);
                    assert!(camera_geom::ray_sphere(&ray, DVec3::ZERO, 1.0).is_some());
                }
            }
        }
    }
    // scale_mat_0 of scan 24: isotropic 231.07 with translation (−28.46, −13.19, 641.49).
    let o = scene.point_in_input_world(DVec3::ZERO);
    assert!((o - DVec3::new(-28.46, -13.19, 641.49)).length() < 0.01, "{o}");
}

#[test]
fn lego_loads_100_views_with_alpha_masks() {
    let Some(dir) = shared_data("nerf_synthetic_lego") else { return };
    let scene = load_scene(&dir, &LoadOptions { downscale: 4, ..LoadOptions::default() }).unwrap();
    assert_eq!(scene.views.len(), 100);
    let fg: usize = scene.views.iter().map(|v| v.mask.as_ref().unwrap().count()).sum();
    let frac = fg as f64 / (100.0 * 200.0 * 200.0);
    // Measured with OpenCV at full resolution: 30.4% of pixels have alpha > 127.
    assert!((0.27..0.34).contains(&frac), "foreground fraction {frac}");
    // Cameras look at the object: the origin projects inside every image.
    for v in &scene.views {
        let p = v.camera.pixel_space_from_world(DVec3::ZERO);
        assert!(p.z > 0.0 && (0.0..200.0).contains(&p.x) && (0.0..200.0).contains(&p.y));
    }
}
