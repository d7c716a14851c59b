//! The configuration's tests.

use super::*;

#[test]
fn defaults_are_valid_and_round_trip_through_toml() {
    let c = TrainConfig::default();
    c.validate().unwrap();
    let back = TrainConfig::from_toml(&c.to_toml()).unwrap();
    assert_eq!(back, c);
    assert!(c.differences(&back).is_empty());
}

#[test]
fn overrides_set_nested_keys_and_typed_values() {
    let c = TrainConfig::load(
        None,
        &[
            "steps=7".into(),
            "guide.scene.partition=1".into(),
            "sampler=uniform".into(),
            "guide.extra=log".into(),
            "guide.camera.view_dependency=quadrature".into(),
            "guide.camera.weighting=mass-preserving".into(),
            "guide.interpolation=nearest".into(),
            "model.preset=neus-cpu".into(),
            "model.normals=central".into(),
            "optim.schedule.decay=step".into(),
            "output.mesh_formats=[\"obj\", \"glb\"]".into(),
        ],
    )
    .unwrap();
    assert_eq!((c.budget, c.guide.scene.partition, c.sampler, c.guide.extra), (Budget::Steps(7), 1, SamplerKind::Uniform, ExtraPoints::LogVariance));
    assert_eq!(c.guide.camera.view_dependency, prob_grid::ViewDependency::Quadrature);
    assert_eq!(c.guide.camera.weighting, prob_grid::Weighting::MassPreserving);
    assert_eq!((c.guide.interpolation, c.model.preset, c.model.normals), (Interpolation::Nearest, Preset::NeusCpu, Normals::Central));
    assert_eq!(c.model.normal_scheme(), NormalScheme::Central);
    assert_eq!(c.optim.schedule.decay, sdf_backbone::Decay::Step);
    assert_eq!(c.output.mesh_formats, vec![MeshFormat::Obj, MeshFormat::Glb]);
    let d = TrainConfig::default().differences(&c);
    assert!(d.contains(&"guide.scene.partition".to_string()) && d.contains(&"budget.steps".to_string()), "{d:?}");
}

#[test]
fn background_model_reads_its_names_and_the_earlier_boolean_key() {
    let model = |o: &str| TrainConfig::load(None, &[o.to_string()]).unwrap().model.background_model;
    assert_eq!(TrainConfig::default().model.background_model, BackgroundModel::Auto);
    assert_eq!(model("model.background_model=\"fixed\""), BackgroundModel::Fixed);
    assert_eq!(model("model.learned_background=true"), BackgroundModel::Learned);
    assert_eq!(model("model.learned_background=false"), BackgroundModel::Fixed);
    assert!(BackgroundModel::Auto.learned(false) && !BackgroundModel::Auto.learned(true));
    let err = TrainConfig::load(None, &["model.background_model=sky".into()]).unwrap_err();
    assert!(err.chain().contains("sky"), "{}", err.chain());
}

