//! Training without masks against the masked twin of the same scene (issue #37): the backdrop
//! stays out of the geometry.

use std::process::Command;

/// A small scene whose bound holds free space around the object (`data.builtin.bound = 1.6`,
/// as a capture's bound does) in front of a backdrop at infinity, 16 views of 64 × 48,
/// 400 iterations (deterministic).
const SCENE: &[&str] = &[
    "steps=400",
    "render.rays=256",
    "data.builtin.width=64",
    "data.builtin.views=16",
    "data.builtin.bound=1.6",
    "data.builtin.backdrop=coarse-checker",
    "output.validate_every=0",
    "output.checkpoint_every=0",
    "output.mesh_resolution=64",
    "output.eval_views=1",
    "output.eval_train_views=0",
];

/// A multi-part object before a near wall (`y = 1.1`, just beyond the bound) and a floor that
/// crosses it, seen from a DTU-like arc: 24 views of 100 × 75, 800 iterations (deterministic).
const NEAR_WALL: &[&str] = &[
    "steps=800",
    "render.rays=256",
    "data.builtin.width=100",
    "data.builtin.views=24",
    "data.builtin.shape=multipart",
    "output.validate_every=0",
    "output.checkpoint_every=0",
    "output.mesh_resolution=96",
    "output.eval_views=1",
    "output.eval_train_views=0",
];

/// The run's Chamfer (∞ when the mesh is nowhere near the object) and F-score on `scene`.
fn train_on(scene: &[&str], extra: &[&str]) -> (f64, f64) {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut args = vec!["train", "--json", "--seed", "0", "--out", out.to_str().unwrap()];
    args.extend_from_slice(scene);
    args.extend_from_slice(extra);
    let o = Command::new(env!("CARGO_BIN_EXE_xtask")).args(&args).output().expect("xtask runs");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let line = o.stdout.split(|&b| b == b'\n').find(|l| l.starts_with(b"{")).expect("a JSON summary");
    let summary: serde_json::Value = serde_json::from_slice(line).unwrap();
    let metrics = &summary["metrics"];
    (metrics["chamfer"].as_f64().unwrap_or(f64::INFINITY), metrics["f_score"].as_f64().unwrap())
}

/// [`train_on`] the small scene with free space around the object.
fn train(extra: &[&str]) -> (f64, f64) {
    train_on(SCENE, extra)
}

/// With the defaults without masks — the initial sphere from the photos (`model.init_radius =
/// "photos"`: 0.22 here, from the first phase's silhouettes), the geometry held still over the
/// first 5 % while the colour and the background learn (`model.geometry_after`), the background
/// moving in from 3 bound radii over the first quarter (`model.background_near_start`) — guided
/// and uniform runs land within 2× the masked twin's Chamfer with an F-score above half the
/// twin's (issue #37's bounds). Measured on the Zen 4 (release build): twin 0.0160 (F 0.56);
/// without masks guided 0.0224 (F 0.35), uniform 0.0201 (F 0.41); on the Xeon (uniform rays with
/// the background's own grid, §42): twin 0.0154 (F 0.57), guided 0.0213 (F 0.37), uniform 0.0209 (F 0.40); without the hold and the
/// moving background 0.0377 (F 0.05) and 0.0415 (F 0.02). With NeuS's sphere of radius 0.5 the
/// sphere filled every view, the network painted the backdrop on it, and carving it away carved
/// the object: no mesh near the object (Chamfer ∞, F 0) for both samplers; so did a first phase
/// with uniform rays (its silhouettes stayed the start's).
#[test]
fn without_masks_the_object_is_meshed_within_2x_its_masked_twins_chamfer() {
    let (twin, twin_f) = train(&[]);
    assert!(twin.is_finite() && twin < 0.03, "masked twin: Chamfer {twin}");
    for sampler in ["guided", "uniform"] {
        let (chamfer, f_score) = train(&["data.masks=false", "--sampler", sampler]);
        eprintln!("{sampler} without masks: Chamfer {chamfer:.4} (F {f_score:.3}) against the twin's {twin:.4} (F {twin_f:.3})");
        assert!(chamfer <= 2.0 * twin, "{sampler} without masks: Chamfer {chamfer} > 2 × the masked twin's {twin}");
        assert!(f_score >= 0.5 * twin_f, "{sampler} without masks: F-score {f_score} < half the masked twin's {twin_f}");
    }
}

/// Uniform rays spend most of a batch on a near wall's pixels while the background is still
/// moving in (§35), and the object's network painted the wall's detail as floaters inside the
/// bound, above the object, which it kept for the detail the background's MLP could not paint
/// (issue #37's last failure). With the background's own hash grid (uniform rays' default,
/// docs/DECISIONS.md §42) the background takes the detail at the wall's depth: within 1.5× the
/// masked twin's Chamfer with an F-score above half the twin's. Measured on the Xeon (release
/// build, the same settings): twin 0.0250 (F 0.274); without masks 0.0304 (F 0.211) with the grid, 0.0395
/// (F 0.082) without it (`model.background_grid=false`: 1.58×, F 0.30 of the twin's).
#[test]
fn uniform_rays_leave_no_floaters_before_a_near_wall() {
    let uniform = ["--sampler", "uniform"];
    let (twin, twin_f) = train_on(NEAR_WALL, &uniform);
    assert!(twin.is_finite() && twin < 0.04, "masked twin: Chamfer {twin}");
    let mut args = vec!["data.masks=false", "data.builtin.backdrop=wall"];
    args.extend_from_slice(&uniform);
    let (chamfer, f_score) = train_on(NEAR_WALL, &args);
    eprintln!("uniform before a near wall: Chamfer {chamfer:.4} (F {f_score:.3}) against the twin's {twin:.4} (F {twin_f:.3})");
    assert!(chamfer <= 1.5 * twin, "Chamfer {chamfer} > 1.5 × the masked twin's {twin}");
    assert!(f_score >= 0.5 * twin_f, "F-score {f_score} < half the masked twin's {twin_f}");
}
