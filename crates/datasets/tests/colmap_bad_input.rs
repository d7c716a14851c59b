//! COLMAP bad input: one test per case (a missing image, an unsupported camera model, duplicate
//! names, no 3D points, binary files cut short, malformed text lines), each error naming the file
//! at fault — never a panic, never a huge allocation.

mod common;

use common::{assert_names, blank_workspace, fixture};
use datasets::colmap::{ColmapModel, ModelEncoding};
use datasets::{DatasetError, LoadOptions, read_cameras};
use glam::DVec3;
#[test]
fn image_missing_on_disk_is_named() {
    let ws = blank_workspace(&fixture("golden", ModelEncoding::Binary));
    let missing = ws.path().join("images/007.png");
    std::fs::remove_file(&missing).unwrap();
    let err = read_cameras(ws.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::NotFound { .. }) && err.to_string().contains("images.bin"), "{err}");
    assert_names(&err, &missing);
}

#[test]
fn unsupported_camera_model_is_named() {
    // Text: FULL_OPENCV by name.
    let ws = blank_workspace(&fixture("golden", ModelEncoding::Text));
    let cameras = ws.path().join("sparse/0/cameras.txt");
    std::fs::write(&cameras, "1 FULL_OPENCV 400 300 500 500 200 150 0 0 0 0 0 0 0 0\n").unwrap();
    let err = read_cameras(ws.path(), &LoadOptions::default()).unwrap_err();
    assert!(matches!(err, DatasetError::Unsupported { .. }) && err.to_string().contains("FULL_OPENCV"), "{err}");
    assert_names(&err, &cameras);
    // Binary: the model id (bytes 12..16 of the first camera) set to 5, OPENCV_FISHEYE.
    let ws = blank_workspace(&fixture("golden", ModelEncoding::Binary));
    let cameras = ws.path().join("sparse/0/cameras.bin");
    let mut bytes = std::fs::read(&cameras).unwrap();
    bytes[12..16].copy_from_slice(&5i32.to_le_bytes());
    std::fs::write(&cameras, bytes).unwrap();
    let err = read_cameras(ws.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("OPENCV_FISHEYE"), "{err}");
    assert_names(&err, &cameras);
}

#[test]
fn duplicate_image_names_are_rejected() {
    let ws = blank_workspace(&fixture("golden", ModelEncoding::Text));
    let images = ws.path().join("sparse/0/images.txt");
    let text = std::fs::read_to_string(&images).unwrap();
    let edited = text.replacen(" 001.png", " 000.png", 1);
    assert_ne!(text, edited);
    std::fs::write(&images, edited).unwrap();
    let err = read_cameras(ws.path(), &LoadOptions::default()).unwrap_err();
    assert!(err.to_string().contains("duplicate name \"000.png\""), "{err}");
    assert_names(&err, &images);
}

#[test]
fn no_3d_points_asks_for_a_bound_sphere() {
    let ws = blank_workspace(&fixture("golden", ModelEncoding::Text));
    let points = ws.path().join("sparse/0/points3D.txt");
    std::fs::write(&points, "# 3D point list with one line of data per point:\n").unwrap();
    let err = read_cameras(ws.path(), &LoadOptions::default()).unwrap_err();
    // The message names the flags a user has, not the library's option.
    assert!(
        err.to_string().contains("data.bound=") && err.to_string().contains("--bound") && err.to_string().contains("none of the 0 points"),
        "{err}"
    );
    assert_names(&err, &points);
    // With the sphere given, the model loads.
    let options = LoadOptions { bound_sphere: Some((DVec3::ZERO, 5.0)), ..LoadOptions::default() };
    let cams = read_cameras(ws.path(), &options).unwrap();
    assert_eq!(cams.world_from_normalized.x_axis.x, 5.0);
}

#[test]
fn binary_files_cut_short_are_errors_never_panics_or_huge_allocations() {
    let src = fixture("golden", ModelEncoding::Binary);
    let dir = tempfile::tempdir().unwrap();
    for name in ["cameras.bin", "images.bin", "points3D.bin"] {
        let bytes = std::fs::read(src.join(name)).unwrap();
        for other in ["cameras.bin", "images.bin", "points3D.bin"] {
            std::fs::copy(src.join(other), dir.path().join(other)).unwrap();
        }
        let path = dir.path().join(name);
        let step = (bytes.len() / 400).max(1);
        let cuts = (0..bytes.len()).step_by(step).chain(bytes.len().saturating_sub(9)..bytes.len());
        for cut in cuts {
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let err = ColmapModel::read(dir.path()).unwrap_err();
            assert!(matches!(err, DatasetError::Corrupt { .. }), "{name} cut at {cut}: {err}");
            assert_names(&err, &path);
        }
        // A corrupt count (2⁶⁴ − 1 records) is caught before any allocation.
        let mut corrupt = bytes.clone();
        corrupt[..8].copy_from_slice(&u64::MAX.to_le_bytes());
        std::fs::write(&path, &corrupt).unwrap();
        let err = ColmapModel::read(dir.path()).unwrap_err();
        assert!(err.to_string().contains("corrupt"), "{err}");
        assert_names(&err, &path);
        std::fs::write(&path, &bytes).unwrap();
    }
    // The number of 2D points of the first image set to 2⁶⁰.
    let images = dir.path().join("images.bin");
    let mut bytes = std::fs::read(&images).unwrap();
    let name_end = 8 + 4 + 56 + 4 + bytes[8 + 4 + 56 + 4..].iter().position(|b| *b == 0).unwrap() + 1;
    bytes[name_end..name_end + 8].copy_from_slice(&(1u64 << 60).to_le_bytes());
    std::fs::write(&images, &bytes).unwrap();
    let err = ColmapModel::read(dir.path()).unwrap_err();
    assert!(err.to_string().contains("number of 2D points"), "{err}");
    assert_names(&err, &images);
}

#[test]
fn malformed_text_lines_are_named_by_number() {
    type Edit = fn(&str) -> String;
    let src = fixture("golden", ModelEncoding::Text);
    let cases: [(&str, Edit); 3] = [
        // A quaternion component that is not a number.
        ("images.txt", |l| {
            let mut t: Vec<String> = l.split(' ').map(String::from).collect();
            t[1] = "abc".into();
            t.join(" ")
        }),
        // A camera line without its parameters.
        ("cameras.txt", |l| l.split(' ').take(5).collect::<Vec<_>>().join(" ")),
        // A track with an image id and no 2D point index.
        ("points3D.txt", |l| format!("{l} 7")),
    ];
    for (file, edit) in cases {
        let dir = tempfile::tempdir().unwrap();
        for f in ["cameras.txt", "images.txt", "points3D.txt"] {
            std::fs::copy(src.join(f), dir.path().join(f)).unwrap();
        }
        let path = dir.path().join(file);
        let text = std::fs::read_to_string(&path).unwrap();
        let mut lines: Vec<String> = text.lines().map(String::from).collect();
        // The line edited: images.txt's second image line, cameras.txt's first camera,
        // points3D.txt's second point.
        let data: Vec<usize> = lines.iter().enumerate().filter(|(_, l)| !l.starts_with('#') && !l.is_empty()).map(|(i, _)| i).collect();
        let target = match file {
            "images.txt" => data[2],
            "cameras.txt" => data[0],
            _ => data[1],
        };
        lines[target] = edit(&lines[target]);
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        let err = ColmapModel::read(dir.path()).unwrap_err();
        assert!(err.to_string().contains(&format!("line {}:", target + 1)), "{file}: {err}");
        assert_names(&err, &path);
    }
}