/// The learned background's keys reach the model: by default 8 frequencies, no view direction
/// (docs/DECISIONS.md §23), and a hash grid of its own for uniform rays only (§42); the earlier
/// model on request; 0 frequencies and an unknown grid setting are errors; the setting survives a
/// configuration file's round trip (`true` / `false` as earlier files wrote it).
#[test]
fn learned_background_defaults_to_eight_frequencies_and_a_hash_grid_for_uniform_rays() {
    let config = |o: &[&str]| TrainConfig::load(None, &o.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
    let model = |o: &[&str]| crate::trainer::background_model(&config(o));
    let guided = model(&[]);
    assert_eq!((guided.frequencies, guided.view_dependent, guided.grid.is_none()), (8, false, true));
    let mut uniform = config(&["model.background_grid=\"auto\""]);
    uniform.sampler = SamplerKind::Uniform;
    let uniform = crate::trainer::background_model(&uniform);
    assert_eq!(uniform.grid.as_ref().map(|g| g.config().clone()), Some(sdf_backbone::BackgroundModel::cpu_grid()));
    assert!(model(&["model.background_grid=true"]).grid.is_some());
    let earlier = model(&["model.background_frequencies=4", "model.background_view=true", "model.background_grid=false"]);
    assert_eq!((earlier.frequencies, earlier.view_dependent, earlier.grid.is_none()), (4, true, true));
    assert_ne!(guided.n_params(), earlier.n_params());
    let err = TrainConfig::load(None, &["model.background_frequencies=0".into()]).unwrap_err();
    assert!(err.chain().contains("model.background_frequencies"), "{}", err.chain());
    let err = TrainConfig::load(None, &["model.background_grid=\"sometimes\"".into()]).unwrap_err();
    assert!(err.chain().contains("auto"), "{}", err.chain());
    for grid in [BackgroundGrid::Auto, BackgroundGrid::On, BackgroundGrid::Off] {
        let mut c = TrainConfig::default();
        c.model.background_grid = grid;
        assert_eq!(TrainConfig::from_toml(&c.to_toml()).unwrap().model.background_grid, grid);
    }
}

/// `auto` (the default) may not choose a scheme the model cannot run: analytic needs a hash
/// grid and no curvature loss, so the NeuS presets and a curvature run get tetrahedral normals
/// (and validate) while an explicit `analytic` there is an error naming the key.
#[test]
fn auto_normals_are_analytic_only_where_the_model_allows_it() {
    let scheme = |o: &[&str]| {
        let c = TrainConfig::load(None, &o.iter().map(|s| s.to_string()).collect::<Vec<_>>()).unwrap();
        c.model.normal_scheme()
    };
    assert_eq!(TrainConfig::default().model.normals, Normals::Auto);
    assert_eq!(scheme(&[]), NormalScheme::Analytic);
    assert_eq!(scheme(&["model.preset=neuralangelo"]), NormalScheme::Analytic);
    assert_eq!(scheme(&["model.preset=neus-cpu"]), NormalScheme::Analytic);
    assert_eq!(scheme(&["model.preset=neus"]), NormalScheme::Analytic);
    assert_eq!(scheme(&["model.curvature=5e-4"]), NormalScheme::Tetrahedral);
    assert_eq!(scheme(&["model.normals=tetrahedral"]), NormalScheme::Tetrahedral);
    // Every preset's network has tangents (the positional encoding's too).
    assert_eq!(scheme(&["model.normals=analytic", "model.preset=neus-cpu"]), NormalScheme::Analytic);
    let bad = ["model.normals=analytic", "model.curvature=5e-4"];
    let err = TrainConfig::load(None, &bad.map(String::from)).unwrap_err();
    assert!(err.chain().contains("model.curvature"), "{}", err.chain());
}

#[test]
fn unknown_keys_bad_enums_and_bad_values_are_named() {
    for (o, expect) in [
        ("guide.scene.partitoin=2", "partitoin"),
        ("guide.scene.partition=0", "partition factor F"),
        ("guide.fixed_s=-1", "guide.fixed_s"),
        ("surface.beta=-1", "beta"),
        ("model.preset=nerf", "nerf"),
        ("guide.camera.view_dependency=sometimes", "sometimes"),
        ("output.mesh_formats=[\"stl\"]", "stl"),
        ("optim.schedule.warmup=1.5", "optim.schedule.warmup"),
        ("optim.table_moments=f16", "f16"),
        ("steps", "key=value"),
    ] {
        let err = TrainConfig::load(None, &[o.into()]).unwrap_err();
        assert!(err.chain().contains(expect), "{o}: {}", err.chain());
    }
    // bf16 moments are for hash tables.
    let err = TrainConfig::load(None, &["model.preset=\"neus-cpu\"".into(), "optim.table_moments=\"bf16\"".into()]).unwrap_err();
    assert!(err.chain().contains("optim.table_moments"), "{}", err.chain());
    assert_eq!(TrainConfig::load(None, &["optim.table_moments=\"bf16\"".into()]).unwrap().optim.table_moments, MomentStorage::Bf16);
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("bad.toml");
    std::fs::write(&file, "[render]\nrayz = 5\n").unwrap();
    let msg = TrainConfig::load(Some(&file), &[]).unwrap_err().chain();
    assert!(msg.contains("rayz") && msg.contains("bad.toml"), "{msg}");
}

/// Regression: a file's value of the wrong type came back as serde's bare "invalid type: unit
/// variant, expected string only", naming neither the key nor its section. Now the dotted key
/// leads the message, from a file given to `load` and from a run folder's `config.toml`.
#[test]
fn a_files_value_that_does_not_fit_is_named_by_its_dotted_key() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("config.toml");
    for (text, key) in [
        ("[data.builtin]\nbackdrop = true\n", "data.builtin.backdrop"),
        ("[model]\neikonal = \"strong\"\n", "model.eikonal"),
        ("[model]\neikonall = 0.1\n", "model.eikonall"),
        ("[guide.scene]\nresolution = -4\n", "guide.scene.resolution"),
    ] {
        std::fs::write(&file, text).unwrap();
        let msg = TrainConfig::load(Some(&file), &[]).unwrap_err().chain();
        assert!(msg.contains(&format!("{key}: ")) && msg.contains("config.toml"), "{text:?}: {msg}");
        let msg = TrainConfig::from_toml(text).unwrap_err().chain();
        assert!(msg.contains(&format!("{key}: ")), "{text:?}: {msg}");
    }
}

