//! What a trainer renders and meshes: views, pdf heat maps, per-view metrics, the mesh and its
//! filters and colours (no gradient, the rays through the same pipeline).

use super::Trainer;
use crate::bail;
use crate::config::MeshFilter;
use crate::error::{Context, Result};
use crate::outputs::{ViewRender, filter_components, heat_map};
use datasets::images::RgbImage;
use prob_grid::{IsoMesh, MarchingCubesConfig, Occupancy, marching_cubes_with_progress};
use rayon::prelude::*;
use sdf_backbone::{RayInput, RayOutput, Trim};
use std::hash::Hasher;
use std::sync::Arc;
use view_sampler::march_through_with;

/// A render's occupancy ([`Trainer::render_occupancy`]) and the Lipschitz bound of the field it
/// was made of.
pub(crate) struct RenderOccupancy {
    occupancy: Occupancy,
    lipschitz: f32,
}

/// Rays per work item of a render. Each work item packs the networks' weights for its passes
/// (the colour network's, the learned background's with its first layer folded per sample) and
/// runs each pass on all its rays at once: at 64 rays the packing and the per-pass set-up were
/// a sixth of a render without masks (DECISIONS §59).
pub(crate) const RENDER_CHUNK: usize = 256;

/// The most pixels a render takes at once ([`Trainer::render_view`]): a 1600 × 1200 view taken
/// whole held ≈ 1.2 GB of rays, depths and SDF values (≈ 650 bytes a pixel).
pub const RENDER_BAND_RAYS: usize = 1 << 16;

impl Trainer {
    /// Changes how renders sample and evaluate (`render.render_fine`, `render_upsample_rounds`,
    /// `render_trim`, `render_resolved`, `render_skip_empty`, `render_colour_stride`) by `edit`: what a render costs
    /// and resolves, not what the model learnt, so a finished run can be re-rendered with others
    /// (`cargo xtask eval --run DIR --render-fine N …`). The changed configuration is validated
    /// before it is taken.
    pub fn set_render_sampling(&mut self, edit: impl FnOnce(&mut crate::config::RenderConfig)) -> Result<()> {
        let mut config = self.config.clone();
        edit(&mut config.render);
        config.validate()?;
        self.config = config;
        Ok(())
    }

    /// Renders `rays` forward only, in parallel chunks, given the SDF at every depth of every
    /// ray (`None`: evaluated here), dropping what carries at most `render.render_trim` of a
    /// ray's colour, the colour networks on every `render.render_colour_stride`-th kept interval
    /// ([`sdf_backbone::Backbone::render`]).
    pub fn render_rays(&self, rays: &[RayInput<f32>], sdf: Option<Vec<Vec<f32>>>) -> Vec<RayOutput<f32>> {
        let params = &self.state.params;
        let sdf = sdf.unwrap_or_else(|| self.backbone.sdf_along(params, rays));
        let (negligible, stride) = (self.config.render.render_trim as f32, self.config.render.render_colour_stride);
        rays.par_chunks(RENDER_CHUNK)
            .zip(sdf.par_chunks(RENDER_CHUNK))
            .flat_map_iter(|(rays, sdf)| self.backbone.render(params, rays, sdf, negligible, stride))
            .collect()
    }

    /// The camera of view `index` at 1/`downscale` resolution (each pixel an n × n block of the
    /// view's, the remainder rows and columns dropped, as the images' own downscale does).
    pub fn downscaled_camera(&self, index: usize, downscale: u32) -> Result<camera_geom::PinholeCamera> {
        let view = &self.data.scene.views[index];
        if downscale == 0 {
            bail!(Input, "a render's downscale must be ≥ 1");
        }
        let c = &view.camera;
        let k = c.intrinsics.downscaled(downscale, c.pixel_centers);
        camera_geom::PinholeCamera::new(k, c.width / downscale, c.height / downscale, c.camera_from_world, c.pixel_centers)
            .with_context(|| format!("view {:?} ({}×{}) rendered at downscale {downscale}", view.name, c.width, c.height))
    }

