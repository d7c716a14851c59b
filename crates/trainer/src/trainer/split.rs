//! How a run splits the image between the object and what lies behind it, measured against a
//! scene's masks (golden scenes and masked datasets keep their masks for evaluation even when
//! the run trains without them): the foreground network's opacity over backdrop pixels (a
//! backdrop painted into the bound as walls), over object pixels, and the guide's pixel mass on
//! backdrop pixels (a guide chasing those walls).

use super::Trainer;
use crate::outputs::ViewRender;
use serde::Serialize;

/// A foreground opacity above which a backdrop pixel counts as walled in.
pub const WALLED_OPACITY: f32 = 0.5;

/// The split of one view (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SplitStats {
    /// Mean foreground opacity over backdrop pixels (0: the background explains them all).
    pub backdrop_opacity: f64,
    /// Fraction of backdrop pixels whose foreground opacity exceeds [`WALLED_OPACITY`].
    pub backdrop_walled: f64,
    /// Mean foreground opacity over object pixels (1: the object is opaque).
    pub object_opacity: f64,
    /// The guide's pixel mass on backdrop pixels of the training view nearest the rendered one
    /// (`None` before the first guide update or without a guide).
    pub guide_backdrop_mass: Option<f64>,
    /// The backdrop's share of that training view's pixels (what a uniform sampler puts there).
    pub backdrop_pixels: Option<f64>,
}

impl Trainer {
    /// The split of `render` (a render of view `view`), `None` when the view has no mask.
    pub fn split_stats(&self, render: &ViewRender, view: usize) -> Option<SplitStats> {
        let mask = render.mask.as_ref()?;
        let (mut sums, mut counts, mut walled) = ([0.0f64; 2], [0usize; 2], 0usize);
        for (out, &object) in render.outputs.iter().zip(mask) {
            sums[object as usize] += f64::from(out.opacity);
            counts[object as usize] += 1;
            walled += usize::from(!object && out.opacity > WALLED_OPACITY);
        }
        let mean = |k: usize| if counts[k] == 0 { 0.0 } else { sums[k] / counts[k] as f64 };
        let (guide_backdrop_mass, backdrop_pixels) = self.guide_backdrop_mass(view).unzip();
        Some(SplitStats {
            backdrop_opacity: mean(0),
            backdrop_walled: if counts[0] == 0 { 0.0 } else { walled as f64 / counts[0] as f64 },
            object_opacity: mean(1),
            guide_backdrop_mass,
            backdrop_pixels,
        })
    }

    /// The guide's pixel mass on the backdrop of the training view whose distribution
    /// [`Self::pdf_heat_map`] shows for `view`, and the backdrop's share of its pixels.
    fn guide_backdrop_mass(&self, view: usize) -> Option<(f64, f64)> {
        let (train_view, distribution) = self.nearest_distribution(view)?;
        let mask = self.data.scene.views[train_view].mask.as_ref()?;
        let camera = distribution.camera();
        let (mut mass, mut total, mut backdrop) = (0.0, 0.0, 0usize);
        for row in 0..camera.height {
            for col in 0..camera.width {
                let p = distribution.pdf_pixel(camera.pixel_center(col, row));
                total += p;
                if !mask.get(col, row) {
                    mass += p;
                    backdrop += 1;
                }
            }
        }
        let pixels = f64::from(camera.width) * f64::from(camera.height);
        (total > 0.0).then(|| (mass / total, backdrop as f64 / pixels))
    }
}
