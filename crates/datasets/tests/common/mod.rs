//! Helpers shared by the COLMAP tests: the committed fixtures, a blank workspace around a
//! model, and the check that an error message starts with the file at fault.
#![allow(dead_code)] // each test crate uses a subset

use datasets::colmap::{ColmapModel, ModelEncoding};
use datasets::{DatasetError, RgbImage};
use std::path::{Path, PathBuf};

pub fn fixture(scene: &str, encoding: ModelEncoding) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/colmap").join(scene);
    match encoding {
        ModelEncoding::Binary => root.join("sparse/0"),
        ModelEncoding::Text => root.join("text"),
    }
}

/// A COLMAP workspace in a temporary folder: `sparse/0/` holds the files of `model_dir`,
/// `images/` a black image of the right size for each registered image (enough for
/// `read_cameras`, which reads headers only, and for the import).
pub fn blank_workspace(model_dir: &Path) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let sparse = dir.path().join("sparse/0");
    std::fs::create_dir_all(&sparse).unwrap();
    for entry in std::fs::read_dir(model_dir).unwrap() {
        let path = entry.unwrap().path();
        std::fs::copy(&path, sparse.join(path.file_name().unwrap())).unwrap();
    }
    let model = ColmapModel::read(model_dir).unwrap();
    let images = dir.path().join("images");
    let mut written: Vec<(u32, PathBuf)> = Vec::new();
    for image in &model.images {
        let camera = model.camera(image.camera_id).unwrap();
        let path = images.join(&image.name);
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        match written.iter().find(|(id, _)| *id == image.camera_id) {
            Some((_, first)) => {
                std::fs::copy(first, &path).unwrap();
            }
            None => {
                RgbImage::new(camera.width, camera.height).save_png(&path).unwrap();
                written.push((image.camera_id, path));
            }
        }
    }
    dir
}

pub fn assert_names(err: &DatasetError, needle: &Path) {
    let msg = err.to_string();
    assert!(msg.starts_with(&needle.display().to_string()), "message {msg:?} does not start with {}", needle.display());
}
