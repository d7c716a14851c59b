//! COLMAP's text model files (`cameras.txt`, `images.txt`, `points3D.txt`).

use super::*;

pub(super) fn as_text<'a>(bytes: &'a [u8], path: &Path) -> Result<&'a str> {
    std::str::from_utf8(bytes).map_err(|e| DatasetError::Corrupt {
        path: path.to_path_buf(),
        kind: "COLMAP text model",
        message: format!("not UTF-8 text (byte {})", e.valid_up_to()),
    })
}

/// The whitespace-separated fields of one line, with the line number for messages.
pub(super) struct Fields<'a> {
    path: &'a Path,
    line: usize,
    rest: &'a str,
}

impl<'a> Fields<'a> {
    fn token(&mut self) -> Option<&'a str> {
        let s = self.rest.trim_start();
        if s.is_empty() {
            return None;
        }
        let end = s.find(char::is_whitespace).unwrap_or(s.len());
        self.rest = &s[end..];
        Some(&s[..end])
    }
    fn next<T: FromStr>(&mut self, what: &str) -> Result<T> {
        let token = self.token().ok_or_else(|| corrupt_text(self.path, self.line, format!("missing {what}")))?;
        token.parse().map_err(|_| corrupt_text(self.path, self.line, format!("{what}: cannot read {token:?}")))
    }
    /// The rest of the line, trimmed.
    fn rest(&mut self) -> &'a str {
        std::mem::take(&mut self.rest).trim()
    }
}

/// Numbered lines that are neither empty nor comments.
pub(super) fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().map(|(i, l)| (i + 1, l.trim())).filter(|(_, l)| !l.is_empty() && !l.starts_with('#'))
}

pub(super) fn cameras_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapCamera>> {
    let text = as_text(bytes, path)?;
    let mut cameras = Vec::new();
    for (line, content) in data_lines(text) {
        let mut f = Fields { path, line, rest: content };
        let camera_id: u32 = f.next("CAMERA_ID")?;
        let model = f.token().ok_or_else(|| corrupt_text(path, line, "missing MODEL".into()))?;
        let width = f.next("WIDTH")?;
        let height = f.next("HEIGHT")?;
        let Some(id) = CameraModel::SUPPORTED.iter().position(|m| *m == model) else {
            return Err(unsupported_model(path, camera_id, model));
        };
        let mut params = [0.0; 8];
        let count = SUPPORTED_PARAMS[id];
        for (i, p) in params.iter_mut().take(count).enumerate() {
            *p = f.next(&format!("{model} parameter {}", i + 1))?;
        }
        if f.token().is_some() {
            return Err(corrupt_text(path, line, format!("{model} takes {count} parameters, the line has more")));
        }
        let camera = ColmapCamera { camera_id, width, height, model: CameraModel::from_params(id, &params[..count]) };
        check_camera(path, &camera)?;
        cameras.push(camera);
    }
    Ok(cameras)
}

pub(super) fn images_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>> {
    let text = as_text(bytes, path)?;
    let mut images = Vec::new();
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    while let Some((line, content)) = lines.next() {
        let content = content.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let mut f = Fields { path, line, rest: content };
        let image_id = f.next("IMAGE_ID")?;
        let quaternion = [f.next("QW")?, f.next("QX")?, f.next("QY")?, f.next("QZ")?];
        let translation = DVec3::new(f.next("TX")?, f.next("TY")?, f.next("TZ")?);
        let camera_id = f.next("CAMERA_ID")?;
        let name = f.rest();
        if name.is_empty() {
            return Err(corrupt_text(path, line, "missing NAME".into()));
        }
        // The 2D points: the very next line, possibly empty (or absent at the end of the file).
        let (line, points_line) = lines.next().unwrap_or((line + 1, ""));
        let mut f = Fields { path, line, rest: points_line };
        let hint = "two lines per image: the second lists X Y POINT3D_ID per 2D point, or is empty";
        let mut values = 0usize;
        while let Some(token) = f.token() {
            let field = ["X", "Y", "POINT3D_ID"][values % 3];
            let ok = if values % 3 == 2 { token.parse::<i64>().is_ok() } else { token.parse::<f64>().is_ok() };
            if !ok {
                return Err(corrupt_text(path, line, format!("{field} of a 2D point of image {image_id}: cannot read {token:?} ({hint})")));
            }
            values += 1;
        }
        if !values.is_multiple_of(3) {
            return Err(corrupt_text(path, line, format!("{values} values for the 2D points of image {image_id}, not a multiple of 3 ({hint})")));
        }
        let points2d = values / 3;
        images.push(ColmapImage { image_id, camera_id, name: name.to_string(), quaternion, translation, points2d });
    }
    Ok(images)
}

pub(super) fn points_text(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let text = as_text(bytes, path)?;
    let mut points = Vec::new();
    let mut track = Vec::new();
    for (line, content) in data_lines(text) {
        let mut f = Fields { path, line, rest: content };
        let point3d_id = f.next("POINT3D_ID")?;
        let point_in_world = DVec3::new(f.next("X")?, f.next("Y")?, f.next("Z")?);
        let color = [f.next("R")?, f.next("G")?, f.next("B")?];
        let error = f.next("ERROR")?;
        track.clear();
        while !f.rest.trim().is_empty() {
            track.push(f.next::<u32>("TRACK IMAGE_ID")?);
            f.next::<u32>("TRACK POINT2D_IDX")?;
        }
        let track_length = track.len() as u32;
        points.push(ColmapPoint { point3d_id, point_in_world, color, error, track_length, images: distinct(&mut track) });
    }
    Ok(points)
}
