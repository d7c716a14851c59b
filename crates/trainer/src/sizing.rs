//! The model sized by the data (`model.grid = "footprint"`): the hash grid's finest resolution
//! from how much of the scene one pixel of the training views covers, so that sharper photos get
//! a finer grid and coarse ones do not pay for cells no pixel can resolve.
//!
//! - **Footprint**: the median, over the scene's views that have it in front, of the side of one
//!   pixel at the region of interest's centre (the origin of the normalised frame, where the
//!   object is; [`camera_geom::PinholeCamera::pixel_footprint_at`]).
//! - **Finest resolution**: the cells of side `pixels_per_cell · footprint` across the bound's
//!   side of 2, `N = 2 / (pixels_per_cell · footprint)`, at least twice the preset's coarsest and
//!   at most [`MAX_FINEST`].
//! - **Levels**: the preset's coarsest resolution and level spacing, as many levels as reach `N`
//!   ([`sdf_backbone::HashGridConfig::reaching`]).
//! - **Table**: a surface crosses about `N²` cells of the finest level, so the preset's table
//!   grows (or shrinks) with `(N / N_preset)²`, within 2¹⁴ … 2²⁴ entries per level; the memory
//!   model sees the result before anything is allocated.
//!
//! The footprint is taken over all views (training and held out alike), from the cameras alone,
//! so the memory check before loading and the trainer after it size the same model.

use crate::bail;
use crate::config::{GridSize, MeshResolution, ModelConfig};
use crate::error::Result;
use camera_geom::PinholeCamera;
use glam::DVec3;
use sdf_backbone::{Backbone, HashGridConfig};

/// The finest resolution a grid sized by the footprint may have (DTU at 1600 × 1200 asks ≈ 2 000).
pub const MAX_FINEST: u32 = 4096;

/// The smallest and largest table of a grid sized by the footprint or given by
/// `model.log2_table`, as log₂ of entries per level.
pub const LOG2_TABLE_RANGE: (u32, u32) = (14, 24);

/// The largest radius [`initial_sphere_radius`] gives (NeuS's geometric initialisation).
pub const MAX_INITIAL_RADIUS: f64 = 0.5;

/// The share of a view's half field of view (towards its nearest image edge) that the initial
/// sphere may cover.
pub const INITIAL_SPHERE_SHARE: f64 = 0.5;

/// The radius of the initial sphere (at the region of interest's centre) that leaves every view
/// room around it: its angular radius from each camera outside the bound at most
/// [`INITIAL_SPHERE_SHARE`] of the angle from the centre's pixel to the nearest image edge, and
/// at most [`MAX_INITIAL_RADIUS`]. Without masks a sphere that fills a view is a wall in front of
/// everything it sees: the network paints the backdrop on it, and carving it away later carves
/// the object with it (docs/DECISIONS.md §32). `None` when no camera outside the bound sees the
/// centre.
pub fn initial_sphere_radius<'a>(cameras: impl IntoIterator<Item = &'a PinholeCamera>) -> Option<f64> {
    let mut radius: Option<f64> = None;
    for camera in cameras {
        let distance = camera.center_in_world().length();
        let p = camera.pixel_space_from_world(DVec3::ZERO);
        if distance <= 1.0 || p.z <= 0.0 {
            continue;
        }
        let (w, h) = (f64::from(camera.width), f64::from(camera.height));
        let margin = p.x.min(w - p.x).min(p.y).min(h - p.y);
        if margin <= 0.0 {
            continue;
        }
        let k = &camera.intrinsics;
        let angle = (margin / k.fx.max(k.fy)).atan() * INITIAL_SPHERE_SHARE;
        let r = distance * angle.sin();
        radius = Some(radius.map_or(r, |best| best.min(r)));
    }
    radius.map(|r| r.min(MAX_INITIAL_RADIUS))
}

/// Median pixel footprint at the region of interest's centre over the cameras that have it in
/// front (`None`: no camera does).
pub fn median_footprint<'a>(cameras: impl IntoIterator<Item = &'a PinholeCamera>) -> Option<f64> {
    let mut footprints: Vec<f64> = cameras.into_iter().filter_map(|c| c.pixel_footprint_at(DVec3::ZERO)).filter(|f| f.is_finite()).collect();
    if footprints.is_empty() {
        return None;
    }
    footprints.sort_by(f64::total_cmp);
    let n = footprints.len();
    Some(if n % 2 == 1 { footprints[n / 2] } else { 0.5 * (footprints[n / 2 - 1] + footprints[n / 2]) })
}

