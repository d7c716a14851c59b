//! SSIM over a window of rows: the image is never copied, per channel or blurred as a whole.
//!
//! A full-resolution view (DTU: 1600 × 1200) blurred five times in f64 as whole images held
//! ≈ 150 MB at once, the largest working set of a run's evaluation; here the horizontal blurs of
//! the last 11 rows are kept (5 × 11 rows), each output row is blurred vertically from them and
//! summed at once. Every value is computed in the same order as the whole-image blur, so the
//! figure is the same to the last bit. The blurs run a whole row at a time, tap by tap over the
//! columns ([`blur`]), so that they run in vector lanes (per pixel and quantity, a loop that
//! matched on the quantity did not vectorise: SSIM was 7 % of a render's wall time on the
//! built-in scene).

use crate::MetricsError;

/// The window's half-width (11 × 11).
const R: usize = 5;
/// The window's side.
const SIDE: usize = 2 * R + 1;
/// The blurred quantities: x, y, x², y², xy.
const QUANTITIES: usize = 5;

/// Mean SSIM (Wang et al. 2004: 11 × 11 Gaussian window, σ = 1.5, K₁ = 0.01, K₂ = 0.03, data
/// range 1) over the valid window positions, averaged over the three channels.
pub fn ssim(pred: &[[f32; 3]], target: &[[f32; 3]], width: usize, height: usize) -> Result<f64, MetricsError> {
    if pred.len() != target.len() || pred.len() != width * height {
        return Err(MetricsError::SizeMismatch { what: "ssim images", a: pred.len(), b: target.len().max(width * height) });
    }
    if width < SIDE || height < SIDE {
        return Err(MetricsError::Empty("ssim window (image smaller than 11 × 11)"));
    }
    let g: Vec<f64> = (0..SIDE).map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
    let norm: f64 = g.iter().sum();
    let g: Vec<f64> = g.iter().map(|v| v / norm).collect();
    let (w2, h2) = (width - 2 * R, height - 2 * R);
    // rows[(q · SIDE + r % SIDE) · w2 + c]: the horizontal blur of quantity q on image row r.
    let mut rows = vec![0.0f64; QUANTITIES * SIDE * w2];
    // One image row's quantities (q · width + column), and an output row's vertical blurs.
    let mut line = vec![0.0f64; QUANTITIES * width];
    let mut blurred = vec![0.0f64; QUANTITIES * w2];
    let mut total = 0.0;
    for k in 0..3 {
        let mut sum = 0.0;
        for r in 0..height {
            for (c, (p, t)) in pred[r * width..(r + 1) * width].iter().zip(&target[r * width..(r + 1) * width]).enumerate() {
                let (x, y) = (f64::from(p[k]), f64::from(t[k]));
                for (q, v) in [x, y, x * x, y * y, x * y].into_iter().enumerate() {
                    line[q * width + c] = v;
                }
            }
            for q in 0..QUANTITIES {
                let slot = (q * SIDE + r % SIDE) * w2;
                blur(&g, |i| &line[q * width + i..q * width + i + w2], &mut rows[slot..slot + w2]);
            }
            if r + 1 < SIDE {
                continue;
            }
            // Output row r − 2R: its window is image rows r − 2R … r.
            let top = r + 1 - SIDE;
            for (q, out) in blurred.chunks_exact_mut(w2).enumerate() {
                blur(&g, |i| &rows[(q * SIDE + (top + i) % SIDE) * w2..][..w2], out);
            }
            let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
            for c in 0..w2 {
                let [mx, my, sxx, syy, sxy] = [0, 1, 2, 3, 4].map(|q| blurred[q * w2 + c]);
                let (vx, vy, cxy) = (sxx - mx * mx, syy - my * my, sxy - mx * my);
                sum += ((2.0 * mx * my + c1) * (2.0 * cxy + c2)) / ((mx * mx + my * my + c1) * (vx + vy + c2));
            }
        }
        total += sum / (w2 * h2) as f64;
    }
    Ok(total / 3.0)
}

