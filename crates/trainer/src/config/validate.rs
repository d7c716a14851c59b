//! The range checks of a [`TrainConfig`]: every key's allowed values, and the combinations
//! that cannot run, each error naming the key and what it expects.

use super::{Budget, GridSize, InitRadius, MeshResolution, MomentStorage, Normals, SmoothingRegion, TrainConfig};
use crate::bail;
use crate::error::Result;
use std::time::Duration;

/// `Ok` when `ok`, else an error naming `key`, its value and what it expects.
fn need(ok: bool, key: &str, value: impl std::fmt::Debug, expected: &str) -> Result<()> {
    if ok { Ok(()) } else { bail!(Config, "{key} = {value:?} is out of range: expected {expected}") }
}

/// What a key that needs a hash grid expects of `model.preset`.
fn hash_grid_preset(with: &str) -> String {
    let presets: Vec<&str> = sdf_backbone::Preset::ALL.into_iter().filter(|p| p.has_hash_grid()).map(sdf_backbone::Preset::name).collect();
    format!("a hash-grid preset ({}) with {with}", presets.join(", "))
}

impl TrainConfig {
    /// Checks every range; the error names the key.
    pub fn validate(&self) -> Result<()> {
        self.validate_data()?;
        self.validate_model()?;
        self.validate_render()?;
        self.validate_optim()?;
        self.validate_guide()?;
        self.validate_output()
    }

    /// The budget and `[data]`.
    fn validate_data(&self) -> Result<()> {
        need(self.budget != Budget::Steps(0), "budget.steps", 0, "≥ 1")?;
        need(self.budget != Budget::Time(Duration::ZERO), "budget.seconds", 0, "> 0")?;
        need(self.data.downscale >= 1, "data.downscale", self.data.downscale, "≥ 1")?;
        need(
            self.data.holdout_every != Some(1),
            "data.holdout_every",
            self.data.holdout_every,
            "0 (none held out) or ≥ 2 (1 would hold out every view and leave none to train on)",
        )?;
        need(
            self.data.bound.is_none_or(|b| b.iter().all(|v| v.is_finite()) && b[3] > 0.0),
            "data.bound",
            self.data.bound,
            "[] or [x, y, z, radius > 0]",
        )?;
        need(self.data.builtin.width >= 16, "data.builtin.width", self.data.builtin.width, "≥ 16")?;
        need(self.data.builtin.views >= 2, "data.builtin.views", self.data.builtin.views, "≥ 2")?;
        let b = self.data.builtin.bound;
        need(b.is_finite() && b >= 1.0, "data.builtin.bound", b, "≥ 1 (the object's own radius)")?;
        Ok(())
    }

