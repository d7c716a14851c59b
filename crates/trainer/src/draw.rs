//! Minimal raster drawing for pictures: a colour map, lines, dots (plots with axes and legends:
//! [`crate::plot`]).

use datasets::RgbImage;

/// A perceptually ordered colour map (dark blue → magenta → orange → yellow), t ∈ [0, 1].
pub fn colormap(t: f32) -> [f32; 3] {
    const STOPS: [[f32; 3]; 5] = [[0.05, 0.03, 0.2], [0.35, 0.05, 0.5], [0.75, 0.2, 0.45], [0.98, 0.55, 0.15], [0.99, 0.95, 0.5]];
    let t = t.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (t as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    [0, 1, 2].map(|c| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f)
}

/// Sets a pixel if it is inside the image.
pub fn put(img: &mut RgbImage, x: i64, y: i64, rgb: [f32; 3]) {
    if x >= 0 && y >= 0 && x < img.width as i64 && y < img.height as i64 {
        img.set_f32(x as u32, y as u32, rgb);
    }
}

/// A line by Bresenham's algorithm.
pub fn line(img: &mut RgbImage, (x0, y0): (i64, i64), (x1, y1): (i64, i64), rgb: [f32; 3]) {
    let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
    let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
    let (mut x, mut y, mut err) = (x0, y0, dx + dy);
    loop {
        put(img, x, y, rgb);
        if x == x1 && y == y1 {
            break;
        }
        let e2 = 2 * err;
        if e2 >= dy {
            err += dy;
            x += sx;
        }
        if e2 <= dx {
            err += dx;
            y += sy;
        }
    }
}