/// A grid sized by the footprint, with what it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct GridChoice {
    /// The grid the model gets.
    pub grid: HashGridConfig,
    /// The preset's grid it replaces.
    pub preset: HashGridConfig,
    /// The median pixel footprint at the region of interest (normalised units).
    pub footprint: f64,
    /// Pixels per finest cell asked.
    pub pixels_per_cell: f64,
}

impl GridChoice {
    /// One line for the run's log: the choice and why.
    pub fn describe(&self) -> String {
        let (g, p) = (&self.grid, &self.preset);
        format!(
            "hash grid sized by the footprint: a pixel spans {:.5} at the region of interest (median over the views) → finest {} at {} pixel(s) per cell: {} levels {} → {}, 2^{} entries per level (the preset's: {} levels {} → {}, 2^{})",
            self.footprint,
            g.finest_resolution,
            self.pixels_per_cell,
            g.levels,
            g.base_resolution,
            g.finest_resolution,
            g.log2_table,
            p.levels,
            p.base_resolution,
            p.finest_resolution,
            p.log2_table
        )
    }
}

/// One line for the run's log when the model keeps its preset's hash grid (`model.grid =
/// "preset"`): how the finest cell compares with the photos' pixel footprint at the region of
/// interest, and the grid `model.grid = "footprint"` would give. A finest cell many pixels wide
/// leaves detail the photos hold unmodelled (DTU at full resolution: ≈ 8 pixels a cell); one far
/// below a pixel models more than the photos can tell. `None` without a hash grid or a footprint.
pub fn describe_preset_grid(model: &ModelConfig, footprint: Option<f64>) -> Option<String> {
    if model.grid != GridSize::Preset {
        return None;
    }
    let preset = model.preset.hash_grid()?;
    let footprint = footprint.filter(|f| *f > 0.0)?;
    let sized = grid_choice(&ModelConfig { grid: GridSize::Footprint, ..model.clone() }, Some(footprint)).ok()??;
    let cell = 2.0 / f64::from(preset.finest_resolution);
    let g = &sized.grid;
    Some(format!(
        "the preset's hash grid, {} levels {} → {}, 2^{} entries per level: a finest cell spans {cell:.5}, a pixel {footprint:.5} at the region of interest (median over the views), {:.1} pixel(s) per finest cell; model.grid = \"footprint\" would give {} levels {} → {}, 2^{} entries per level ({} pixel(s) per cell)",
        preset.levels,
        preset.base_resolution,
        preset.finest_resolution,
        model.log2_table.unwrap_or(preset.log2_table),
        cell / footprint,
        g.levels,
        g.base_resolution,
        g.finest_resolution,
        g.log2_table,
        model.pixels_per_cell
    ))
}

/// The grid `model` asks for on views whose median footprint is `footprint`: `None` for the
/// preset's own grid, an error when the footprint is needed and there is none.
pub fn grid_choice(model: &ModelConfig, footprint: Option<f64>) -> Result<Option<GridChoice>> {
    if model.grid == GridSize::Preset {
        return Ok(None);
    }
    let Some(preset) = model.preset.hash_grid() else {
        bail!(Config, "model.grid = \"footprint\" needs a hash-grid preset (neuralangelo-cpu, neuralangelo), not {}", model.preset.name());
    };
    let Some(footprint) = footprint.filter(|f| *f > 0.0) else {
        bail!(Config, "model.grid = \"footprint\": no view has the region of interest's centre in front of its camera; use model.grid = \"preset\"");
    };
    let wanted = 2.0 / (model.pixels_per_cell * footprint);
    let finest = wanted.round().clamp(f64::from(2 * preset.base_resolution), f64::from(MAX_FINEST)) as u32;
    let growth = 2.0 * (f64::from(finest) / f64::from(preset.finest_resolution)).log2();
    let grown = (f64::from(preset.log2_table) + growth).round().clamp(f64::from(LOG2_TABLE_RANGE.0), f64::from(LOG2_TABLE_RANGE.1)) as u32;
    let log2_table = model.log2_table.unwrap_or(grown);
    Ok(Some(GridChoice { grid: preset.reaching(finest, log2_table), preset, footprint, pixels_per_cell: model.pixels_per_cell }))
}

