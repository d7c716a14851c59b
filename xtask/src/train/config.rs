//! The training configuration: TOML with every knob of the paper and its ablations, unknown keys
//! and out-of-range values rejected with the key named, `key=value` overrides on the command line.

use anyhow::{Context, Result, bail};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Which rays the trainer draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SamplerKind {
    /// The probability-guided sampler with the surface losses and the extra ray points.
    Guided,
    /// Uniform pixels, the plain backbone (same rays and samples per ray).
    Uniform,
}

/// Everything a run needs. Defaults: the built-in scene on a 2-core CPU in ≤ 5 minutes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Seed of every random stream.
    pub seed: u64,
    /// Training iterations.
    pub steps: u64,
    /// Guided or uniform.
    pub sampler: SamplerKind,
    /// Data options.
    pub data: DataConfig,
    /// The backbone.
    pub model: ModelConfig,
    /// Rays and samples.
    pub render: RenderConfig,
    /// Optimiser.
    pub optim: OptimConfig,
    /// The probability-guided sampler.
    pub guide: GuideConfig,
    /// The surface losses.
    pub surface: SurfaceConfig,
    /// Outputs.
    pub output: OutputConfig,
}

/// Data options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Integer downscale of the images (area average; intrinsics follow).
    pub downscale: u32,
    /// Use the dataset's masks (mask BCE loss) when it has them.
    pub masks: bool,
    /// Every n-th view is held out for evaluation (0: none).
    pub holdout_every: usize,
    /// Built-in scene only: image width (height = 3/4 of it).
    pub builtin_width: u32,
    /// Built-in scene only: number of views (DTU-like rig).
    pub builtin_views: usize,
}

/// The backbone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// neuralangelo-cpu, neus-cpu, neuralangelo (paper scale), neus (paper scale).
    pub preset: String,
    /// Radius of the initial sphere.
    pub init_radius: f64,
    /// Hash-grid levels active at the start (coarse-to-fine; Neuralangelo: 4).
    pub initial_levels: usize,
    /// Fraction of the run after which all levels are active.
    pub all_levels_at: f64,
    /// Eikonal weight (NeuS: 0.1).
    pub eikonal: f64,
    /// Mask BCE weight (NeuS: 0.1).
    pub mask: f64,
    /// Curvature loss weight, reached linearly over the learning-rate warm-up (Neuralangelo:
    /// 5e-4; default 0: not measured to help on 300-iteration runs).
    pub curvature: f64,
    /// Normals (and curvature) by "tetrahedral" (4 probes) or "central" (6 probes) differences.
    pub normals: String,
    /// Colour behind the object (fixed background).
    pub background: [f64; 3],
    /// A learned, direction-conditioned background instead of the fixed colour (for captures
    /// without masks).
    pub learned_background: bool,
}

/// Rays and samples per iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Rays per iteration.
    pub rays: usize,
    /// Stratified samples per ray (NeuS: 64).
    pub coarse: usize,
    /// Up-sampled samples per ray (NeuS: 64 in 4 rounds); guided runs give `guide.extra_points`
    /// of them to the points around λ̃, so both samplers use coarse + fine per ray.
    pub fine: usize,
    /// Up-sampling rounds (NeuS: 4).
    pub upsample_rounds: usize,
    /// Scale of the first up-sampling round, doubled each round (NeuS: 64).
    pub upsample_s: f64,
    /// Rays per work item (gradient chunk).
    pub chunk: usize,
}

/// Optimiser.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Learning rate of the MLPs and the variance.
    pub lr: f64,
    /// Learning rate of the hash tables.
    pub lr_grid: f64,
    /// Warm-up iterations.
    pub warmup: u64,
    /// "cosine" (decay to `final_factor`) or "step" (× `step_factor` at each of `milestones`).
    pub schedule: String,
    /// Final learning rate as a fraction of the base (cosine decay).
    pub final_factor: f64,
    /// Step decay: milestones as fractions of the run.
    pub milestones: Vec<f64>,
    /// Step decay: multiplier per milestone.
    pub step_factor: f64,
    /// Clip the gradient's global norm (0: off).
    pub clip_norm: f64,
}