    /// Renders view `view` of the scene at 1/`downscale` resolution (the estimator's coarse
    /// samples without jitter, up-sampled), with its targets and mask, in bands of rows of at
    /// most [`RENDER_BAND_RAYS`] pixels.
    pub fn render_view(&self, index: usize, downscale: u32) -> Result<ViewRender> {
        self.render_view_in_bands(index, downscale, RENDER_BAND_RAYS)
    }

    /// [`Trainer::render_view`] in bands of whole rows of at most `band_rays` pixels (at least
    /// one row): each band's rays, depths and SDF values are dropped before the next, so that a
    /// render's working set is a band's, whatever the image's size; every ray is rendered alone,
    /// so the bands do not change the result.
    pub(crate) fn render_view_in_bands(&self, index: usize, downscale: u32, band_rays: usize) -> Result<ViewRender> {
        let camera = self.downscaled_camera(index, downscale)?;
        let view = &self.data.scene.views[index];
        let image = view.image.downscaled(downscale);
        let mask = view.mask.as_ref().map(|m| m.downscaled(downscale));
        let (width, height) = (image.width, image.height);
        let occupancy = if self.config.render.render_skip_empty { Some(self.render_occupancy()?) } else { None };
        let rows_per_band = (band_rays / width.max(1) as usize).clamp(1, height.max(1) as usize) as u32;
        let mut outputs = Vec::with_capacity((width * height) as usize);
        for first in (0..height).step_by(rows_per_band as usize) {
            outputs.extend(self.render_rows(&camera, first..(first + rows_per_band).min(height), occupancy.as_deref()));
        }
        let pixels = || (0..height).flat_map(|r| (0..width).map(move |c| (c, r)));
        let target = pixels().map(|(c, r)| image.get_f32(c, r)).collect();
        let mask = mask.map(|m| pixels().map(|(c, r)| m.get(c, r)).collect());
        Ok(ViewRender { width, height, outputs, target, mask })
    }

    /// The outputs of the pixels of `rows` (row-major) seen by `camera`: the estimator's coarse
    /// samples without jitter through `occupancy` (else the estimator's), up-sampled and trimmed
    /// where they cross occupied space (not up-sampled where their coarse values and the
    /// occupancy's Lipschitz bound prove them faint: [`sdf_backbone::proven_faint`]); a ray
    /// that crosses no occupied cell has no interval at all (opacity 0: nothing along it can
    /// carry weight), only the background, and no SDF is evaluated for it.
    fn render_rows(
        &self,
        camera: &camera_geom::PinholeCamera,
        rows: std::ops::Range<u32>,
        render_occupancy: Option<&RenderOccupancy>,
    ) -> Vec<RayOutput<f32>> {
        let occupancy = render_occupancy.map(|o| &o.occupancy);
        let r = &self.config.render;
        let width = camera.width;
        // The render's own occupancy, else the estimator's (training with skipping).
        let marched = occupancy.or(self.estimator.occupancy());
        let (mut rays, hits): (Vec<RayInput<f32>>, Vec<bool>) = rows
            .into_par_iter()
            .flat_map_iter(|row| (0..width).map(move |col| (col, row)))
            .map_init(
                || (Vec::new(), Vec::with_capacity(r.coarse + 1)),
                |(segments, scratch), (col, row)| {
                    let ray = camera.ray_through_pixel_index(col, row);
                    let crosses = march_through_with(marched, ray.origin, ray.direction, r.coarse, 0.5, segments, scratch);
                    let empty = occupancy.is_some() && !crosses;
                    // An empty ray's depths are not needed: no allocation for it.
                    let depths = if empty { Vec::new() } else { scratch.clone() };
                    let (origin, direction) = (ray.origin.as_vec3().to_array(), ray.direction.as_vec3().to_array());
                    (RayInput { origin, direction, depths, target: [0.0; 3], mask: None, weight: 1.0 }, !empty)
                },
            )
            .unzip();
        // Up-sampling and the trim for the rays that cross occupied space, the SDF at every
        // depth kept for the render.
        let index: Vec<usize> = (0..rays.len()).filter(|&i| hits[i]).collect();
        let mut crossing: Vec<RayInput<f32>> =
            index.iter().map(|&i| RayInput { depths: std::mem::take(&mut rays[i].depths), ..rays[i].clone() }).collect();
        let (params, fine, rounds) = (&self.state.params, r.render_fine, r.render_upsample_rounds);
        let lipschitz = render_occupancy.map(|o| o.lipschitz);
        let resolved = r.resolved_applied().map(|most| most as f32);
        let trim = (r.render_trim > 0.0).then(|| Trim { s: self.s() as f32, negligible: r.render_trim as f32, lipschitz, resolved });
        let values = self.backbone.upsample_for_render(params, &mut crossing, fine, rounds, r.upsample_s, trim);
        // An empty ray: no depths, no values.
        let mut sdf = vec![Vec::new(); rays.len()];
        for ((ray, values), &i) in crossing.into_iter().zip(values).zip(&index) {
            rays[i] = ray;
            sdf[i] = values;
        }
        self.render_rays(&rays, Some(sdf))
    }