/// The marching-cubes resolution `output.mesh_resolution` asks for on a model `model` and views
/// of median footprint `footprint`: the number given, or for `"model"` the finest level of the
/// run's hash grid (the preset's, or the one sized by the footprint), for a preset without a
/// hash grid the footprint's resolution `2 / (pixels_per_cell · footprint)`; within 64 …
/// [`MAX_MESH_RESOLUTION`].
pub fn mesh_resolution(resolution: MeshResolution, model: &ModelConfig, footprint: Option<f64>) -> Result<u32> {
    if let MeshResolution::Cells(n) = resolution {
        return Ok(n);
    }
    let finest = match (grid_choice(model, footprint)?, model.preset.hash_grid()) {
        (Some(choice), _) => f64::from(choice.grid.finest_resolution),
        (None, Some(preset)) => f64::from(preset.finest_resolution),
        (None, None) => match footprint.filter(|f| *f > 0.0) {
            Some(f) => (2.0 / (model.pixels_per_cell * f)).round(),
            None => bail!(
                Config,
                "output.mesh_resolution = \"model\" on {}: no hash grid, and no view has the region of interest's centre in front of its camera; give a number of cells",
                model.preset.name()
            ),
        },
    };
    Ok(finest.clamp(64.0, f64::from(MAX_MESH_RESOLUTION)) as u32)
}

/// The finest mesh `output.mesh_resolution = "model"` makes (cells per side).
pub const MAX_MESH_RESOLUTION: u32 = 2048;

/// The run's networks without parameters: the preset's, on the grid sized by the footprint when
/// the configuration asks for one (the memory model's view of the trainer's backbone).
pub fn architecture(model: &ModelConfig, footprint: Option<f64>) -> Result<Backbone> {
    let mut backbone = sdf_backbone::architecture_varied(model.preset, &variation(model, grid_choice(model, footprint)?.as_ref()))?;
    backbone.set_products(model.products.into());
    Ok(backbone)
}

/// What the configuration changes of its preset's networks: the grid sized by the footprint
/// (`grid`, from [`grid_choice`], which has `model.log2_table` in it) or the preset's grid with
/// the table `model.log2_table`, and `model.sdf_layers`.
pub fn variation(model: &ModelConfig, grid: Option<&GridChoice>) -> sdf_backbone::Variation {
    let preset_with_table = || model.log2_table.and_then(|log2_table| model.preset.hash_grid().map(|g| HashGridConfig { log2_table, ..g }));
    sdf_backbone::Variation { grid: grid.map(|choice| choice.grid.clone()).or_else(preset_with_table), sdf_layers: model.sdf_layers }
}

/// The parameters a 64 × 64 hidden layer (and its bias) adds: what the neuralangelo-cpu SDF
/// network lost with docs/DECISIONS.md §39.
const SECOND_SDF_LAYER: usize = 64 * 65;

