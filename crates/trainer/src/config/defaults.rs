//! The defaults of every section: the built-in scene on a 2-core CPU in a few minutes (the
//! paper's values where a 2-core CPU affords them; each departure says why in its field's doc).

use super::*;

impl Default for TrainConfig {
    fn default() -> Self {
        TrainConfig {
            seed: 0,
            budget: Budget::Time(Duration::from_secs(120)),
            sampler: SamplerKind::Guided,
            data: DataConfig::default(),
            model: ModelConfig::default(),
            render: RenderConfig::default(),
            optim: OptimConfig::default(),
            guide: GuideConfig::default(),
            mining: MiningConfig::default(),
            surface: SurfaceLossConfig::default(),
            output: OutputConfig::default(),
        }
    }
}

impl Default for DataConfig {
    fn default() -> Self {
        DataConfig { downscale: 1, masks: true, holdout_every: Some(8), bound: None, builtin: BuiltinConfig::default() }
    }
}

impl Default for BuiltinConfig {
    fn default() -> Self {
        BuiltinConfig {
            shape: prob_grid::ShapeName::Composite,
            width: 200,
            views: 49,
            backdrop: datasets::golden::Backdrop::Checker,
            rig: datasets::golden::rig::Rig::Dtu,
            bound: 1.0,
        }
    }
}

impl Default for ModelConfig {
    fn default() -> Self {
        ModelConfig {
            preset: Preset::NeuralangeloCpu,
            grid: GridSize::Preset,
            sdf_layers: None,
            pixels_per_cell: 1.0,
            log2_table: None,
            init_radius: InitRadius::Photos,
            initial_levels: 4,
            all_levels_at: 0.25,
            eikonal: 0.1,
            mask: 1.0,
            curvature: 0.0,
            normal_smoothness: 0.0,
            smoothing_decay: SmoothingDecay::Levels,
            smoothing_region: SmoothingRegion::Everywhere,
            smoothing_depth: 0.0,
            normals: Normals::Auto,
            background: [0.0; 3],
            background_model: BackgroundModel::Auto,
            background_frequencies: 8,
            background_view: false,
            background_grid: BackgroundGrid::Auto,
            background_near: 1.0,
            background_near_start: Some(3.0),
            background_near_until: 0.25,
            geometry_after: Some(0.05),
            s_floor: None,
            init_s: None,
            opacity_entropy: 0.0,
            opacity_sparsity: 0.0,
            opacity_guard: None,
            opacity_guard_tolerance: None,
            opacity_guard_after: None,
            opacity_guard_until: None,
            products: Products::F32,
        }
    }
}

impl ModelConfig {
    /// The normal scheme the run uses: the chosen one, or for `auto` analytic without a
    /// curvature loss (the curvature's Laplacian comes from the probes of numerical normals) and
    /// tetrahedral with one.
    pub fn normal_scheme(&self) -> NormalScheme {
        match self.normals {
            Normals::Central => NormalScheme::Central,
            Normals::Tetrahedral => NormalScheme::Tetrahedral,
            Normals::Analytic => NormalScheme::Analytic,
            Normals::Auto if self.curvature == 0.0 => NormalScheme::Analytic,
            Normals::Auto => NormalScheme::Tetrahedral,
        }
    }
}

impl Default for RenderConfig {
    fn default() -> Self {
        RenderConfig {
            rays: 256,
            coarse: 16,
            fine: 16,
            upsample_rounds: 2,
            upsample_s: 64.0,
            render_fine: 32,
            render_upsample_rounds: 2,
            render_trim: 1e-4,
            render_resolved: Some(0.02),
            render_colour_stride: NonZeroUsize::new(4).expect("4 > 0"),
            render_skip_empty: true,
            chunk: 8,
            skip_empty: true,
            occupancy_dilation: 1,
        }
    }
}

impl Default for OptimConfig {
    fn default() -> Self {
        OptimConfig { lr: 5e-3, lr_grid: 1e-2, schedule: LrSchedule::default(), clip_norm: None, table_moments: MomentStorage::F32 }
    }
}

impl Default for GuideConfig {
    /// The paper's knobs at 2-core sizes: scene grid 64³ (paper 128³), camera grids 32 × 32 × 64
    /// (paper 64 × 64 × 128), F = 2, opaque view dependency, η⁻² weighting, 8 extra points.
    fn default() -> Self {
        GuideConfig {
            updates: 6,
            scene: SceneGridConfig { resolution: 64, ..Default::default() },
            camera: CameraGridConfig { ru: 32, rv: 32, rl: 64, ..Default::default() },
            interpolation: Interpolation::Linear,
            fixed_s: None,
            uniform_fractions: vec![0.2, 0.4, 0.6, 0.8],
            extra_points: 8,
            extra: ExtraPoints::Gaussian,
            extra_bin_spread: true,
        }
    }
}

impl Default for MiningConfig {
    fn default() -> Self {
        MiningConfig { cells: 128, new_weight: 0.9, uniform: 0.1, alpha: 0.6, alpha_warmup: 0.1 }
    }
}

impl Default for OutputConfig {
    fn default() -> Self {
        OutputConfig {
            validate_every: Some(100),
            validate_share: 0.03,
            validate_downscale: 2,
            eval_downscale: 1,
            eval_views: 3,
            eval_train_views: 2,
            metrics_every: None,
            snapshots: Vec::new(),
            snapshot_checkpoints: true,
            checkpoint_every: Some(1000),
            log_every: 10,
            mesh_resolution: MeshResolution::Cells(192),
            mesh_filter: MeshFilter::Supported,
            min_component_area: 0.01,
            mesh_formats: vec![MeshFormat::Ply],
            vertex_colors: false,
            chamfer_spacing: DEFAULT_CHAMFER_SPACING,
            chamfer_max_dist: 0.1,
            fscore_tau: 0.01,
        }
    }
}