/// The probability-guided sampler (the paper's knobs and ablation switches).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GuideConfig {
    /// Update the camera grids every K iterations.
    pub update_every: u64,
    /// Scene grid cells per axis (paper: 128).
    pub scene_resolution: usize,
    /// Partition factor F (paper: 2; ablation: 1).
    pub partition: u32,
    /// Camera grid cells along u and v (paper: 64).
    pub camera_uv: usize,
    /// Camera grid cells along λ (paper: 128).
    pub camera_depth: usize,
    /// View dependency (VD): opaque, quadrature, paper, off.
    pub view_dependency: String,
    /// FS: a fixed s for the probability update (0: the backbone's current s).
    pub fixed_s: f64,
    /// Fractions of uniform rays over the quarters of the run (paper: 0.2, 0.4, 0.6, 0.8).
    pub uniform_fractions: Vec<f64>,
    /// Extra points per ray around λ̃ (paper: 32).
    pub extra_points: usize,
    /// How the extra points are drawn: gaussian (paper), uniform (RU), log (Log).
    pub extra: String,
}

/// The surface losses (paper Sec. 4.5).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SurfaceConfig {
    /// Weight of L_surf (paper: 500; ablation L: 0 / 10 / 500).
    pub weight: f64,
    /// λ₁ (paper: 0.5).
    pub lambda_near: f64,
    /// λ₂ (paper: 0.5).
    pub lambda_far: f64,
    /// ε of L_empty.
    pub epsilon: f64,
    /// β of L_bg.
    pub beta: f64,
}

/// Outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Validation pictures every n iterations (0: only at the end).
    pub validate_every: u64,
    /// Downscale of the validation renders.
    pub validate_downscale: u32,
    /// Held-out views rendered for the final PSNR (spread over the held-out set).
    pub eval_views: usize,
    /// Training views rendered for the final training-view PSNR (the render-fit figure).
    pub eval_train_views: usize,
    /// Mesh + Chamfer and PSNR of one held-out view every n iterations, logged (0: only at the
    /// end; not counted in the iteration time).
    pub metrics_every: u64,
    /// Checkpoint every n iterations (0: only at the end).
    pub checkpoint_every: u64,
    /// Log scalars every n iterations.
    pub log_every: u64,
    /// Marching-cubes resolution of the final mesh.
    pub mesh_resolution: u32,
    /// Keep only the mesh's largest connected component.
    pub largest_component: bool,
    /// Mesh formats: any of ply, obj, glb.
    pub mesh_formats: Vec<String>,
    /// Vertex colours (rendered along the normal) on the mesh.
    pub vertex_colors: bool,
    /// Spacing of the points sampled on meshes for Chamfer, in input world units per unit of the
    /// normalised frame (relative: multiplied by the scene's scale).
    pub chamfer_spacing: f64,
    /// Chamfer outlier distance (normalised units; DTU: 20 mm ≈ 0.087 of scan 24's radius).
    pub chamfer_max_dist: f64,
    /// F-score threshold τ (normalised units).
    pub fscore_tau: f64,
}

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            seed: 0,
            steps: 300,
            sampler: SamplerKind::Guided,
            data: DataConfig::default(),
            model: ModelConfig::default(),
            render: RenderConfig::default(),
            optim: OptimConfig::default(),
            guide: GuideConfig::default(),
            surface: SurfaceConfig::default(),
            output: OutputConfig::default(),
        }
    }
}

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig { downscale: 1, masks: true, holdout_every: 8, builtin_width: 200, builtin_views: 49 }
    }
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            preset: "neuralangelo-cpu".into(),
            init_radius: 0.5,
            initial_levels: 4,
            all_levels_at: 0.25,
            eikonal: 0.1,
            mask: 0.1,
            curvature: 0.0,
            normals: "tetrahedral".into(),
            background: [0.0; 3],
            learned_background: false,
        }
    }
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig { rays: 256, coarse: 32, fine: 32, upsample_rounds: 2, upsample_s: 64.0, chunk: 32 }
    }
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig {
            lr: 5e-3,
            lr_grid: 1e-2,
            warmup: 20,
            schedule: "cosine".into(),
            final_factor: 0.1,
            milestones: vec![0.5, 0.75],
            step_factor: 0.3,
            clip_norm: 0.0,
        }
    }
}