#[test]
fn steps_alone_turn_the_time_budget_off() {
    assert!(TrainConfig::default().timed());
    let c = TrainConfig::load(None, &["steps=40".into()]).unwrap();
    assert_eq!(c.budget, Budget::Steps(40));
    // The last budget given wins.
    let c = TrainConfig::load(None, &["steps=40".into(), "time_budget_s=30".into()]).unwrap();
    assert_eq!(c.budget, Budget::Time(Duration::from_secs(30)));
    let c = TrainConfig::load(None, &["time_budget_s=30".into(), "budget.steps=7".into()]).unwrap();
    assert_eq!(c.budget, Budget::Steps(7));
    for bad in ["steps=0", "time_budget_s=-1", "budget.seconds=0", "time_budget_s=1e300"] {
        assert!(TrainConfig::load(None, &[bad.into()]).is_err(), "{bad}");
    }
}

#[test]
fn a_run_folder_of_an_earlier_version_keeps_its_budget() {
    let mut old = TrainConfig::default().to_toml().replace("[budget]\nseconds = 120.0\n", "");
    old.insert_str(0, "steps = 300\ntime_budget_s = 90.0\n");
    assert_eq!(TrainConfig::from_toml(&old).unwrap().budget, Budget::Time(Duration::from_secs(90)));
    let old = old.replace("time_budget_s = 90.0", "time_budget_s = 0.0");
    assert_eq!(TrainConfig::from_toml(&old).unwrap().budget, Budget::Steps(300));
}

#[test]
fn a_struct_built_budget_is_the_budget() {
    // The trap of earlier versions: a `steps` field that only `load` made binding.
    let c = TrainConfig { budget: Budget::Steps(5), ..TrainConfig::default() };
    assert!(!c.timed() && c.budget.steps() == Some(5));
}

#[test]
fn durations_parse_with_units() {
    let secs = |t: &str| parse_duration(t).unwrap().as_secs_f64();
    assert_eq!((secs("90"), secs("10m"), secs("1.5h"), secs("45s"), secs("1e3s"), secs("2e1")), (90.0, 600.0, 5400.0, 45.0, 1000.0, 20.0));
    assert!(parse_duration("-3m").is_err() && parse_duration("3 weeks").is_err() && parse_duration("m").is_err());
    assert!(parse_duration("3d").unwrap_err().chain().contains("unknown unit"));
}

#[test]
fn every_sampler_reads_back_by_the_name_it_prints() {
    for kind in [SamplerKind::Guided, SamplerKind::Uniform, SamplerKind::ErrorMap, SamplerKind::SoftMining] {
        let c = TrainConfig::load(None, &[format!("sampler={}", kind.name())]).unwrap();
        assert_eq!(c.sampler, kind);
        assert_eq!(TrainConfig::from_toml(&c.to_toml()).unwrap().sampler, kind);
        #[cfg(feature = "clap")]
        assert_eq!(<SamplerKind as clap::ValueEnum>::from_str(kind.name(), false), Ok(kind));
    }
}

