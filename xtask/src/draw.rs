//! Minimal raster drawing for pictures: a colour map, lines, dots, simple line plots.

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

/// A plotted curve: its colour and its (x, y) points.
pub type Series = ([f32; 3], Vec<(f64, f64)>);

/// 3×5 glyphs for digits, '.', '-' (rows top to bottom, 3 bits each).
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        _ => return None,
    })
}

/// Writes `text` (digits, '.', '-') with its top-left corner at (x, y), pixels scaled by `scale`.
pub fn text(img: &mut RgbImage, x: i64, y: i64, text: &str, scale: i64, rgb: [f32; 3]) {
    for (i, c) in text.chars().enumerate() {
        let Some(g) = glyph(c) else { continue };
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits >> (2 - col) & 1 == 1 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            put(img, x + (i as i64 * 4 + col) * scale + dx, y + row as i64 * scale + dy, rgb);
                        }
                    }
                }
            }
        }
    }
}

/// A line plot: each series is (colour, points (x, y)); the x axis is cropped to where some
/// series exceeds 0.5 % of its peak (padded), with the x range written at both ends. Vertical
/// markers (x, colour) are drawn dashed.
pub fn plot(width: u32, height: u32, series: &[Series], markers: &[(f64, [f32; 3])]) -> RgbImage {
    let mut img = RgbImage::new(width, height);
    img.data.fill(255);
    let (m, w, h) = (20i64, width as i64, height as i64);
    let mut x_min = f64::INFINITY;
    let mut x_max = f64::NEG_INFINITY;
    for (_, points) in series {
        let peak = points.iter().map(|p| p.1).fold(0.0f64, f64::max);
        for p in points.iter().filter(|p| peak > 0.0 && p.1 > 0.005 * peak) {
            x_min = x_min.min(p.0);
            x_max = x_max.max(p.0);
        }
    }
    for (x, _) in markers {
        x_min = x_min.min(*x);
        x_max = x_max.max(*x);
    }
    if !(x_max > x_min) {
        let xs = series.iter().flat_map(|s| s.1.iter().map(|p| p.0));
        (x_min, x_max) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| (a.min(x), b.max(x)));
    }
    let pad = 0.15 * (x_max - x_min).max(1e-9);
    let (x_min, x_max) = (x_min - pad, x_max + pad);
    text(&mut img, m, h - m + 6, &format!("{x_min:.3}"), 2, [0.2; 3]);
    let label = format!("{x_max:.3}");
    text(&mut img, w - m - label.len() as i64 * 8, h - m + 6, &label, 2, [0.2; 3]);
    let y_max = series.iter().flat_map(|s| s.1.iter().map(|p| p.1)).fold(0.0f64, f64::max).max(1e-30);
    let to_px = |x: f64, y: f64| {
        let px = m + ((x - x_min) / (x_max - x_min).max(1e-30) * (w - 2 * m) as f64) as i64;
        let py = h - m - (y / y_max * (h - 2 * m) as f64) as i64;
        (px, py)
    };
    let grey = [0.3; 3];
    line(&mut img, (m, h - m), (w - m, h - m), grey);
    line(&mut img, (m, m), (m, h - m), grey);
    for (x, rgb) in markers {
        let (px, _) = to_px(*x, 0.0);
        for y in (m..h - m).step_by(6) {
            line(&mut img, (px, y), (px, (y + 3).min(h - m)), *rgb);
        }
    }
    for (rgb, points) in series {
        let points: Vec<(f64, f64)> = points.iter().copied().filter(|p| p.0 >= x_min && p.0 <= x_max).collect();
        for pair in points.windows(2) {
            line(&mut img, to_px(pair[0].0, pair[0].1), to_px(pair[1].0, pair[1].1), *rgb);
        }
    }
    img
}