    /// The guide's distribution of the training camera nearest in index to `view`, with that
    /// camera's view index (`None` before the first guide update or without a guide).
    pub(super) fn nearest_distribution(&self, view: usize) -> Option<(usize, &view_sampler::CameraDistribution)> {
        let distributions = self.estimator.distributions();
        if distributions.is_empty() {
            return None;
        }
        let i = self.split.train.iter().position(|&v| v >= view).unwrap_or(0).min(distributions.len() - 1);
        Some((self.split.train[i], &distributions[i]))
    }

    /// The pixel marginal of the guide for the training camera nearest in index to `view`.
    pub fn pdf_heat_map(&self, view: usize) -> Option<RgbImage> {
        let (_, distribution) = self.nearest_distribution(view)?;
        let (ru, rv, _) = distribution.resolution();
        Some(heat_map(&distribution.pixel_marginal(), ru, rv, 4))
    }

    /// The zero level set of the current SDF (normalised frame) at [`Self::mesh_resolution`],
    /// components filtered by `output.mesh_filter`; `progress(blocks done, blocks)`.
    pub fn extract_mesh(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<IsoMesh> {
        Ok(self.extract_mesh_with_stats(progress)?.0)
    }

    /// The occupancy of the current field at the current s on the guide's scene grid (dilated by
    /// `render.occupancy_dilation`, at least one cell), for renders (`render.render_skip_empty`):
    /// made once for all the views rendered of one field, keyed by a hash of the parameters'
    /// bits, the active hash-grid levels, the field's Lipschitz bound and the dilation (the scene
    /// grid does not change in a trainer's life), so that no change of the model can reuse a
    /// stale one. It carries the Lipschitz bound its evaluation checked (the claim, raised where
    /// the evaluation measured a steeper slope), which proves rays faint ([`Trim`]).
    fn render_occupancy(&self) -> Result<Arc<RenderOccupancy>> {
        let key = {
            let mut h = std::hash::DefaultHasher::new();
            h.write_u64(parameters_digest(&self.state.params));
            h.write_u32(self.config.render.occupancy_dilation);
            h.write_u32(self.estimator.lipschitz_bound().to_bits());
            // The finest active hash-grid level (coarse to fine changes the field, not the
            // parameters), through the normal step tied to it.
            h.write_u64(self.backbone.config.normal_step.to_bits());
            h.finish()
        };
        let mut cache = self.render_occupancy.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if let Some((k, occupancy)) = cache.as_ref()
            && *k == key
        {
            return Ok(Arc::clone(occupancy));
        }
        let mut field = self.backbone.field(&self.state.params);
        field.lipschitz = self.estimator.lipschitz_bound();
        let scene = &self.config.guide.scene;
        let active = prob_grid::evaluate(&field, self.s() as f32, scene).context("the occupancy of a render")?;
        let occupancy = Occupancy::from_active(&active, scene, self.config.render.occupancy_dilation.max(1)).clipped_to_occupied();
        let occupancy = Arc::new(RenderOccupancy { occupancy, lipschitz: active.lipschitz.used.max(active.lipschitz.measured) });
        *cache = Some((key, Arc::clone(&occupancy)));
        Ok(occupancy)
    }

    /// PSNR (whole image, inside the mask) and SSIM of view `view` rendered at `downscale`.
    pub fn view_metrics(&self, view: usize, downscale: u32) -> Result<(f64, Option<f64>, Option<f64>)> {
        let render = self.render_view(view, downscale)?;
        let (whole, masked) = render.psnr();
        Ok((whole, masked, render.ssim()))
    }

    /// Meshes this trainer's model at `resolution` from now on (`"model"` resolved as
    /// `output.mesh_resolution` is: the model's finest cell), without changing the run's
    /// configuration — a finished run meshed again at another resolution
    /// ([`crate::run::remesh`]). Returns the cells per side.
    pub fn set_mesh_resolution(&mut self, resolution: crate::config::MeshResolution) -> Result<u32> {
        let resolution = resolution.checked().map_err(crate::Error::Config)?;
        self.mesh_resolution = crate::sizing::mesh_resolution(resolution, &self.config.model, self.footprint)?;
        Ok(self.mesh_resolution)
    }

    /// [`Self::extract_mesh`] with (components found, components kept).
    pub fn extract_mesh_with_stats(&self, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<(IsoMesh, usize, usize)> {
        let mc = MarchingCubesConfig { resolution: self.mesh_resolution, block: 16, ..Default::default() };
        let mut field = self.backbone.field(&self.state.params);
        field.lipschitz = self.estimator.lipschitz_bound();
        let (mesh, _) = marching_cubes_with_progress(&field, &mc, progress)?;
        Ok(self.filter_mesh(&mesh, self.config.output.mesh_filter))
    }

    /// `mesh` with its components filtered by `filter` (see [`MeshFilter`]): (mesh, found, kept).
    pub fn filter_mesh(&self, mesh: &IsoMesh, filter: MeshFilter) -> (IsoMesh, usize, usize) {
        filter_components(mesh, filter, &self.data.scene, &self.split.train, self.use_masks, self.config.output.min_component_area)
    }

    /// Vertex colours: each vertex rendered by a short ray coming to it along its normal.
    pub fn vertex_colors(&self, mesh: &IsoMesh) -> Vec<[u8; 3]> {
        let normals = prob_grid::vertex_normals(&mesh.vertices, &mesh.triangles);
        let rays: Vec<RayInput<f32>> = mesh
            .vertices
            .iter()
            .zip(&normals)
            .map(|(p, n)| {
                let n = if n.length() > 0.0 { *n } else { glam::Vec3::Z };
                RayInput {
                    origin: (*p + 0.05 * n).to_array(),
                    direction: (-n).to_array(),
                    depths: (0..=16).map(|i| i as f32 * 0.1 / 16.0).collect(),
                    target: [0.0; 3],
                    mask: None,
                    weight: 1.0,
                }
            })
            .collect();
        self.render_rays(&rays, None).iter().map(|o| o.color.map(|c| (c.clamp(0.0, 1.0) * 255.0).round() as u8)).collect()
    }
}

/// A digest of the parameters' bits for [`Trainer::render_occupancy`]'s key, one multiply per
/// pair of values (SipHash over each value was 0.7 % of a render's CPU time on the built-in
/// scene): each step is a bijection of the digest so far, so that parameters that differ in one
/// value always differ in their digest; not a defence against crafted collisions.
fn parameters_digest(params: &[f32]) -> u64 {
    params.chunks(2).fold(0x243F_6A88_85A3_08D3, |h, pair| {
        let word = u64::from(pair[0].to_bits()) | u64::from(pair.get(1).map_or(0, |v| v.to_bits())) << 32;
        (h ^ word).wrapping_mul(0x9E37_79B9_7F4A_7C15).rotate_left(29)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Budget, TrainConfig};
    use crate::data::SceneData;

    /// `model.products` reaches the trainer's networks (it once reached only the memory model's).
    #[test]
    fn the_trainers_networks_run_the_configured_products() {
        for (products, expected) in
            [(crate::config::Products::F32, sdf_backbone::Products::F32), (crate::config::Products::Bf16, sdf_backbone::Products::Bf16Hidden)]
        {
            let mut config = TrainConfig { budget: Budget::Steps(1), ..TrainConfig::default() };
            config.data.builtin.width = 48;
            config.model.products = products;
            let data = SceneData::builtin(&config).unwrap();
            let trainer = Trainer::new(config, data).unwrap();
            assert_eq!((trainer.backbone.sdf.b.products(), trainer.backbone.color.products()), (expected, expected));
        }
    }

    /// The guard on the foreground (`model.opacity_guard`) reaches the trainer's pipeline
    /// without masks, where a learned background exists to compare with, and not with masks;
    /// off by default.
    #[test]
    fn the_guard_on_the_foreground_runs_only_without_masks() {
        let guard = |weight| Some(sdf_backbone::OpacityGuard { weight, tolerance: None });
        for (masks, setting, expected) in [(false, Some(0.07), guard(0.07)), (true, Some(0.07), None), (false, None, None)] {
            let mut config = TrainConfig { budget: Budget::Steps(1), ..TrainConfig::default() };
            config.data.builtin.width = 48;
            config.data.masks = masks;
            config.model.opacity_guard = setting;
            let data = SceneData::builtin(&config).unwrap();
            let trainer = Trainer::new(config, data).unwrap();
            assert_eq!(trainer.backbone.config.opacity_guard, expected, "masks {masks}, {setting:?}");
            assert_eq!(trainer.backbone.background.is_some(), !masks, "masks {masks}: the learned background");
        }
    }

    /// A trainer of the built-in scene at 48 pixels wide, 64 rays a step, for `steps` steps.
    fn small_trainer(steps: u64) -> Trainer {
        let mut config = TrainConfig { budget: Budget::Steps(steps), ..TrainConfig::default() };
        config.data.builtin.width = 48;
        config.render.rays = 64;
        let data = SceneData::builtin(&config).unwrap();
        Trainer::new(config, data).unwrap()
    }

    /// The renders' occupancy key tells parameters apart that differ in one bit of one value,
    /// wherever it is (odd and even positions, the last of an odd count).
    #[test]
    fn parameters_that_differ_in_one_bit_have_other_digests() {
        let params: Vec<f32> = (0..1001).map(|i| (i as f32 * 0.37).sin()).collect();
        let base = parameters_digest(&params);
        for (i, bit) in [(0, 0), (1, 31), (500, 7), (1000, 22), (999, 0)] {
            let mut changed = params.clone();
            changed[i] = f32::from_bits(changed[i].to_bits() ^ (1 << bit));
            assert_ne!(parameters_digest(&changed), base, "value {i}, bit {bit}");
        }
        assert_ne!(parameters_digest(&params[..1000]), base, "one value fewer");
    }

    /// The renders' occupancy is made once per field: reused while nothing changed, made again
    /// after the parameters or the active hash-grid levels changed.
    #[test]
    fn a_renders_occupancy_is_reused_only_for_the_same_field() {
        let mut trainer = small_trainer(1);
        let first = trainer.render_occupancy().unwrap();
        assert!(Arc::ptr_eq(&first, &trainer.render_occupancy().unwrap()), "the same field reuses its occupancy");
        let mut params = trainer.state().params.clone();
        params[0] += 1e-3;
        trainer.set_parameters(&params).unwrap();
        let second = trainer.render_occupancy().unwrap();
        assert!(!Arc::ptr_eq(&first, &second), "new parameters make a new occupancy");
        let levels = trainer.backbone.levels().expect("the default preset has a hash grid");
        trainer.backbone.set_active_levels(levels - 1);
        assert!(!Arc::ptr_eq(&second, &trainer.render_occupancy().unwrap()), "other active levels make a new occupancy");
    }

    /// Guards the renders' empty-space skipping: a ray that crosses no cell of the render's
    /// occupancy has no interval (no SDF evaluated for it) and renders the background alone
    /// (opacity 0), with masks (a fixed background) and without (the learned one); rendered
    /// without skipping, those rays carry next to nothing of the object.
    #[test]
    fn a_ray_that_crosses_no_occupied_cell_renders_the_background_alone() {
        for masks in [true, false] {
            let mut config = TrainConfig { budget: Budget::Steps(300), ..TrainConfig::default() };
            config.data.builtin.width = 48;
            config.data.masks = masks;
            config.render.rays = 64;
            let data = SceneData::builtin(&config).unwrap();
            let mut trainer = Trainer::new(config, data).unwrap();
            for _ in 0..300 {
                trainer.step().unwrap();
            }
            let skipped = trainer.render_view(1, 1).unwrap();
            let occupancy = trainer.render_occupancy().unwrap();
            let camera = trainer.downscaled_camera(1, 1).unwrap();
            let mut depths = Vec::new();
            let empty: Vec<bool> = (0..camera.height)
                .flat_map(|row| (0..camera.width).map(move |col| (col, row)))
                .map(|(col, row)| {
                    let ray = camera.ray_through_pixel_index(col, row);
                    !view_sampler::march_through(Some(&occupancy.occupancy), ray.origin, ray.direction, 8, 0.5, &mut depths)
                })
                .collect();
            let n_empty = empty.iter().filter(|&&e| e).count();
            assert!(n_empty > empty.len() / 4 && n_empty < empty.len(), "masks {masks}: {n_empty} of {} rays cross no occupied cell", empty.len());
            let background = trainer.config().model.background.map(|c| c as f32);
            trainer.set_render_sampling(|r| r.render_skip_empty = false).unwrap();
            let full = trainer.render_view(1, 1).unwrap();
            for ((out, whole), _) in skipped.outputs.iter().zip(&full.outputs).zip(&empty).filter(|(_, e)| **e) {
                assert_eq!((out.opacity, out.depth), (0.0, 0.0), "masks {masks}");
                if masks {
                    assert_eq!(out.color, background);
                }
                let most = (0..3).map(|k| (out.color[k] - whole.color[k]).abs()).fold(whole.opacity, f32::max);
                assert!(most <= 1e-3, "masks {masks}: a ray that crosses no occupied cell, rendered whole: {whole:?}, skipped: {out:?}");
            }
        }
    }

    /// Guards the bands that bound a render's memory: a view rendered a few rows at a time (bands
    /// that split the rays crossing the object differently into work items) gives the same
    /// outputs as the view at once, for the trained field.
    #[test]
    fn a_view_rendered_in_bands_of_rows_is_the_view_rendered_at_once() {
        let mut trainer = small_trainer(30);
        for _ in 0..30 {
            trainer.step().unwrap();
        }
        let whole = trainer.render_view_in_bands(1, 1, usize::MAX).unwrap();
        for band in [1, 100, 48 * 7] {
            let banded = trainer.render_view_in_bands(1, 1, band).unwrap();
            assert_eq!((banded.width, banded.height, &banded.target, &banded.mask), (whole.width, whole.height, &whole.target, &whole.mask));
            let most = whole
                .outputs
                .iter()
                .zip(&banded.outputs)
                .map(|(a, b)| (a.color[0] - b.color[0]).abs().max((a.opacity - b.opacity).abs()))
                .fold(0.0, f32::max);
            assert!(most <= 1e-6, "bands of {band} pixels: outputs differ by {most}");
        }
    }
}