/// A mesh resolution is a number of cells or `"model"`, and either reads back from the run
/// folder's `config.toml` as written; another name or a number out of range is refused naming
/// the key.
#[test]
fn mesh_resolution_reads_a_number_or_model_and_round_trips() {
    let resolution = |o: &str| TrainConfig::load(None, &[o.to_string()]).map(|c| c.output.mesh_resolution);
    assert_eq!(resolution("output.mesh_resolution=256").unwrap(), MeshResolution::Cells(256));
    assert_eq!(resolution("output.mesh_resolution=model").unwrap(), MeshResolution::Model);
    for setting in [MeshResolution::Model, MeshResolution::Cells(300)] {
        let mut config = TrainConfig::default();
        config.output.mesh_resolution = setting;
        assert_eq!(TrainConfig::from_toml(&config.to_toml()).unwrap(), config);
    }
    for (bad, says) in [("output.mesh_resolution=fine", "\"model\""), ("output.mesh_resolution=4", "output.mesh_resolution")] {
        let err = resolution(bad).unwrap_err().chain();
        assert!(err.contains(says), "{bad}: {err}");
    }
    // On a command line (`eval --mesh-resolution`): the same values, the same range.
    assert_eq!(" 384 ".parse::<MeshResolution>(), Ok(MeshResolution::Cells(384)));
    assert_eq!("model".parse::<MeshResolution>(), Ok(MeshResolution::Model));
    assert_eq!("2048".parse::<MeshResolution>(), Ok(MeshResolution::Cells(2048)));
    for (bad, says) in [("7", "8 … 2048"), ("2049", "8 … 2048"), ("fine", "\"model\""), ("-3", "\"model\"")] {
        let err = bad.parse::<MeshResolution>().unwrap_err();
        assert!(err.contains(says), "{bad}: {err}");
    }
}

#[test]
fn the_initial_radius_is_auto_photos_or_a_number_in_the_bound() {
    use super::InitRadius;
    let radius = |v: &str| TrainConfig::load(None, &[format!("model.init_radius={v}")]).map(|c| c.model.init_radius);
    assert_eq!(TrainConfig::default().model.init_radius, InitRadius::Photos);
    assert_eq!(radius("0.3").unwrap(), InitRadius::Radius(0.3));
    assert_eq!(radius("auto").unwrap(), InitRadius::Auto);
    assert_eq!(radius("photos").unwrap(), InitRadius::Photos);
    assert!(radius("1.2").unwrap_err().chain().contains("model.init_radius"));
    assert!(radius("big").unwrap_err().chain().contains("auto, photos or a number"));
    // Written and read back as it was given.
    for (given, written) in [("0.3", "init_radius = 0.3"), ("photos", "init_radius = \"photos\"")] {
        let config = TrainConfig::load(None, &[format!("model.init_radius={given}")]).unwrap();
        let text = toml::to_string(&config).unwrap();
        assert!(text.contains(written), "{text}");
        assert_eq!(TrainConfig::from_toml(&text).unwrap().model.init_radius, config.model.init_radius);
    }
}

#[test]
fn the_guard_is_off_unless_given_a_positive_weight() {
    let load = |kv: &str| TrainConfig::load(None, &[kv.to_string()]).map(|c| (c.model.opacity_guard, c.model.opacity_guard_tolerance));
    assert_eq!(TrainConfig::default().model.opacity_guard, None);
    assert_eq!(load("model.opacity_guard=0.2").unwrap().0, Some(0.2));
    assert_eq!(load("model.opacity_guard=0").unwrap().0, None);
    assert_eq!(load("model.opacity_guard_tolerance=0.05").unwrap().1, Some(0.05));
    for bad in ["model.opacity_guard=-0.1", "model.opacity_guard_tolerance=-1", "model.opacity_guard_until=1.5", "model.opacity_guard_after=-0.2"] {
        let err = load(bad).unwrap_err().chain();
        assert!(err.contains(bad.split('=').next().unwrap()), "{bad}: {err}");
    }
    let config = TrainConfig::load(None, &["model.opacity_guard=0.2".to_string()]).unwrap();
    assert_eq!(TrainConfig::from_toml(&config.to_toml()).unwrap(), config);
}

#[test]
fn the_initial_s_is_the_presets_unless_given() {
    let init_s = |v: &str| TrainConfig::load(None, &[format!("model.init_s={v}")]).map(|c| c.model.init_s);
    assert_eq!(TrainConfig::default().model.init_s, None);
    assert_eq!(init_s("0").unwrap(), None);
    assert_eq!(init_s("4").unwrap(), Some(4.0));
    assert!(init_s("0.5").unwrap_err().chain().contains("model.init_s"));
    assert!(init_s("nan").unwrap_err().chain().contains("model.init_s"));
}