    /// `[model]` and the combinations it takes part in.
    fn validate_model(&self) -> Result<()> {
        let non_neg = |v: f64| v.is_finite() && v >= 0.0;
        if let InitRadius::Radius(r) = self.model.init_radius {
            need(r > 0.0 && r < 1.0, "model.init_radius", r, "in (0, 1), auto or photos")?;
        }
        need(self.model.pixels_per_cell.is_finite() && self.model.pixels_per_cell > 0.0, "model.pixels_per_cell", self.model.pixels_per_cell, "> 0")?;
        need(
            self.model.grid == GridSize::Preset || self.model.preset.has_hash_grid(),
            "model.preset",
            self.model.preset.name(),
            &hash_grid_preset("model.grid = \"footprint\""),
        )?;
        if let Some(t) = self.model.log2_table {
            let (lo, hi) = crate::sizing::LOG2_TABLE_RANGE;
            need((lo..=hi).contains(&t), "model.log2_table", t, &format!("0 (the grid's own) or in {lo}..={hi}"))?;
            need(self.model.preset.has_hash_grid(), "model.preset", self.model.preset.name(), &hash_grid_preset("model.log2_table"))?;
        }
        need(self.model.initial_levels >= 1, "model.initial_levels", self.model.initial_levels, "≥ 1")?;
        need((0.0..=1.0).contains(&self.model.all_levels_at), "model.all_levels_at", self.model.all_levels_at, "in [0, 1]")?;
        need(non_neg(self.model.eikonal), "model.eikonal", self.model.eikonal, "≥ 0")?;
        need(non_neg(self.model.mask), "model.mask", self.model.mask, "≥ 0")?;
        need(non_neg(self.model.opacity_entropy), "model.opacity_entropy", self.model.opacity_entropy, "≥ 0")?;
        need(non_neg(self.model.opacity_sparsity), "model.opacity_sparsity", self.model.opacity_sparsity, "≥ 0")?;
        if let Some(w) = self.model.opacity_guard {
            need(w > 0.0 && w.is_finite(), "model.opacity_guard", w, "> 0 (0: off)")?;
        }
        if let Some(t) = self.model.opacity_guard_tolerance {
            need(t > 0.0 && t.is_finite(), "model.opacity_guard_tolerance", t, "> 0 (0: none)")?;
        }
        for (key, fraction) in
            [("model.opacity_guard_after", self.model.opacity_guard_after), ("model.opacity_guard_until", self.model.opacity_guard_until)]
        {
            if let Some(f) = fraction {
                need(f > 0.0 && f <= 1.0, key, f, "a fraction of the run in (0, 1] (0: none)")?;
            }
        }
        need((1..=16).contains(&self.model.background_frequencies), "model.background_frequencies", self.model.background_frequencies, "in 1..=16")?;
        if let Some([from, to]) = self.model.s_floor {
            let ok = from.is_finite() && to.is_finite() && from > 0.0 && to >= from;
            need(ok, "model.s_floor", format!("[{from}, {to}]"), "[] or [from, to] with 0 < from ≤ to")?;
        }
        if let Some(s) = self.model.init_s {
            need(s.is_finite() && s >= 1.0, "model.init_s", s, "0 (the preset's) or ≥ 1")?;
        }
        let near = self.model.background_near;
        need(near.is_finite() && near >= 1.0, "model.background_near", near, "≥ 1 (bound radii)")?;
        if let Some(start) = self.model.background_near_start {
            need(start.is_finite() && start >= near, "model.background_near_start", start, "0 (none) or ≥ model.background_near")?;
        }
        if let Some(after) = self.model.geometry_after {
            need(after > 0.0 && after < 1.0, "model.geometry_after", after, "0 (none) or in (0, 1)")?;
        }
        let until = self.model.background_near_until;
        need((0.0..=1.0).contains(&until), "model.background_near_until", until, "in [0, 1]")?;
        need(non_neg(self.model.curvature), "model.curvature", self.model.curvature, "≥ 0")?;
        need(non_neg(self.model.normal_smoothness), "model.normal_smoothness", self.model.normal_smoothness, "≥ 0")?;
        need(non_neg(self.model.smoothing_depth), "model.smoothing_depth", self.model.smoothing_depth, "≥ 0")?;
        need(
            self.model.smoothing_depth == 0.0 || self.model.smoothing_region == SmoothingRegion::Outside,
            "model.smoothing_depth",
            self.model.smoothing_depth,
            "0 with model.smoothing_region = \"everywhere\" (a depth inside the solid applies only to \"outside\")",
        )?;
        if self.model.normals == Normals::Analytic {
            need(
                self.model.curvature == 0.0,
                "model.curvature",
                self.model.curvature,
                "0 with model.normals = \"analytic\" (the curvature's Laplacian comes from the probes of numerical normals)",
            )?;
        }
        need(self.model.background.iter().all(|c| (0.0..=1.0).contains(c)), "model.background", self.model.background, "each in [0, 1]")?;
        Ok(())
    }

    /// `[render]`.
    fn validate_render(&self) -> Result<()> {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        need(self.render.rays >= 1, "render.rays", self.render.rays, "≥ 1")?;
        need(self.render.coarse >= 2, "render.coarse", self.render.coarse, "≥ 2")?;
        need(
            self.render.upsample_rounds >= 1 || self.render.fine == 0,
            "render.upsample_rounds",
            self.render.upsample_rounds,
            "≥ 1 when render.fine > 0",
        )?;
        need(
            self.render.render_upsample_rounds >= 1 || self.render.render_fine == 0,
            "render.render_upsample_rounds",
            self.render.render_upsample_rounds,
            "≥ 1 when render.render_fine > 0",
        )?;
        need(finite_pos(self.render.upsample_s), "render.upsample_s", self.render.upsample_s, "> 0")?;
        need(
            self.output.snapshots.iter().all(|&t| finite_pos(t)),
            "output.snapshots",
            &self.output.snapshots,
            "training times in seconds, each > 0",
        )?;
        need((0.0..0.5).contains(&self.render.render_trim), "render.render_trim", self.render.render_trim, "in [0, 0.5)")?;
        if let Some(most) = self.render.render_resolved {
            need(most > 0.0 && most < 1.0, "render.render_resolved", most, "in [0, 1) (0: off)")?;
        }
        need(self.render.chunk >= 1, "render.chunk", self.render.chunk, "≥ 1")?;
        need(self.render.occupancy_dilation <= 8, "render.occupancy_dilation", self.render.occupancy_dilation, "in 0..=8")?;
        Ok(())
    }