/// `out[c] = Σᵢ g[i] · tap(i)[c]` over the window's taps in order, each column's sum the one
/// `(0..SIDE).map(|i| g[i] * …).sum()` gives (the same additions in the same order), a whole
/// row at a time so that the loop runs over columns in vector lanes.
#[inline]
fn blur<'a>(g: &[f64], tap: impl Fn(usize) -> &'a [f64], out: &mut [f64]) {
    out.fill(-0.0);
    for (i, &weight) in g.iter().enumerate() {
        for (o, &v) in out.iter_mut().zip(tap(i)) {
            *o += weight * v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The whole-image computation this module replaces: five blurred images per channel.
    fn whole_image_ssim(pred: &[[f32; 3]], target: &[[f32; 3]], width: usize, height: usize) -> f64 {
        let g: Vec<f64> = (0..SIDE).map(|i| (-((i as f64 - R as f64).powi(2)) / (2.0 * 1.5 * 1.5)).exp()).collect();
        let norm: f64 = g.iter().sum();
        let g: Vec<f64> = g.iter().map(|v| v / norm).collect();
        let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
        let (w2, h2) = (width - 2 * R, height - 2 * R);
        let mut total = 0.0;
        for k in 0..3 {
            let x: Vec<f64> = pred.iter().map(|p| f64::from(p[k])).collect();
            let y: Vec<f64> = target.iter().map(|p| f64::from(p[k])).collect();
            let blur = |f: &dyn Fn(usize) -> f64| -> Vec<f64> {
                let rows: Vec<f64> = (0..height * w2).map(|j| (0..SIDE).map(|i| g[i] * f((j / w2) * width + j % w2 + i)).sum()).collect();
                (0..h2 * w2).map(|j| (0..SIDE).map(|i| g[i] * rows[(j / w2 + i) * w2 + j % w2]).sum()).collect()
            };
            let (mx, my) = (blur(&|i| x[i]), blur(&|i| y[i]));
            let (sxx, syy, sxy) = (blur(&|i| x[i] * x[i]), blur(&|i| y[i] * y[i]), blur(&|i| x[i] * y[i]));
            let mut sum = 0.0;
            for i in 0..mx.len() {
                let (vx, vy, cxy) = (sxx[i] - mx[i] * mx[i], syy[i] - my[i] * my[i], sxy[i] - mx[i] * my[i]);
                sum += ((2.0 * mx[i] * my[i] + c1) * (2.0 * cxy + c2)) / ((mx[i] * mx[i] + my[i] * my[i] + c1) * (vx + vy + c2));
            }
            total += sum / mx.len() as f64;
        }
        total / 3.0
    }

    #[test]
    fn ssim_over_a_window_of_rows_is_the_whole_image_figure_to_the_bit() {
        for (w, h) in [(11, 11), (37, 23), (64, 40)] {
            let img: Vec<[f32; 3]> =
                (0..w * h).map(|i| [((i % w) as f32 / w as f32), ((i / w) as f32 / h as f32), ((i * 7919) % 101) as f32 / 101.0]).collect();
            let other: Vec<[f32; 3]> = img.iter().enumerate().map(|(i, p)| p.map(|v| (v + ((i * 31) % 17) as f32 / 40.0).min(1.0))).collect();
            assert_eq!(ssim(&other, &img, w, h).unwrap().to_bits(), whole_image_ssim(&other, &img, w, h).to_bits(), "{w} × {h}");
        }
    }

    #[test]
    fn ssim_is_one_for_identical_images_and_drops_with_noise() {
        let (w, h) = (32, 24);
        let img: Vec<[f32; 3]> = (0..w * h).map(|i| [((i % w) as f32 / w as f32), ((i / w) as f32 / h as f32), 0.5]).collect();
        assert!((ssim(&img, &img, w, h).unwrap() - 1.0).abs() < 1e-9);
        let noisy: Vec<[f32; 3]> = img.iter().enumerate().map(|(i, p)| p.map(|v| v + if (i * 7919) % 3 == 0 { 0.1 } else { -0.05 })).collect();
        let s = ssim(&noisy, &img, w, h).unwrap();
        assert!(s < 0.9 && s > 0.0, "ssim {s}");
        assert!(matches!(ssim(&img[..10], &img, w, h), Err(MetricsError::SizeMismatch { .. })));
        assert!(matches!(ssim(&img[..100], &img[..100], 10, 10), Err(MetricsError::Empty(_))));
    }
}
