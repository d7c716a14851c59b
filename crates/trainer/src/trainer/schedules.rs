//! What follows the run's progress: the active hash-grid levels (coarse-to-fine), the smoothing
//! weights, where the learned background starts, and whether the geometry learns yet.

use super::Trainer;
use crate::config::{SmoothingDecay, SmoothingRegion};

impl Trainer {
    /// Active hash-grid levels at `progress` (coarse-to-fine).
    pub(super) fn active_levels(&self, levels: usize, progress: f64) -> usize {
        let ramp = if self.config.model.all_levels_at > 0.0 { (progress / self.config.model.all_levels_at).min(1.0) } else { 1.0 };
        let start = self.config.model.initial_levels.min(levels);
        start + ((levels - start) as f64 * ramp).floor() as usize
    }

    /// The curvature and normal-smoothness weights at `progress`: reached linearly over the
    /// learning-rate warm-up, then, with `model.smoothing_decay = "levels"`, divided by the finest
    /// active resolution over the initial levels' finest (Neuralangelo's growth factor per level
    /// switched on).
    pub(super) fn smoothing_weights(&self, progress: f64) -> (f64, f64) {
        let warmup = self.config.optim.schedule.warmup;
        let ramp = if warmup > 0.0 { (progress / warmup).min(1.0) } else { 1.0 };
        let decay = match (self.config.model.smoothing_decay, self.backbone.level_resolutions(), self.finest_active_resolution(progress)) {
            (SmoothingDecay::Levels, Some(resolutions), Some(finest)) => {
                let initial = self.config.model.initial_levels.clamp(1, resolutions.len());
                f64::from(resolutions[initial - 1]) / f64::from(finest)
            }
            _ => 1.0,
        };
        let m = &self.config.model;
        (m.curvature * ramp * decay, m.normal_smoothness * ramp * decay)
    }

    /// The finest active hash-grid level's resolution at `progress` (`None` without a hash grid).
    fn finest_active_resolution(&self, progress: f64) -> Option<u32> {
        let resolutions = self.backbone.level_resolutions()?;
        let active = self.active_levels(resolutions.len(), progress).clamp(1, resolutions.len());
        Some(resolutions[active - 1])
    }

    /// The normal smoothness's region (`model.smoothing_region`) at `progress`: with `outside`,
    /// its depth `model.smoothing_depth` cells of the finest active level (side 2 / resolution:
    /// the bound's cube is 2 across); without a hash grid, cells of twice the normals' step.
    fn smoothness_region(&self, progress: f64) -> sdf_backbone::SmoothnessRegion {
        match self.config.model.smoothing_region {
            SmoothingRegion::Everywhere => sdf_backbone::SmoothnessRegion::Everywhere,
            SmoothingRegion::Outside => {
                let cell = self.finest_active_resolution(progress).map_or(2.0 * self.backbone.config.normal_step, |n| 2.0 / f64::from(n));
                sdf_backbone::SmoothnessRegion::Outside { depth: self.config.model.smoothing_depth * cell }
            }
        }
    }

    /// Where the learned background starts at `progress`: from `model.background_near_start`
    /// in to `model.background_near` over the first `model.background_near_until` of the run.
    fn background_near(&self, progress: f64) -> f64 {
        let m = &self.config.model;
        match m.background_near_start {
            Some(start) if progress < m.background_near_until => start + (m.background_near - start) * progress / m.background_near_until,
            _ => m.background_near,
        }
    }

    /// The factor on the geometry's learning rates at `progress`: without masks 0 before
    /// `model.geometry_after`, 1 from there on; with masks always 1 (the masks say where the
    /// object is from the first step).
    pub(super) fn geometry_rate(&self, progress: f64) -> f32 {
        let hold = !self.uses_masks() && self.config.model.geometry_after.is_some_and(|after| progress < after);
        if hold { 0.0 } else { 1.0 }
    }

