//! COLMAP's binary model files (`cameras.bin`, `images.bin`, `points3D.bin`).

use super::*;

/// A cursor over a binary model file that checks every read against the bytes left.
pub(super) struct Bin<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Bin<'a> {
    fn take(&mut self, n: usize, what: &str) -> Result<&'a [u8]> {
        let left = self.bytes.len() - self.pos;
        if n > left {
            return Err(corrupt_binary(self.path, format!("cut short at byte {}: {what} needs {n} bytes, {left} left", self.pos)));
        }
        let out = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(out)
    }
    fn u8(&mut self, what: &str) -> Result<u8> {
        Ok(self.take(1, what)?[0])
    }
    fn u32(&mut self, what: &str) -> Result<u32> {
        Ok(u32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn i32(&mut self, what: &str) -> Result<i32> {
        Ok(i32::from_le_bytes(self.take(4, what)?.try_into().expect("4 bytes")))
    }
    fn u64(&mut self, what: &str) -> Result<u64> {
        Ok(u64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    fn f64(&mut self, what: &str) -> Result<f64> {
        Ok(f64::from_le_bytes(self.take(8, what)?.try_into().expect("8 bytes")))
    }
    /// A count of items of at least `min_bytes` each, checked against the bytes left so that a
    /// corrupt count never drives an allocation.
    fn count(&mut self, what: &str, min_bytes: usize) -> Result<usize> {
        let at = self.pos;
        let n = self.u64(what)?;
        let left = (self.bytes.len() - self.pos) as u64;
        if n.checked_mul(min_bytes as u64).is_none_or(|need| need > left) {
            return Err(corrupt_binary(
                self.path,
                format!("cut short or corrupt: {what} at byte {at} is {n}, needing at least {min_bytes} bytes each, {left} bytes left"),
            ));
        }
        Ok(n as usize)
    }
    fn size(&mut self, what: &str) -> Result<u32> {
        let v = self.u64(what)?;
        u32::try_from(v).map_err(|_| corrupt_binary(self.path, format!("{what} {v} at byte {} is out of range", self.pos - 8)))
    }
    fn name(&mut self) -> Result<String> {
        let at = self.pos;
        let end = self.bytes[self.pos..]
            .iter()
            .position(|b| *b == 0)
            .ok_or_else(|| corrupt_binary(self.path, format!("cut short at byte {at}: image name without its terminating NUL")))?;
        let bytes = self.take(end + 1, "image name")?;
        String::from_utf8(bytes[..end].to_vec()).map_err(|_| corrupt_binary(self.path, format!("image name at byte {at} is not UTF-8")))
    }
    fn finish(&self) -> Result<()> {
        let left = self.bytes.len() - self.pos;
        if left != 0 {
            return Err(corrupt_binary(self.path, format!("{left} unexpected bytes after the last record (byte {})", self.pos)));
        }
        Ok(())
    }
}

pub(super) fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(io_err(path))
}

pub(super) fn cameras_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapCamera>> {
    let mut b = Bin { path, bytes, pos: 0 };
    let n = b.count("number of cameras", 24)?;
    let mut cameras = Vec::with_capacity(n);
    for _ in 0..n {
        let camera_id = b.u32("camera id")?;
        let model_id = b.i32("camera model id")?;
        let width = b.size("camera width")?;
        let height = b.size("camera height")?;
        let Some(&count) = usize::try_from(model_id).ok().and_then(|i| SUPPORTED_PARAMS.get(i)) else {
            let name = match usize::try_from(model_id).ok().and_then(|i| MODEL_NAMES.get(i)) {
                Some(name) => format!("{name} (id {model_id})"),
                None => format!("with unknown id {model_id}"),
            };
            return Err(unsupported_model(path, camera_id, &name));
        };
        let mut params = [0.0; 8];
        for p in params.iter_mut().take(count) {
            *p = b.f64("camera parameter")?;
        }
        let camera = ColmapCamera { camera_id, width, height, model: CameraModel::from_params(model_id as usize, &params[..count]) };
        check_camera(path, &camera)?;
        cameras.push(camera);
    }
    b.finish()?;
    Ok(cameras)
}

/// Bytes of an image record before its name: id, quaternion, translation, camera id.
pub(super) const IMAGE_HEAD_BYTES: usize = 4 + 4 * 8 + 3 * 8 + 4;

pub(super) fn images_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapImage>> {
    let mut b = Bin { path, bytes, pos: 0 };
    // Smallest record: head, an empty name (1 NUL byte), the 2D point count.
    let n = b.count("number of images", IMAGE_HEAD_BYTES + 1 + 8)?;
    let mut images = Vec::with_capacity(n);
    for _ in 0..n {
        let image_id = b.u32("image id")?;
        let mut quaternion = [0.0; 4];
        for q in &mut quaternion {
            *q = b.f64("image quaternion")?;
        }
        let translation = DVec3::new(b.f64("image translation")?, b.f64("image translation")?, b.f64("image translation")?);
        let camera_id = b.u32("image camera id")?;
        let name = b.name()?;
        let points2d = b.count("number of 2D points", 24)?;
        b.take(points2d * 24, "2D points")?;
        images.push(ColmapImage { image_id, camera_id, name, quaternion, translation, points2d });
    }
    b.finish()?;
    Ok(images)
}

/// Number of distinct values in `ids` (sorted in place).
pub(super) fn distinct(ids: &mut [u32]) -> u32 {
    ids.sort_unstable();
    (ids.len() - ids.windows(2).filter(|w| w[0] == w[1]).count()) as u32
}

pub(super) fn points_binary(bytes: &[u8], path: &Path) -> Result<Vec<ColmapPoint>> {
    let mut b = Bin { path, bytes, pos: 0 };
    let n = b.count("number of 3D points", 8 + 24 + 3 + 8 + 8)?;
    let mut points = Vec::with_capacity(n);
    let mut track = Vec::new();
    for _ in 0..n {
        let point3d_id = b.u64("point id")?;
        let point_in_world = DVec3::new(b.f64("point xyz")?, b.f64("point xyz")?, b.f64("point xyz")?);
        let color = [b.u8("point colour")?, b.u8("point colour")?, b.u8("point colour")?];
        let error = b.f64("point error")?;
        let length = b.count("track length", 8)?;
        track.clear();
        for _ in 0..length {
            track.push(b.u32("track image id")?);
            b.u32("track point2D index")?;
        }
        let track_length = u32::try_from(length).map_err(|_| corrupt_binary(path, format!("track of point {point3d_id} is too long")))?;
        points.push(ColmapPoint { point3d_id, point_in_world, color, error, track_length, images: distinct(&mut track) });
    }
    b.finish()?;
    Ok(points)
}
