//! Images held as u8 RGB and masks as bits: the 49-view 1600×1200 DTU scan fits in < 400 MB.

use crate::error::{DatasetError, Result, io_err};
pub use image::ExtendedColorType;
use std::path::Path;

/// An 8-bit RGB image, row-major, 3 bytes per pixel.
#[derive(Debug, Clone, PartialEq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `3·width·height` bytes, row-major.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// A black image.
    pub fn new(width: u32, height: u32) -> RgbImage {
        RgbImage { width, height, data: vec![0; 3 * width as usize * height as usize] }
    }

    /// The pixel at (column, row) as `[r, g, b]` in [0, 1].
    pub fn get_f32(&self, column: u32, row: u32) -> [f32; 3] {
        let i = 3 * (row as usize * self.width as usize + column as usize);
        [self.data[i], self.data[i + 1], self.data[i + 2]].map(|v| v as f32 / 255.0)
    }

    /// Sets the pixel at (column, row) from `[r, g, b]` in [0, 1] (clamped, rounded).
    pub fn set_f32(&mut self, column: u32, row: u32, rgb: [f32; 3]) {
        let i = 3 * (row as usize * self.width as usize + column as usize);
        for (c, v) in rgb.iter().enumerate() {
            self.data[i + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
    }

    /// Area-averaged by an integer factor (remainder dropped), as the loaders' `downscale`.
    pub fn downscaled(&self, n: u32) -> RgbImage {
        let (data, width, height) = downscale_u8(&self.data, self.width, self.height, 3, n.max(1));
        RgbImage { width, height, data }
    }

    /// Writes a PNG atomically.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        crate::io::write_atomic(path, &self.png_bytes().map_err(|e| DatasetError::Io { path: path.to_path_buf(), source: e })?)
    }

    /// The image encoded as PNG.
    pub fn png_bytes(&self) -> std::io::Result<Vec<u8>> {
        png_bytes(&self.data, self.width, self.height, image::ExtendedColorType::Rgb8)
    }
}

/// A binary mask, one bit per pixel, row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    bits: Vec<u64>,
}

impl Mask {
    /// An all-background mask.
    pub fn new(width: u32, height: u32) -> Mask {
        Mask { width, height, bits: vec![0; (width as usize * height as usize).div_ceil(64)] }
    }

    /// Whether (column, row) is foreground.
    pub fn get(&self, column: u32, row: u32) -> bool {
        let i = row as usize * self.width as usize + column as usize;
        self.bits[i / 64] >> (i % 64) & 1 == 1
    }

    /// Sets (column, row).
    pub fn set(&mut self, column: u32, row: u32, value: bool) {
        let i = row as usize * self.width as usize + column as usize;
        if value {
            self.bits[i / 64] |= 1 << (i % 64);
        } else {
            self.bits[i / 64] &= !(1 << (i % 64));
        }
    }

    /// The bits, row-major, 64 pixels a word (the last word of the mask zero-padded).
    pub fn as_words(&self) -> &[u64] {
        &self.bits
    }

    /// Number of foreground pixels.
    pub fn count(&self) -> usize {
        self.bits.iter().map(|w| w.count_ones() as usize).sum()
    }

    fn to_grey(&self) -> Vec<u8> {
        let mut grey = vec![0u8; self.width as usize * self.height as usize];
        for row in 0..self.height {
            for col in 0..self.width {
                if self.get(col, row) {
                    grey[(row * self.width + col) as usize] = 255;
                }
            }
        }
        grey
    }

    /// Downscaled by an integer factor: foreground where more than half the block is.
    pub fn downscaled(&self, n: u32) -> Mask {
        let (grey, width, height) = downscale_u8(&self.to_grey(), self.width, self.height, 1, n.max(1));
        let mut out = Mask::new(width, height);
        for (i, v) in grey.iter().enumerate() {
            if *v > 127 {
                out.set(i as u32 % width, i as u32 / width, true);
            }
        }
        out
    }