impl Default for GuideConfig {
    fn default() -> Self {
        GuideConfig {
            update_every: 50,
            scene_resolution: 64,
            partition: 2,
            camera_uv: 32,
            camera_depth: 64,
            view_dependency: "opaque".into(),
            fixed_s: 0.0,
            uniform_fractions: vec![0.2, 0.4, 0.6, 0.8],
            extra_points: 16,
            extra: "gaussian".into(),
        }
    }
}

impl Default for SurfaceConfig {
    /// The paper's λ₁, λ₂ and our ε, β; the weight is 1, not the paper's 500: on the built-in
    /// scene 500 erases the surface within 100 iterations (empty mesh) and 10 costs 0.005 in
    /// Chamfer, while 1 gains over 0 (BENCHMARKS.md). `surface.weight = 500` is the paper's.
    fn default() -> Self {
        let d = surface_losses::SurfaceLossConfig::default();
        SurfaceConfig { weight: 1.0, lambda_near: d.lambda_near, lambda_far: d.lambda_far, epsilon: d.epsilon, beta: d.beta }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            validate_every: 100,
            validate_downscale: 2,
            eval_views: 3,
            eval_train_views: 2,
            metrics_every: 0,
            checkpoint_every: 100,
            log_every: 10,
            mesh_resolution: 192,
            largest_component: true,
            mesh_formats: vec!["ply".into()],
            vertex_colors: false,
            chamfer_spacing: 0.004,
            chamfer_max_dist: 0.1,
            fscore_tau: 0.01,
        }
    }
}

/// Sets `a.b.c = value` in a TOML table; the value is parsed as TOML (`5`, `1e-3`, `true`,
/// `[1, 2]`, `"text"`) and taken as a bare string otherwise.
fn set_dotted(table: &mut toml::Table, key: &str, raw: &str) -> Result<()> {
    let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let mut parts: Vec<&str> = key.split('.').collect();
    let last = parts.pop().filter(|s| !s.is_empty()).with_context(|| format!("override {key:?}: empty key"))?;
    let mut t = table;
    for p in parts {
        t = t
            .entry(p.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()))
            .as_table_mut()
            .with_context(|| format!("override {key:?}: {p:?} is not a section"))?;
    }
    t.insert(last.to_string(), value);
    Ok(())
}