#[test]
fn the_geometry_holds_still_for_a_fraction_of_the_run_or_never() {
    let load = |v: &[&str]| TrainConfig::load(None, &v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    assert_eq!(TrainConfig::default().model.geometry_after, Some(0.05));
    assert_eq!(load(&["model.geometry_after=0.1"]).unwrap().model.geometry_after, Some(0.1));
    assert!(load(&["model.geometry_after=1"]).unwrap_err().chain().contains("model.geometry_after"));
    assert_eq!(load(&["model.geometry_after=0"]).unwrap().model.geometry_after, None);
}

#[test]
fn the_backgrounds_start_lies_beyond_its_near_radius() {
    let load = |v: &[&str]| TrainConfig::load(None, &v.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    assert_eq!(TrainConfig::default().model.background_near_start, Some(3.0));
    assert_eq!(load(&["model.background_near_start=3"]).unwrap().model.background_near_start, Some(3.0));
    assert!(load(&["model.background_near=2", "model.background_near_start=1.5"]).unwrap_err().chain().contains("model.background_near_start"));
    assert!(load(&["model.background_near_until=1.5"]).unwrap_err().chain().contains("model.background_near_until"));
}

#[test]
fn the_sdf_networks_depth_is_the_presets_unless_given() {
    let layers = |v: &str| TrainConfig::load(None, &[format!("model.sdf_layers={v}")]).map(|c| c.model.sdf_layers.map(std::num::NonZeroUsize::get));
    assert_eq!(TrainConfig::default().model.sdf_layers, None);
    assert_eq!(layers("0").unwrap(), None);
    assert_eq!(layers("2").unwrap(), Some(2));
    let err = layers("-1").unwrap_err().chain();
    assert!(err.contains("sdf_layers"), "{err}");
    let config = TrainConfig::load(None, &["model.sdf_layers=3".to_string()]).unwrap();
    assert_eq!(TrainConfig::from_toml(&config.to_toml()).unwrap(), config);
    // The run's networks (and so the memory model and a resumed run) have the layers asked.
    let backbone = crate::sizing::architecture(&config.model, None).unwrap();
    assert_eq!(backbone.sdf.b.config().hidden_layers, 3);
}

/// `model.smoothing_decay` is `levels` unless given, reads its two names and names the key of a
/// bad one.
#[test]
fn the_smoothing_decay_is_per_level_unless_given_and_names_a_bad_value() {
    let decay = |v: &str| TrainConfig::load(None, &[format!("model.smoothing_decay={v}")]).map(|c| c.model.smoothing_decay);
    assert_eq!(TrainConfig::default().model.smoothing_decay, SmoothingDecay::Levels, "Neuralangelo's, the default");
    assert_eq!(decay("levels").unwrap(), SmoothingDecay::Levels);
    assert_eq!(decay("none").unwrap(), SmoothingDecay::None);
    let err = decay("often").unwrap_err().chain();
    assert!(err.contains("smoothing_decay") && err.contains("often"), "{err}");
}

/// `model.log2_table` is the grid's own unless given; a given table replaces the preset's (and
/// the footprint's grown one) in the networks the run, the memory model and a resumed run build;
/// out of range, or on a preset without a hash grid, it is refused with the key named.
#[test]
fn a_given_table_size_replaces_the_grids_own_and_a_bad_one_is_refused() {
    let load = |given: &[&str]| TrainConfig::load(None, &given.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    assert_eq!(TrainConfig::default().model.log2_table, None);
    assert_eq!(load(&["model.log2_table=0"]).unwrap().model.log2_table, None);
    let config = load(&["model.log2_table=18"]).unwrap();
    assert_eq!(TrainConfig::from_toml(&config.to_toml()).unwrap(), config);
    let table = |model: &ModelConfig, footprint| {
        let backbone = crate::sizing::architecture(model, footprint).unwrap();
        let sdf_backbone::InputEncoding::HashGrid(grid) = &backbone.sdf.a else { panic!("a hash-grid preset") };
        (grid.encoding.config().log2_table, grid.encoding.config().finest_resolution)
    };
    assert_eq!(table(&TrainConfig::default().model, None), (16, 256));
    assert_eq!(table(&config.model, None), (18, 256), "the preset's levels, the table given");
    let mut sized = config.model.clone();
    sized.grid = GridSize::Footprint;
    assert_eq!(table(&sized, Some(2.0 / 512.0)), (18, 512), "the footprint's finest level, the table given (it would grow to 2^18 anyway)");
    sized.log2_table = Some(15);
    assert_eq!(table(&sized, Some(2.0 / 512.0)), (15, 512));
    for bad in ["model.log2_table=13", "model.log2_table=25"] {
        let err = load(&[bad]).unwrap_err().chain();
        assert!(err.contains("model.log2_table") && err.contains("14..=24"), "{err}");
    }
    let err = load(&["model.log2_table=18", "model.preset=\"neus-cpu\""]).unwrap_err().chain();
    assert!(err.contains("model.log2_table") && err.contains("hash-grid preset"), "{err}");
}

/// `model.smoothing_region` is `everywhere` unless given, reads its two names and names the key
/// of a bad one; a negative `model.smoothing_depth` is refused, and so is a depth with
/// `everywhere` (where it would be ignored).
#[test]
fn the_smoothing_region_reads_its_names_and_a_negative_depth_is_refused() {
    let region = |v: &str| TrainConfig::load(None, &[format!("model.smoothing_region={v}")]).map(|c| c.model.smoothing_region);
    assert_eq!(TrainConfig::default().model.smoothing_region, SmoothingRegion::Everywhere);
    assert_eq!(region("everywhere").unwrap(), SmoothingRegion::Everywhere);
    assert_eq!(region("outside").unwrap(), SmoothingRegion::Outside);
    let err = region("inside").unwrap_err().chain();
    assert!(err.contains("smoothing_region") && err.contains("inside"), "{err}");
    let err = TrainConfig::load(None, &["model.smoothing_depth=-1".to_string()]).unwrap_err().chain();
    assert!(err.contains("model.smoothing_depth"), "{err}");
    let err = TrainConfig::load(None, &["model.smoothing_depth=2".to_string()]).unwrap_err().chain();
    assert!(err.contains("model.smoothing_depth") && err.contains("everywhere"), "{err}");
    let depth = ["model.smoothing_region=\"outside\"", "model.smoothing_depth=2"].map(String::from);
    assert_eq!(TrainConfig::load(None, &depth).unwrap().model.smoothing_depth, 2.0);
}

/// The configuration is written through a `toml::Value` (one serialiser of it in the build, the
/// one `differences` uses); with `toml`'s `preserve_order` that is the text the struct's own
/// serialiser writes, sections and keys in the fields' order.
#[test]
fn the_configuration_is_written_in_its_fields_order() {
    let given = ["steps=300", "model.opacity_guard=0.2", "output.snapshots=[120, 360]", "model.init_radius=0.3", "output.mesh_resolution=\"model\""];
    let varied = TrainConfig::load(None, &given.map(String::from)).unwrap();
    for config in [TrainConfig::default(), varied] {
        let text = config.to_toml();
        assert_eq!(text, toml::to_string_pretty(&config).unwrap());
        assert!(text.find("[model]").unwrap() < text.find("[render]").unwrap(), "{text}");
        assert_eq!(TrainConfig::from_toml(&text).unwrap().to_toml(), text);
    }
}

/// `render.render_resolved`: on by default, 0 turns it off (and is written back as 0), a bound
/// outside (0, 1) is refused naming the key; it applies only with a trim, whose weights it reads.
#[test]
fn a_renders_resolution_bound_is_off_at_zero_and_checked() {
    let applied = |kv: &[&str]| TrainConfig::load(None, &kv.iter().map(|k| k.to_string()).collect::<Vec<_>>()).unwrap().render.resolved_applied();
    assert_eq!(applied(&[]), Some(0.02));
    assert_eq!(applied(&["render.render_trim=0"]), None, "no trim, no rule");
    assert_eq!(applied(&["render.render_resolved=0"]), None);
    let load = |kv: &str| TrainConfig::load(None, &[kv.to_string()]).map(|c| c.render.render_resolved);
    assert_eq!(TrainConfig::default().render.render_resolved, Some(0.02));
    assert_eq!(load("render.render_resolved=0").unwrap(), None);
    assert_eq!(load("render.render_resolved=0.1").unwrap(), Some(0.1));
    for bad in ["render.render_resolved=-0.1", "render.render_resolved=1.5"] {
        assert!(load(bad).unwrap_err().chain().contains("render.render_resolved"), "{bad}");
    }
    let config = TrainConfig::load(None, &["render.render_resolved=0".to_string()]).unwrap();
    assert_eq!(TrainConfig::from_toml(&config.to_toml()).unwrap(), config);
}