/// A checkpoint that does not fit the run's networks, named: a neuralangelo-cpu run made before
/// its SDF network had one hidden layer (§39) has one 64 × 64 layer more than this build makes
/// of its configuration, and only a build from before can resume or evaluate it.
pub fn explain_size_mismatch(model: &ModelConfig, error: sdf_backbone::BackboneError) -> crate::Error {
    match error {
        sdf_backbone::BackboneError::SizeMismatch { found, expected, .. }
            if model.preset == sdf_backbone::Preset::NeuralangeloCpu && model.sdf_layers.is_none() && found == expected + SECOND_SDF_LAYER =>
        {
            crate::Error::Input(format!(
                "{error}: the run was made by a build whose neuralangelo-cpu SDF network had two hidden layers (before docs/DECISIONS.md §39); resume or evaluate it with such a build (its mesh and metrics.json stand)"
            ))
        }
        error => error.into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use camera_geom::{Intrinsics, PixelCenters};

    #[test]
    fn the_preset_grid_is_described_against_the_photos_footprint() {
        let model = ModelConfig::default();
        // A pixel of 2/512 against the preset's finest cell of 2/256: two pixels a cell, and a
        // grid sized at one pixel a cell reaches 512 with a table 2² times as large.
        let line = describe_preset_grid(&model, Some(2.0 / 512.0)).unwrap();
        assert!(line.contains("8 levels 16 → 256") && line.contains("2.0 pixel(s) per finest cell"), "{line}");
        assert!(line.contains("→ 512, 2^18 entries per level (1 pixel(s) per cell)"), "{line}");
        assert_eq!(describe_preset_grid(&model, None), None);
        let sized = ModelConfig { grid: GridSize::Footprint, ..ModelConfig::default() };
        assert_eq!(describe_preset_grid(&sized, Some(0.004)), None, "a sized grid has its own line");
    }

    #[test]
    fn a_checkpoint_of_the_two_layer_sdf_network_is_named() {
        let model = crate::config::TrainConfig::default().model;
        let mismatch = |found, expected| sdf_backbone::BackboneError::SizeMismatch { name: "params".into(), found, expected };
        let text = explain_size_mismatch(&model, mismatch(799_414, 795_254)).to_string();
        assert!(text.contains("two hidden layers") && text.contains("799414"), "{text}");
        // Any other mismatch, or a run that names its depth, keeps the plain message.
        assert!(!explain_size_mismatch(&model, mismatch(1000, 795_254)).to_string().contains("two hidden layers"));
        let mut given = model.clone();
        given.sdf_layers = std::num::NonZeroUsize::new(1);
        assert!(!explain_size_mismatch(&given, mismatch(799_414, 795_254)).to_string().contains("two hidden layers"));
        // The layer's size is what the preset's networks say it is.
        let two = crate::config::TrainConfig::load(None, &["model.sdf_layers=2".to_string()]).unwrap().model;
        let count = |m: &ModelConfig| architecture(m, None).unwrap().n_params::<f32>();
        assert_eq!(count(&two), count(&model) + SECOND_SDF_LAYER);
    }

    fn camera(eye: DVec3, focal: f64) -> PinholeCamera {
        let k = Intrinsics { fx: focal, fy: focal, cx: 200.0, cy: 150.0, skew: 0.0 };
        PinholeCamera::look_at(eye, DVec3::ZERO, DVec3::Z, k, 400, 300, PixelCenters::Integer).unwrap()
    }

    #[test]
    fn the_initial_sphere_leaves_every_view_room_around_it() {
        // Focal 540 for 300 rows: 150 px to the nearest edge = 15.5° from the centre.
        let far = [camera(DVec3::new(0.0, -4.0, 0.0), 540.0), camera(DVec3::new(3.0, 3.0, 1.5), 540.0)];
        assert_eq!(initial_sphere_radius(&far), Some(MAX_INITIAL_RADIUS), "far cameras keep NeuS's 0.5");
        // A looser bound: the same views 1.6 times closer to the centre.
        let near: Vec<PinholeCamera> = far.iter().map(|c| camera(c.center_in_world() / 1.6, 540.0)).collect();
        assert!(initial_sphere_radius(&near).unwrap() < MAX_INITIAL_RADIUS);
        let r = initial_sphere_radius(&near).unwrap();
        for c in &near {
            let d = c.center_in_world().length();
            let half_view = (150.0f64 / 540.0).atan();
            assert!((r / d).asin() <= INITIAL_SPHERE_SHARE * half_view + 1e-12, "the sphere covers at most its share of the view");
        }
        assert!((0.3..0.35).contains(&r), "{r}");
        // A camera inside the bound or looking away says nothing.
        let inside = camera(DVec3::new(0.0, -0.9, 0.0), 540.0);
        assert_eq!(initial_sphere_radius(std::slice::from_ref(&inside)), None);
        assert_eq!(initial_sphere_radius(&[inside, far[0]]), Some(MAX_INITIAL_RADIUS));
    }

    #[test]
    fn an_automatic_initial_radius_is_neus_own_with_masks() {
        use crate::config::InitRadius;
        let near = [camera(DVec3::new(0.0, -1.75, 0.0), 540.0)];
        assert_eq!(InitRadius::Auto.resolve(&near, true), MAX_INITIAL_RADIUS);
        assert!(InitRadius::Auto.resolve(&near, false) < 0.25);
        assert_eq!(InitRadius::Radius(0.4).resolve(&near, false), 0.4);
    }

    fn footprint_model() -> ModelConfig {
        ModelConfig { grid: GridSize::Footprint, ..ModelConfig::default() }
    }

    #[test]
    fn footprint_is_the_median_over_the_cameras_that_face_the_centre() {
        let cams = [camera(DVec3::new(0.0, -2.0, 0.5), 500.0), camera(DVec3::new(0.0, -3.0, 0.5), 500.0), camera(DVec3::new(0.0, -4.0, 0.5), 500.0)];
        let f = median_footprint(&cams).unwrap();
        assert!((f - DVec3::new(0.0, -3.0, 0.5).length() / 500.0).abs() < 1e-12);
        // A camera looking away from the centre does not count.
        let away = PinholeCamera::look_at(
            DVec3::new(0.0, -2.0, 0.0),
            DVec3::new(0.0, -5.0, 0.0),
            DVec3::Z,
            cams[0].intrinsics,
            400,
            300,
            PixelCenters::Integer,
        )
        .unwrap();
        assert_eq!(median_footprint(&[away]), None);
        assert_eq!(median_footprint(&[]), None);
    }

    /// Twice the focal length (sharper photos of the same object) doubles the finest
    /// resolution and quadruples the table; the preset keeps its grid; a missing footprint and a
    /// positional preset are refused with the key named.
    #[test]
    fn sharper_views_get_a_finer_grid() {
        let model = footprint_model();
        let at = |footprint: f64| grid_choice(&model, Some(footprint)).unwrap().unwrap().grid;
        let (coarse, fine) = (at(2.0 / 256.0), at(1.0 / 256.0));
        assert_eq!(coarse, HashGridConfig::neuralangelo_cpu());
        assert_eq!((fine.finest_resolution, fine.log2_table, fine.levels), (512, 18, 10));
        let half = grid_choice(&ModelConfig { pixels_per_cell: 2.0, ..footprint_model() }, Some(1.0 / 256.0)).unwrap().unwrap().grid;
        assert_eq!(half, coarse);
        assert_eq!(at(1e-6).finest_resolution, MAX_FINEST);
        assert_eq!(at(1.0).finest_resolution, 32);
        assert_eq!(grid_choice(&ModelConfig::default(), Some(1e-3)).unwrap(), None);
        assert!(grid_choice(&model, None).unwrap_err().to_string().contains("model.grid"));
        let neus = ModelConfig { preset: sdf_backbone::Preset::NeusCpu, ..footprint_model() };
        assert!(grid_choice(&neus, Some(1e-3)).unwrap_err().to_string().contains("hash-grid preset"));
        let backbone = architecture(&model, Some(1.0 / 256.0)).unwrap();
        assert!(backbone.n_params::<f32>() > sdf_backbone::architecture(model.preset).n_params::<f32>());
    }

    /// `"model"` meshes at the finest level of the run's grid (sized or the preset's), a
    /// positional preset at the footprint's resolution, a number as given; a positional preset
    /// without a footprint is refused naming the key.
    #[test]
    fn a_mesh_as_fine_as_the_model_follows_its_finest_level() {
        let model = footprint_model();
        let at = |model: &ModelConfig, footprint| mesh_resolution(MeshResolution::Model, model, footprint);
        assert_eq!(at(&model, Some(1.0 / 256.0)).unwrap(), 512);
        assert_eq!(at(&ModelConfig::default(), Some(1.0 / 256.0)).unwrap(), 256);
        assert_eq!(at(&ModelConfig::default(), None).unwrap(), 256);
        let neus = ModelConfig { preset: sdf_backbone::Preset::NeusCpu, ..ModelConfig::default() };
        assert_eq!(at(&neus, Some(2.0 / 300.0)).unwrap(), 300);
        assert_eq!(at(&neus, Some(1e-6)).unwrap(), MAX_MESH_RESOLUTION);
        assert!(at(&neus, None).unwrap_err().to_string().contains("output.mesh_resolution"));
        assert_eq!(mesh_resolution(MeshResolution::Cells(100), &model, None).unwrap(), 100);
    }
}
