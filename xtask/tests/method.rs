//! Tests that guard the method through the trainer's own path: guidance is not a stub, the
//! surface-loss hook reaches the gradient, masked training ignores the backdrop.

use prob_grid::Shape;
use trainer::config::TrainConfig;
use trainer::data::SceneData;
use trainer::trainer::Trainer;

fn config(overrides: &[&str]) -> TrainConfig {
    let mut all: Vec<String> = ["data.builtin.width=96", "data.builtin.views=12", "render.rays=512", "guide.uniform_fractions=[0.0]"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    all.extend(overrides.iter().map(|s| s.to_string()));
    TrainConfig::load(None, &all).unwrap()
}

/// A guided batch drawn from a field close to the truth (the scene's own analytic SDF) lands
/// in the objects' silhouettes far more often than a uniform one, with λ̃ near the true depth.
/// It fails if the guide is stubbed (uniform pixels, or depths not from the grid).
#[test]
fn guided_rays_land_on_the_object_and_uniform_ones_do_not() {
    let shape = Shape::composite();
    let stats = |sampler: &str| {
        let config = config(&[&format!("sampler={sampler}")]);
        let data = SceneData::builtin(&config).unwrap();
        let mut trainer = Trainer::new(config, data).unwrap();
        if sampler == "guided" {
            let report = trainer.guide_from(&shape, 300.0).unwrap();
            assert!(report.empty_cameras.is_empty(), "{report:?}");
        }
        let batch = trainer.batch(0, 0.0, 300.0);
        let (mut in_mask, mut depth_errors) = (0usize, Vec::new());
        for (d, ray) in batch.drawn.iter().zip(&batch.rays) {
            in_mask += usize::from(ray.mask == Some(1.0));
            if let Some(depth) = d.depth {
                let view = &trainer.data().scene.views[trainer.split().train[d.camera as usize]];
                let r = view.camera.ray_through_pixel_index(d.pixel[0], d.pixel[1]);
                if let Some(t) = shape.ray_hit(r.origin, r.direction, 0.0, 10.0, 1e-7) {
                    let true_depth = t * view.camera.depth_per_distance(r.direction);
                    depth_errors.push((f64::from(depth.depth) - true_depth).abs());
                }
            }
        }
        depth_errors.sort_by(f64::total_cmp);
        let median = depth_errors.get(depth_errors.len() / 2).copied();
        (in_mask as f64 / batch.drawn.len() as f64, median, batch.drawn.iter().filter(|d| d.guided).count())
    };
    let (guided_in, guided_depth, guided_count) = stats("guided");
    let (uniform_in, uniform_depth, uniform_count) = stats("uniform");
    eprintln!("in mask: guided {guided_in:.3}, uniform {uniform_in:.3}; median |λ̃ − depth| guided {guided_depth:?}");
    assert_eq!((guided_count, uniform_count), (512, 0));
    assert!(uniform_depth.is_none(), "uniform rays have no λ̃");
    // Measured 0.74 vs 0.24 (the thin ring is 1–2 camera-grid cells wide, so some guided pixels
    // fall just beside it; the sampler's own golden test counts a one-cell dilation).
    assert!(guided_in > 0.6, "guided rays in the mask: {guided_in}");
    assert!(guided_in > 2.5 * uniform_in, "guided {guided_in} vs uniform {uniform_in}");
    // s = 300: the logistic's spread is ~0.006; grid cells (2/64 = 0.03) dominate.
    assert!(guided_depth.unwrap() < 0.03, "median depth error {guided_depth:?}");
}

/// The surface losses enter the gradient of a guided batch (weight 1 vs 0, same batch).
#[test]
fn the_surface_loss_hook_changes_the_gradient() {
    let gradient = |weight: &str| {
        let config = config(&["render.rays=64", &format!("surface.weight={weight}")]);
        let data = SceneData::builtin(&config).unwrap();
        let mut trainer = Trainer::new(config, data).unwrap();
        trainer.guide_from(&Shape::composite(), 100.0).unwrap();
        let batch = trainer.batch(3, 0.1, 100.0);
        let (loss, _) = trainer.gradient(&batch);
        (loss, trainer.gradients().to_vec())
    };
    let (l0, g0) = gradient("0");
    let (l1, g1) = gradient("1");
    assert!(l1 > l0, "the surface losses add to the loss: {l1} vs {l0}");
    let diff: f64 = g0.iter().zip(&g1).map(|(a, b)| f64::from(a - b).powi(2)).sum::<f64>().sqrt();
    let norm: f64 = g0.iter().map(|a| f64::from(*a).powi(2)).sum::<f64>().sqrt();
    assert!(diff > 1e-3 * norm, "the gradient did not change: |Δg| = {diff}, |g| = {norm}");
}

/// Masked training (NeuS): the colour loss never sees backdrop pixels, so a scene with a
/// textured backdrop gives the very same gradients as its black-backdrop twin.
#[test]
fn masked_training_ignores_the_backdrop() {
    let loss = |backdrop: bool| {
        let config = config(&["render.rays=128", &format!("data.builtin.backdrop={}", if backdrop { "checker" } else { "none" })]);
        let data = SceneData::builtin(&config).unwrap();
        let mut trainer = Trainer::new(config, data).unwrap();
        trainer.update_grids().unwrap();
        let batch = trainer.batch(0, 0.0, trainer.s());
        let backdrop_rays = batch.rays.iter().filter(|r| r.mask == Some(0.0) && r.target != [0.0; 3]).count();
        (trainer.gradient(&batch).0, trainer.gradients().to_vec(), backdrop_rays)
    };
    let (with, g_with, n_with) = loss(true);
    let (without, g_without, n_without) = loss(false);
    assert!(n_with > 10 && n_without == 0, "the backdrop is in the targets: {n_with} vs {n_without}");
    assert_eq!(with, without);
    assert_eq!(g_with, g_without);
}

/// A backdrop + mask scene trains exactly as its black-backdrop twin: after several
/// iterations (grid updates included) the parameters are equal bit for bit, so its Chamfer is
/// the twin's (the issue asked for within 1.2×; the backdrop never enters the loss).
#[test]
fn masked_backdrop_scene_trains_exactly_as_its_black_backdrop_twin() {
    let params = |backdrop: bool| {
        let config = config(&[
            "render.rays=64",
            "steps=6",
            "guide.updates=3",
            &format!("data.builtin.backdrop={}", if backdrop { "checker" } else { "none" }),
        ]);
        let data = SceneData::builtin(&config).unwrap();
        let mut trainer = Trainer::new(config, data).unwrap();
        while !trainer.done() {
            trainer.step().unwrap();
        }
        trainer.state().params.clone()
    };
    let (with, without) = (params(true), params(false));
    assert_eq!(with.len(), without.len());
    assert!(!with.is_empty());
    assert!(with.iter().zip(&without).all(|(a, b)| a.to_bits() == b.to_bits()), "the backdrop changed the training");
}

/// The default mesh filter keeps every real part of a multi-part scene (a base, a cage with a
/// ball seen only through its openings, a thin ring, a thin pole, a bowl) and drops a floater
/// outside the visual hull; `largest` would keep one part only.
#[test]
fn the_default_mesh_filter_keeps_every_part_and_drops_floaters() {
    use prob_grid::{MarchingCubesConfig, marching_cubes};
    use trainer::config::MeshFilter;
    use trainer::data::ViewSplit;
    let config = config(&["data.builtin.shape=multipart", "data.builtin.width=160", "data.builtin.views=24"]);
    let data = SceneData::builtin(&config).unwrap();
    let split = ViewSplit::new(&config, &data.scene);
    let floater = Shape::Sphere { center: glam::DVec3::new(0.55, -0.55, 0.45), radius: 0.06 };
    let field = Shape::Union(vec![Shape::multipart(), floater]);
    let (mesh, _) = marching_cubes(&field, &MarchingCubesConfig { resolution: 160, block: 16, ..Default::default() }).unwrap();
    let (_, count) = mesh.component_labels();
    assert_eq!(count, 7, "six parts and a floater");
    let filter = |f| trainer::outputs::filter_components(&mesh, f, &data.scene, &split.train, true, 0.01);
    let (_, found, kept) = filter(MeshFilter::Supported);
    assert_eq!((found, kept), (7, 6), "the supported filter keeps the six parts and drops the floater");
    let (_, _, kept) = filter(MeshFilter::Largest);
    assert_eq!(kept, 1);
    // Without masks the filter can only go by area, which cannot tell this floater (1.1 % of the
    // area) from the thin pole (0.7 %): at 0.5 % both stay (the default, 1 %, would drop the pole).
    let (_, _, kept) = trainer::outputs::filter_components(&mesh, MeshFilter::Supported, &data.scene, &split.train, false, 0.005);
    assert_eq!(kept, 7);
}
