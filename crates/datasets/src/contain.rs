//! Paths named inside a dataset's files (COLMAP image names, transforms.json `file_path`) stay
//! inside the dataset's folder: no absolute path, no `..` that climbs out, no symbolic link that
//! leads out. An escape is an error naming the file, the entry and the path — a dataset never
//! makes the loader read elsewhere.

use crate::error::{DatasetError, Result};
use std::path::{Component, Path, PathBuf};

/// `base` joined with `name` (read from entry `entry` of the file `listed_in`), or an error when
/// `name` is absolute or climbs out of `base`. Checks the words alone; see [`inside`] for the
/// file it leads to.
pub(crate) fn join_inside(base: &Path, name: &str, listed_in: &Path, entry: &str) -> Result<PathBuf> {
    let relative = Path::new(name);
    let mut depth = 0usize;
    for component in relative.components() {
        match component {
            Component::Prefix(_) | Component::RootDir => return Err(escape(base, name, listed_in, entry, "is an absolute path")),
            Component::ParentDir if depth == 0 => return Err(escape(base, name, listed_in, entry, "climbs out of it with `..`")),
            Component::ParentDir => depth -= 1,
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
        }
    }
    Ok(base.join(relative))
}

/// `path` (an existing file named by entry `entry` of `listed_in`) when it lies inside `base`
/// once symbolic links are resolved; an error otherwise. A path that does not exist (yet) is
/// returned as it is: opening it fails with its own error.
pub(crate) fn inside(base: &Path, path: PathBuf, listed_in: &Path, entry: &str) -> Result<PathBuf> {
    match (base.canonicalize(), path.canonicalize()) {
        (Ok(base_real), Ok(real)) if !real.starts_with(&base_real) => {
            let name = path.strip_prefix(base).unwrap_or(&path).display().to_string();
            Err(escape(base, &name, listed_in, entry, &format!("is a symbolic link to {}, outside it", real.display())))
        }
        _ => Ok(path),
    }
}

fn escape(base: &Path, name: &str, listed_in: &Path, entry: &str, why: &str) -> DatasetError {
    DatasetError::InvalidValue {
        path: listed_in.to_path_buf(),
        entry: entry.to_string(),
        message: format!("{name:?} {why}: a dataset's files must lie inside its folder {}", base.display()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_that_leave_the_dataset_folder_are_errors_naming_the_file_and_entry() {
        let base = Path::new("/data/scene");
        let list = Path::new("/data/scene/sparse/0/images.txt");
        assert_eq!(join_inside(base, "a/../b.png", list, "image 1").unwrap(), base.join("a/../b.png"));
        assert_eq!(join_inside(base, "./c.png", list, "image 1").unwrap(), base.join("./c.png"));
        for (name, why) in [("../../x.png", "climbs out"), ("a/../../x.png", "climbs out"), ("/etc/passwd", "absolute")] {
            let msg = join_inside(base, name, list, "image 7").unwrap_err().to_string();
            assert!(msg.contains(why) && msg.contains("images.txt") && msg.contains("image 7") && msg.contains(name), "{msg}");
        }
    }

    #[test]
    fn a_symbolic_link_out_of_the_folder_is_an_error() {
        let outside = tempfile::tempdir().unwrap();
        let secret = outside.path().join("secret.png");
        std::fs::write(&secret, b"x").unwrap();
        let dir = tempfile::tempdir().unwrap();
        std::os::unix::fs::symlink(&secret, dir.path().join("img.png")).unwrap();
        std::fs::write(dir.path().join("own.png"), b"x").unwrap();
        let list = dir.path().join("transforms.json");
        assert!(inside(dir.path(), dir.path().join("own.png"), &list, "frames[0].file_path").is_ok());
        let msg = inside(dir.path(), dir.path().join("img.png"), &list, "frames[1].file_path").unwrap_err().to_string();
        assert!(msg.contains("symbolic link") && msg.contains("frames[1].file_path"), "{msg}");
    }
}