    /// `[optim]`.
    fn validate_optim(&self) -> Result<()> {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        let non_neg = |v: f64| v.is_finite() && v >= 0.0;
        need(finite_pos(self.optim.lr), "optim.lr", self.optim.lr, "> 0")?;
        need(non_neg(self.optim.lr_grid), "optim.lr_grid", self.optim.lr_grid, "≥ 0")?;
        self.optim.schedule.validate().map_err(|e| crate::Error::Config(format!("optim.schedule.{e}")))?;
        need(self.optim.clip_norm.is_none_or(non_neg), "optim.clip_norm", self.optim.clip_norm.unwrap_or(0.0), "≥ 0")?;
        need(
            self.optim.table_moments == MomentStorage::F32 || self.model.preset.has_hash_grid(),
            "model.preset",
            self.model.preset.name(),
            &hash_grid_preset("optim.table_moments = \"bf16\""),
        )?;
        Ok(())
    }

    /// `[guide]` and `[mining]`.
    fn validate_guide(&self) -> Result<()> {
        let non_neg = |v: f64| v.is_finite() && v >= 0.0;
        need(self.guide.updates >= 1, "guide.updates", self.guide.updates, "≥ 1")?;
        self.guide.scene.validate().map_err(|e| crate::Error::Config(format!("guide.scene: {e}")))?;
        self.guide.camera.validate().map_err(|e| crate::Error::Config(format!("guide.camera: {e}")))?;
        need(self.guide.fixed_s.is_none_or(non_neg), "guide.fixed_s", self.guide.fixed_s.unwrap_or(0.0), "≥ 0 (0: the backbone's s)")?;
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
        need(self.mining.cells >= 1, "mining.cells", self.mining.cells, "≥ 1")?;
        need((0.0..=1.0).contains(&self.mining.new_weight), "mining.new_weight", self.mining.new_weight, "in [0, 1]")?;
        need((0.0..=1.0).contains(&self.mining.uniform), "mining.uniform", self.mining.uniform, "in [0, 1]")?;
        need((0.0..=1.0).contains(&self.mining.alpha), "mining.alpha", self.mining.alpha, "in [0, 1]")?;
        need((0.0..=1.0).contains(&self.mining.alpha_warmup), "mining.alpha_warmup", self.mining.alpha_warmup, "in [0, 1]")?;
        Ok(())
    }

    /// `[surface]` and `[output]`.
    fn validate_output(&self) -> Result<()> {
        let finite_pos = |v: f64| v.is_finite() && v > 0.0;
        self.surface.validate().map_err(|e| crate::Error::Config(format!("surface.{e}")))?;
        need((0.0..=1.0).contains(&self.output.validate_share), "output.validate_share", self.output.validate_share, "in [0, 1]")?;
        need(self.output.validate_downscale >= 1, "output.validate_downscale", self.output.validate_downscale, "≥ 1")?;
        need(self.output.eval_downscale >= 1, "output.eval_downscale", self.output.eval_downscale, "≥ 1")?;
        need(self.output.log_every >= 1, "output.log_every", self.output.log_every, "≥ 1")?;
        if let MeshResolution::Cells(n) = self.output.mesh_resolution {
            need(MeshResolution::CELLS.contains(&n), "output.mesh_resolution", n, "in 8..=2048 or \"model\"")?;
        }
        need((0.0..1.0).contains(&self.output.min_component_area), "output.min_component_area", self.output.min_component_area, "in [0, 1)")?;
        need(finite_pos(self.output.chamfer_spacing), "output.chamfer_spacing", self.output.chamfer_spacing, "> 0")?;
        need(finite_pos(self.output.chamfer_max_dist), "output.chamfer_max_dist", self.output.chamfer_max_dist, "> 0")?;
        need(finite_pos(self.output.fscore_tau), "output.fscore_tau", self.output.fscore_tau, "> 0")?;
        Ok(())
    }
}