    /// Writes a grey PNG (255 = foreground).
    pub fn save_png(&self, path: &Path) -> Result<()> {
        write_png(path, &self.to_grey(), self.width, self.height, image::ExtendedColorType::L8)
    }
}

/// Encodes pixels as PNG in memory.
pub fn png_bytes(pixels: &[u8], width: u32, height: u32, color: image::ExtendedColorType) -> std::io::Result<Vec<u8>> {
    use image::ImageEncoder;
    let mut bytes = Vec::new();
    image::codecs::png::PngEncoder::new(&mut bytes).write_image(pixels, width, height, color).map_err(std::io::Error::other)?;
    Ok(bytes)
}

/// Encodes pixels as PNG in memory and writes the file atomically.
pub fn write_png(path: &Path, pixels: &[u8], width: u32, height: u32, color: image::ExtendedColorType) -> Result<()> {
    let bytes = png_bytes(pixels, width, height, color).map_err(|e| DatasetError::Io { path: path.to_path_buf(), source: e })?;
    crate::io::write_atomic(path, &bytes)
}

/// A decoded image file: RGB (composited over `background` where it has alpha) and, when the
/// file has an alpha channel, the alpha as a mask.
pub(crate) struct Decoded {
    pub rgb: RgbImage,
    pub alpha_mask: Option<Mask>,
}

fn decode(path: &Path) -> Result<image::DynamicImage> {
    decode_bytes(&std::fs::read(path).map_err(io_err(path))?, path)
}

/// The largest image side any loader accepts (a 1-gigapixel frame is 32 768 a side).
pub const MAX_IMAGE_SIDE: u32 = 1 << 16;

/// The most pixels a decoded image may have: 2²⁸ (1 GiB as RGBA, the largest form we convert
/// to), so that a small file whose header claims a huge image is refused before decoding.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 28;

/// Decodes the bytes of an image file (format from its contents), refusing headers beyond
/// [`MAX_IMAGE_SIDE`] or [`MAX_IMAGE_PIXELS`] before any pixel is allocated.
pub(crate) fn decode_bytes(bytes: &[u8], path: &Path) -> Result<image::DynamicImage> {
    let corrupt = |message: String| DatasetError::Corrupt { path: path.to_path_buf(), kind: "image", message };
    let reader = || image::ImageReader::new(std::io::Cursor::new(bytes)).with_guessed_format().map_err(|e| corrupt(e.to_string()));
    let (w, h) = reader()?.into_dimensions().map_err(|e| corrupt(e.to_string()))?;
    if w > MAX_IMAGE_SIDE || h > MAX_IMAGE_SIDE || w as u64 * h as u64 > MAX_IMAGE_PIXELS {
        return Err(corrupt(format!("{w}×{h} pixels: beyond the {MAX_IMAGE_SIDE} a side and {MAX_IMAGE_PIXELS} in all an image may have")));
    }
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE);
    limits.max_image_height = Some(MAX_IMAGE_SIDE);
    limits.max_alloc = Some(4 * MAX_IMAGE_PIXELS);
    let mut reader = reader()?;
    reader.limits(limits);
    reader.decode().map_err(|e| corrupt(e.to_string()))
}

/// Area-averages `channels`-channel u8 rows by an integer factor (remainder dropped).
fn downscale_u8(src: &[u8], width: u32, height: u32, channels: usize, n: u32) -> (Vec<u8>, u32, u32) {
    if n == 1 {
        return (src.to_vec(), width, height);
    }
    let (w2, h2) = (width / n, height / n);
    let mut out = vec![0u8; w2 as usize * h2 as usize * channels];
    let norm = n * n;
    for y in 0..h2 as usize {
        for x in 0..w2 as usize {
            for c in 0..channels {
                let mut sum = 0u32;
                for dy in 0..n as usize {
                    let row = (y * n as usize + dy) * width as usize;
                    for dx in 0..n as usize {
                        sum += src[(row + x * n as usize + dx) * channels + c] as u32;
                    }
                }
                out[(y * w2 as usize + x) * channels + c] = ((sum + norm / 2) / norm) as u8;
            }
        }
    }
    (out, w2, h2)
}