    /// Sets the schedules that follow the progress: the active hash-grid levels and where the
    /// learned background starts.
    pub(super) fn set_progress_schedules(&mut self, progress: f64) {
        if let Some(levels) = self.backbone.levels() {
            self.backbone.set_active_levels(self.active_levels(levels, progress));
        }
        self.backbone.config.normal_smoothness_region = self.smoothness_region(progress);
        let near = self.background_near(progress);
        if let Some(background) = &mut self.backbone.background {
            background.near = near;
        }
        let m = &self.config.model;
        let guard_on = m.opacity_guard_after.is_none_or(|after| progress >= after) && m.opacity_guard_until.is_none_or(|until| progress < until);
        self.backbone.config.opacity_guard = super::opacity_guard(&self.config, self.uses_masks()).filter(|_| guard_on);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{Budget, InitRadius, TrainConfig};
    use crate::data::SceneData;

    fn small(masks: bool, steps: u64) -> (TrainConfig, SceneData) {
        let mut config = TrainConfig { budget: Budget::Steps(steps), ..TrainConfig::default() };
        (config.data.builtin.width, config.data.masks, config.render.rays) = (48, masks, 64);
        config.model.init_radius = InitRadius::Radius(0.5);
        let data = SceneData::builtin(&config).unwrap();
        (config, data)
    }

    #[test]
    fn the_configured_initial_s_is_the_trainers_s() {
        for (init_s, expected) in [(None, 20.0855), (Some(4.0), 4.0)] {
            let (mut config, data) = small(true, 1);
            config.model.init_s = init_s;
            let trainer = Trainer::new(config, data).unwrap();
            assert!((trainer.s() - expected).abs() < 1e-3 * expected, "{init_s:?}: s = {}", trainer.s());
        }
    }

    #[test]
    fn the_learned_background_moves_in_from_its_start_over_its_share_of_the_run() {
        let (mut config, data) = small(false, 1);
        (config.model.background_near, config.model.background_near_start, config.model.background_near_until) = (1.0, Some(3.0), 0.25);
        let mut trainer = Trainer::new(config, data).unwrap();
        for (progress, near) in [(0.0, 3.0), (0.125, 2.0), (0.25, 1.0), (0.9, 1.0)] {
            trainer.set_progress_schedules(progress);
            assert_eq!(trainer.backbone.background.as_ref().unwrap().near, near, "at {progress}");
        }
        trainer.config.model.background_near_start = None;
        trainer.set_progress_schedules(0.0);
        assert_eq!(trainer.backbone.background.as_ref().unwrap().near, 1.0, "no start: always the near radius");
    }

    /// `model.smoothing_region = "outside"` reaches the backbone with its depth in cells of the
    /// finest active level: shallower as finer levels switch on.
    #[test]
    fn the_smoothing_regions_depth_follows_the_finest_active_level() {
        use sdf_backbone::SmoothnessRegion;
        let (mut config, data) = small(true, 1);
        (config.model.smoothing_region, config.model.smoothing_depth) = (SmoothingRegion::Outside, 3.0);
        (config.model.initial_levels, config.model.all_levels_at) = (4, 0.5);
        let mut trainer = Trainer::new(config, data).unwrap();
        let resolutions = trainer.backbone.level_resolutions().unwrap().to_vec();
        for (progress, finest) in [(0.0, resolutions[3]), (0.9, resolutions[resolutions.len() - 1])] {
            trainer.set_progress_schedules(progress);
            let depth = 3.0 * 2.0 / f64::from(finest);
            assert_eq!(trainer.backbone.config.normal_smoothness_region, SmoothnessRegion::Outside { depth }, "at {progress}");
        }
        trainer.config.model.smoothing_region = SmoothingRegion::Everywhere;
        trainer.set_progress_schedules(0.9);
        assert_eq!(trainer.backbone.config.normal_smoothness_region, SmoothnessRegion::Everywhere);
    }

    /// Neuralangelo's decay: the smoothing weights are divided by the finest active resolution
    /// over the initial levels' finest, after the warm-up's ramp; `none` keeps them as given.
    #[test]
    fn the_smoothing_weights_decay_by_the_grids_growth_per_level_switched_on() {
        let (mut config, data) = small(true, 1);
        (config.model.normal_smoothness, config.model.curvature) = (0.2, 0.0);
        (config.model.initial_levels, config.model.all_levels_at, config.optim.schedule.warmup) = (4, 0.5, 0.1);
        config.model.smoothing_decay = SmoothingDecay::Levels;
        let mut trainer = Trainer::new(config, data).unwrap();
        let resolutions = trainer.backbone.level_resolutions().unwrap().to_vec();
        let levels = resolutions.len();
        assert!(levels > 4 && resolutions[levels - 1] > resolutions[3], "the preset has levels to switch on: {resolutions:?}");
        let at = |trainer: &Trainer, progress: f64| trainer.smoothing_weights(progress).1;
        assert!((at(&trainer, 0.05) - 0.1).abs() < 1e-12, "half-way through the warm-up: half the weight");
        assert!((at(&trainer, 0.1) - 0.2).abs() < 1e-12, "the initial levels: the weight as given");
        let all = 0.2 * f64::from(resolutions[3]) / f64::from(resolutions[levels - 1]);
        assert!((at(&trainer, 0.6) - all).abs() < 1e-12, "every level: decayed by the growth over them");
        let middle = trainer.active_levels(levels, 0.3);
        let expected = 0.2 * f64::from(resolutions[3]) / f64::from(resolutions[middle - 1]);
        assert!(middle > 4 && middle < levels && (at(&trainer, 0.3) - expected).abs() < 1e-12, "part of the way: {middle} levels");
        trainer.config.model.curvature = 1e-3;
        assert!((trainer.smoothing_weights(0.6).0 - 1e-3 * all / 0.2).abs() < 1e-15, "the curvature decays alike");
        trainer.config.model.smoothing_decay = SmoothingDecay::None;
        assert_eq!(trainer.smoothing_weights(0.6), (1e-3, 0.2), "none: as given after the warm-up");
        trainer.config.model.curvature = 0.0;
        trainer.step().unwrap();
        assert_eq!(trainer.backbone.config.normal_smoothness, 0.0, "a step at progress 0 sets the weight the ramp gives");
    }

    #[test]
    fn the_guard_on_the_foreground_works_only_inside_its_share_of_the_run() {
        let (mut config, data) = small(false, 1);
        config.model.opacity_guard = Some(0.1);
        (config.model.opacity_guard_after, config.model.opacity_guard_until) = (Some(0.25), Some(0.5));
        let mut trainer = Trainer::new(config, data).unwrap();
        for (progress, on) in [(0.0, false), (0.2, false), (0.25, true), (0.4, true), (0.5, false), (0.9, false)] {
            trainer.set_progress_schedules(progress);
            assert_eq!(trainer.backbone.config.opacity_guard.is_some(), on, "at {progress}");
        }
        (trainer.config.model.opacity_guard_after, trainer.config.model.opacity_guard_until) = (None, None);
        trainer.set_progress_schedules(0.9);
        assert_eq!(trainer.backbone.config.opacity_guard.map(|g| g.weight), Some(0.1), "no window: the whole run");
        let (mut config, data) = small(true, 1);
        config.model.opacity_guard = Some(0.1);
        let mut trainer = Trainer::new(config, data).unwrap();
        trainer.set_progress_schedules(0.5);
        assert_eq!(trainer.backbone.config.opacity_guard, None, "with masks: never");
    }

    /// With `model.geometry_after` the SDF (encoding, network, variance) holds still over that
    /// share of the run while the colour network and the background learn; then it learns.
    #[test]
    fn the_geometry_holds_still_until_its_share_of_the_run_while_colour_and_background_learn() {
        let (mut config, data) = small(false, 10);
        config.model.geometry_after = Some(0.25);
        let mut trainer = Trainer::new(config, data).unwrap();
        let layout = trainer.backbone.layout();
        let geometry = |p: &[f32]| [&p[layout.encoding.clone()], &p[layout.sdf_mlp.clone()], &p[layout.variance..=layout.variance]].concat();
        let start = trainer.state().params.clone();
        for _ in 0..3 {
            trainer.step().unwrap();
        }
        let held = trainer.state().params.clone();
        assert_eq!(geometry(&held), geometry(&start), "the geometry holds still over the first quarter (steps 0, 1, 2)");
        assert_ne!(held[layout.color.clone()], start[layout.color.clone()], "the colour network learns meanwhile");
        assert_ne!(held[layout.background.clone()], start[layout.background.clone()], "the background learns meanwhile");
        trainer.step().unwrap();
        assert_ne!(geometry(&trainer.state().params), geometry(&held), "the geometry learns from a quarter of the run on");
        // With masks the key is unused: the geometry learns from the first step.
        let (mut config, data) = small(true, 10);
        config.model.geometry_after = Some(0.25);
        let mut trainer = Trainer::new(config, data).unwrap();
        let start = trainer.state().params.clone();
        trainer.step().unwrap();
        assert_ne!(geometry(&trainer.state().params), geometry(&start), "with masks the geometry learns from the first step");
    }
}