impl TrainConfig {
    /// The defaults, then `file` (if any), then the `key=value` overrides; validated.
    pub fn load(file: Option<&Path>, overrides: &[String]) -> Result<TrainConfig> {
        let mut table = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).with_context(|| format!("cannot read config {}", path.display()))?;
                toml::from_str::<toml::Table>(&text).with_context(|| format!("config {} is not valid TOML", path.display()))?
            }
            None => toml::Table::new(),
        };
        for o in overrides {
            let (k, v) = o.split_once('=').with_context(|| format!("override {o:?} is not key=value"))?;
            set_dotted(&mut table, k.trim(), v.trim())?;
        }
        let origin = file.map_or("the command line".to_string(), |p| format!("{} and the command line", p.display()));
        let config: TrainConfig = table.try_into().map_err(|e: toml::de::Error| anyhow::anyhow!("config from {origin}: {}", e.message()))?;
        config.validate().with_context(|| format!("config from {origin}"))?;
        Ok(config)
    }

    /// Checks every range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        fn need(ok: bool, key: &str, value: impl std::fmt::Debug, expected: &str) -> Result<()> {
            if ok { Ok(()) } else { bail!("{key} = {value:?} is out of range: expected {expected}") }
        }
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        need(self.steps >= 1, "steps", self.steps, "≥ 1")?;
        need(self.data.downscale >= 1, "data.downscale", self.data.downscale, "≥ 1")?;
        need(self.data.builtin_width >= 16, "data.builtin_width", self.data.builtin_width, "≥ 16")?;
        need(self.data.builtin_views >= 2, "data.builtin_views", self.data.builtin_views, "≥ 2")?;
        sdf_backbone::Preset::from_name(&self.model.preset).map_err(|e| anyhow::anyhow!("model.preset: {e}"))?;
        need(self.model.init_radius > 0.0 && self.model.init_radius < 1.0, "model.init_radius", self.model.init_radius, "in (0, 1)")?;
        need(self.model.initial_levels >= 1, "model.initial_levels", self.model.initial_levels, "≥ 1")?;
        need((0.0..=1.0).contains(&self.model.all_levels_at), "model.all_levels_at", self.model.all_levels_at, "in [0, 1]")?;
        need(self.model.eikonal.is_finite() && self.model.eikonal >= 0.0, "model.eikonal", self.model.eikonal, "≥ 0")?;
        need(self.model.mask.is_finite() && self.model.mask >= 0.0, "model.mask", self.model.mask, "≥ 0")?;
        need(self.model.curvature.is_finite() && self.model.curvature >= 0.0, "model.curvature", self.model.curvature, "≥ 0")?;
        need(["tetrahedral", "central"].contains(&self.model.normals.as_str()), "model.normals", &self.model.normals, "tetrahedral or central")?;
        need(self.model.background.iter().all(|c| (0.0..=1.0).contains(c)), "model.background", self.model.background, "each in [0, 1]")?;
        need(self.render.rays >= 1, "render.rays", self.render.rays, "≥ 1")?;
        need(self.render.coarse >= 2, "render.coarse", self.render.coarse, "≥ 2")?;
        need(
            self.render.upsample_rounds >= 1 || self.render.fine == 0,
            "render.upsample_rounds",
            self.render.upsample_rounds,
            "≥ 1 when render.fine > 0",
        )?;
        need(finite_pos(self.render.upsample_s), "render.upsample_s", self.render.upsample_s, "> 0")?;
        need(self.render.chunk >= 1, "render.chunk", self.render.chunk, "≥ 1")?;
        need(finite_pos(self.optim.lr), "optim.lr", self.optim.lr, "> 0")?;
        need(self.optim.lr_grid.is_finite() && self.optim.lr_grid >= 0.0, "optim.lr_grid", self.optim.lr_grid, "≥ 0")?;
        need((0.0..=1.0).contains(&self.optim.final_factor), "optim.final_factor", self.optim.final_factor, "in [0, 1]")?;
        need(["cosine", "step"].contains(&self.optim.schedule.as_str()), "optim.schedule", &self.optim.schedule, "cosine or step")?;
        need(self.optim.milestones.iter().all(|m| (0.0..=1.0).contains(m)), "optim.milestones", &self.optim.milestones, "fractions in [0, 1]")?;
        need((0.0..=1.0).contains(&self.optim.step_factor), "optim.step_factor", self.optim.step_factor, "in [0, 1]")?;
        need(self.optim.clip_norm.is_finite() && self.optim.clip_norm >= 0.0, "optim.clip_norm", self.optim.clip_norm, "≥ 0")?;
        need(self.guide.update_every >= 1, "guide.update_every", self.guide.update_every, "≥ 1")?;
        need(self.guide.scene_resolution >= 4, "guide.scene_resolution", self.guide.scene_resolution, "≥ 4")?;
        need((1..=8).contains(&self.guide.partition), "guide.partition", self.guide.partition, "in 1..=8 (F)")?;
        need(self.guide.camera_uv >= 2, "guide.camera_uv", self.guide.camera_uv, "≥ 2")?;
        need(self.guide.camera_depth >= 2, "guide.camera_depth", self.guide.camera_depth, "≥ 2")?;
        need(
            ["opaque", "quadrature", "paper", "off"].contains(&self.guide.view_dependency.as_str()),
            "guide.view_dependency",
            &self.guide.view_dependency,
            "opaque, quadrature, paper or off",
        )?;
        need(self.guide.fixed_s.is_finite() && self.guide.fixed_s >= 0.0, "guide.fixed_s", self.guide.fixed_s, "≥ 0 (0: the backbone's s)")?;
        need(
            !self.guide.uniform_fractions.is_empty() && self.guide.uniform_fractions.iter().all(|f| (0.0..=1.0).contains(f)),
            "guide.uniform_fractions",
            &self.guide.uniform_fractions,
            "a non-empty list of fractions in [0, 1]",
        )?;
        need(
            self.guide.extra_points <= self.render.fine,
            "guide.extra_points",
            self.guide.extra_points,
            "≤ render.fine (the extra points replace up-sampled ones)",
        )?;
        need(
            ["gaussian", "uniform", "log"].contains(&self.guide.extra.as_str()),
            "guide.extra",
            &self.guide.extra,
            "gaussian, uniform (RU) or log (Log)",
        )?;
        self.surface_losses().validate().map_err(|e| anyhow::anyhow!("surface.{e}"))?;
        need(self.output.validate_downscale >= 1, "output.validate_downscale", self.output.validate_downscale, "≥ 1")?;
        need(self.output.log_every >= 1, "output.log_every", self.output.log_every, "≥ 1")?;
        need((8..=2048).contains(&self.output.mesh_resolution), "output.mesh_resolution", self.output.mesh_resolution, "in 8..=2048")?;
        need(
            self.output.mesh_formats.iter().all(|f| ["ply", "obj", "glb"].contains(&f.as_str())),
            "output.mesh_formats",
            &self.output.mesh_formats,
            "any of ply, obj, glb",
        )?;
        need(finite_pos(self.output.chamfer_spacing), "output.chamfer_spacing", self.output.chamfer_spacing, "> 0")?;
        need(finite_pos(self.output.chamfer_max_dist), "output.chamfer_max_dist", self.output.chamfer_max_dist, "> 0")?;
        need(finite_pos(self.output.fscore_tau), "output.fscore_tau", self.output.fscore_tau, "> 0")?;
        Ok(())
    }

    /// The surface-loss configuration.
    pub fn surface_losses(&self) -> surface_losses::SurfaceLossConfig {
        surface_losses::SurfaceLossConfig {
            weight: self.surface.weight,
            lambda_near: self.surface.lambda_near,
            lambda_far: self.surface.lambda_far,
            epsilon: self.surface.epsilon,
            beta: self.surface.beta,
            band_sigmas: 3.0,
        }
    }

    /// The configuration as TOML (written to the run folder).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("the configuration serialises")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_valid_and_round_trip_through_toml() {
        let c = TrainConfig::default();
        c.validate().unwrap();
        let back: TrainConfig = toml::from_str(&c.to_toml()).unwrap();
        assert_eq!(back, c);
    }

    #[test]
    fn overrides_set_nested_keys_and_parse_values() {
        let c = TrainConfig::load(None, &["steps=7".into(), "guide.partition=1".into(), "sampler=uniform".into(), "guide.extra=log".into()]).unwrap();
        assert_eq!((c.steps, c.guide.partition, c.sampler, c.guide.extra.as_str()), (7, 1, SamplerKind::Uniform, "log"));
    }

    #[test]
    fn unknown_keys_and_bad_values_are_named() {
        let err = TrainConfig::load(None, &["guide.partitoin=2".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("partitoin"), "{err:#}");
        let err = TrainConfig::load(None, &["guide.partition=0".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("guide.partition"), "{err:#}");
        let err = TrainConfig::load(None, &["guide.fixed_s=-1".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("guide.fixed_s"), "{err:#}");
        let err = TrainConfig::load(None, &["surface.beta=-1".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("beta"), "{err:#}");
        let err = TrainConfig::load(None, &["steps".into()]).unwrap_err();
        assert!(format!("{err:#}").contains("key=value"), "{err:#}");
        let dir = std::env::temp_dir().join(format!("psneus-config-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bad.toml");
        std::fs::write(&file, "[render]\nrayz = 5\n").unwrap();
        let err = TrainConfig::load(Some(&file), &[]).unwrap_err();
        let msg = format!("{err:#}");
        assert!(msg.contains("rayz") && msg.contains("bad.toml"), "{msg}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