/// Loads an image file as RGB, downscaled by `downscale` (area average). Files with alpha are
/// composited over `background` and give an alpha mask (alpha > 127 after averaging).
pub(crate) fn load_rgb(path: &Path, downscale: u32, background: [f32; 3]) -> Result<Decoded> {
    Ok(rgb_of(decode(path)?, downscale, background))
}

/// The RGB (and alpha mask) of a decoded image, as [`load_rgb`].
pub(crate) fn rgb_of(img: image::DynamicImage, downscale: u32, background: [f32; 3]) -> Decoded {
    let (w, h) = (img.width(), img.height());
    if img.color().has_alpha() {
        let rgba = img.into_rgba8();
        let (data, w2, h2) = downscale_u8(rgba.as_raw(), w, h, 4, downscale);
        let mut rgb = RgbImage::new(w2, h2);
        let mut mask = Mask::new(w2, h2);
        for (i, px) in data.chunks_exact(4).enumerate() {
            let a = px[3] as f32 / 255.0;
            for c in 0..3 {
                // Premultiplied compositing: colour·α + background·(1 − α).
                let v = px[c] as f32 / 255.0 * a + background[c] * (1.0 - a);
                rgb.data[3 * i + c] = (v.clamp(0.0, 1.0) * 255.0).round() as u8;
            }
            if px[3] > 127 {
                mask.set(i as u32 % w2, i as u32 / w2, true);
            }
        }
        Decoded { rgb, alpha_mask: Some(mask) }
    } else {
        let rgb = img.into_rgb8();
        let (data, w2, h2) = downscale_u8(rgb.as_raw(), w, h, 3, downscale);
        Decoded { rgb: RgbImage { width: w2, height: h2, data }, alpha_mask: None }
    }
}

/// Loads a mask file (grey or RGB: the first channel; soft edges thresholded: > 127 is
/// foreground, after area-averaging by `downscale`). Returns the mask and the file's full size.
pub(crate) fn load_mask(path: &Path, downscale: u32) -> Result<(Mask, (u32, u32))> {
    Ok(mask_of(decode(path)?, downscale))
}

/// The mask of a decoded image, as [`load_mask`].
pub(crate) fn mask_of(img: image::DynamicImage, downscale: u32) -> (Mask, (u32, u32)) {
    let (w, h) = (img.width(), img.height());
    let grey: Vec<u8> = match img {
        image::DynamicImage::ImageLuma8(g) => g.into_raw(),
        other => other.into_rgb8().as_raw().chunks_exact(3).map(|p| p[0]).collect(),
    };
    let (data, w2, h2) = downscale_u8(&grey, w, h, 1, downscale);
    let mut mask = Mask::new(w2, h2);
    for (i, v) in data.iter().enumerate() {
        if *v > 127 {
            mask.set(i as u32 % w2, i as u32 / w2, true);
        }
    }
    (mask, (w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn downscale_is_an_area_average_dropping_the_remainder() {
        // 5×2 grey image, factor 2 → 2×1.
        let src = [0u8, 10, 20, 30, 99, 40, 50, 60, 70, 99];
        let (out, w, h) = downscale_u8(&src, 5, 2, 1, 2);
        assert_eq!((w, h), (2, 1));
        assert_eq!(out, vec![25, 45]);
    }

    #[test]
    fn mask_bits_round_trip() {
        let mut m = Mask::new(70, 3);
        m.set(69, 2, true);
        m.set(0, 1, true);
        m.set(0, 1, false);
        assert!(m.get(69, 2) && !m.get(0, 1));
        assert_eq!(m.count(), 1);
    }
}
