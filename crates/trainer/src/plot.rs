//! Plots a reader can read (plotters, with DejaVu Sans shipped in `xtask/assets`, no system
//! fonts): a title, axis labels with units, a legend, round tick values, error bars when a point
//! has a spread (mean ± std over seeds), dashed vertical markers.

use crate::error::{Error, Result};
use datasets::images::RgbImage;
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::sync::Once;

/// The font, embedded (Bitstream Vera licence: `xtask/assets/DejaVuSans.LICENSE.txt`).
static FONT: &[u8] = include_bytes!("../assets/DejaVuSans.ttf");

fn register() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // A font that does not parse is a build-time asset error, reported at first draw.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

/// A point of a series: x, y and an optional error bar (± value).
pub type Point = (f64, f64, Option<f64>);

/// A line of points (x, y, optional ± error).
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend entry.
    pub label: String,
    /// Colour (RGB in [0, 1]).
    pub color: [f32; 3],
    /// Points, sorted by x.
    pub points: Vec<Point>,
}

/// One panel: series on labelled axes.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    /// Title above the panel.
    pub title: String,
    /// x axis label, with its unit.
    pub x_label: String,
    /// y axis label, with its unit.
    pub y_label: String,
    /// The lines.
    pub series: Vec<Series>,
    /// Dashed vertical markers (x, colour, legend label).
    pub markers: Vec<(f64, [f32; 3], String)>,
}

fn rgb(c: [f32; 3]) -> RGBColor {
    let u = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u8;
    RGBColor(u(c[0]), u(c[1]), u(c[2]))
}

/// The range of `values` with a margin (a degenerate range is widened).
fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.filter(|v| v.is_finite()).fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = if hi > lo { 0.06 * (hi - lo) } else { 0.5 * lo.abs().max(1e-3) };
    (lo - pad, hi + pad)
}

/// Draws `panels` in a grid of `columns`, each `size` pixels, into an image.
pub fn render(panels: &[Panel], columns: usize, size: (u32, u32)) -> Result<RgbImage> {
    register();
    let columns = columns.max(1);
    let rows = panels.len().div_ceil(columns).max(1);
    let (w, h) = (size.0 * columns as u32, size.1 * rows as u32);
    let mut buffer = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| Error::Drawing(format!("plot: {e}")))?;
        let areas = root.split_evenly((rows, columns));
        for (panel, area) in panels.iter().zip(areas.iter()) {
            draw_panel(panel, area).map_err(|e| Error::Drawing(format!("plot {:?}: {e}", panel.title)))?;
        }
        root.present().map_err(|e| Error::Drawing(format!("plot: {e}")))?;
    }
    let mut img = RgbImage::new(w, h);
    img.data.copy_from_slice(&buffer);
    Ok(img)
}

/// A tick value without trailing zeros: 60, 0.025, 1.5e-5.
fn tick(v: &f64) -> String {
    let v = *v;
    if v == 0.0 {
        return "0".into();
    }
    if v.abs() >= 1e-3 && v.abs() < 1e6 {
        let s = format!("{v:.6}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.1e}")
    }
}

type DrawResult = std::result::Result<(), Box<dyn std::error::Error>>;

fn draw_panel(panel: &Panel, area: &DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> DrawResult {
    let points = || panel.series.iter().flat_map(|s| s.points.iter());
    let (x0, x1) = range(points().map(|p| p.0).chain(panel.markers.iter().map(|m| m.0)));
    let (y0, y1) = range(points().flat_map(|p| [p.1 - p.2.unwrap_or(0.0), p.1 + p.2.unwrap_or(0.0)]));
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart
        .configure_mesh()
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .x_desc(&panel.x_label)
        .y_desc(&panel.y_label)
        .axis_desc_style(("sans-serif", 15))
        .label_style(("sans-serif", 13))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()?;
    for s in &panel.series {
        let color = rgb(s.color);
        chart
            .draw_series(LineSeries::new(s.points.iter().map(|p| (p.0, p.1)), color.stroke_width(2)))?
            .label(&s.label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2)));
        chart.draw_series(s.points.iter().map(|p| Circle::new((p.0, p.1), 3, color.filled())))?;
        chart
            .draw_series(s.points.iter().filter_map(|p| p.2.map(|e| ErrorBar::new_vertical(p.0, p.1 - e, p.1, p.1 + e, color.stroke_width(1), 8))))?;
    }
    for (x, c, label) in &panel.markers {
        let color = rgb(*c);
        let dashes: Vec<(f64, f64)> = (0..40).map(|i| y0 + (y1 - y0) * f64::from(i) / 40.0).map(|y| (*x, y)).collect();
        chart
            .draw_series(dashes.chunks(2).map(|d| PathElement::new(d.to_vec(), color.stroke_width(1))))?
            .label(label)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 6, y), (x + 12, y), (x + 18, y)], color.stroke_width(1)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(160, 160, 160))
        .label_font(("sans-serif", 13))
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_plot_renders_with_text_and_lines() {
        let panel = Panel {
            title: "Chamfer against wall time".into(),
            x_label: "wall time (s)".into(),
            y_label: "Chamfer (normalised units)".into(),
            series: vec![
                Series { label: "uniform".into(), color: [0.2, 0.35, 0.85], points: vec![(60.0, 0.03, Some(0.002)), (120.0, 0.02, Some(0.001))] },
                Series { label: "guided".into(), color: [0.85, 0.15, 0.15], points: vec![(60.0, 0.028, None), (120.0, 0.018, None)] },
            ],
            markers: vec![(90.0, [0.3, 0.3, 0.3], "true depth".into())],
        };
        let img = render(&[panel.clone(), panel], 2, (480, 320)).unwrap();
        if let Ok(p) = std::env::var("PSNEUS_PLOT_SAMPLE") {
            img.save_png(std::path::Path::new(&p)).unwrap();
        }
        assert_eq!((img.width, img.height), (960, 320));
        // Both series colours appear, and dark text pixels (labels, ticks) do.
        let has = |c: [u8; 3]| img.data.chunks_exact(3).any(|p| p == c);
        assert!(has([217, 38, 38]) && has([51, 89, 217]));
        let dark = img.data.chunks_exact(3).filter(|p| p.iter().all(|v| *v < 60)).count();
        assert!(dark > 500, "{dark} dark pixels: no text?");
    }
}
