//! The training configuration: TOML with every knob of the paper and its ablations, typed (serde
//! enums and the libraries' own configuration structs), unknown keys and out-of-range values
//! rejected with the key named, `key=value` overrides on the command line.
//!
//! Where a library defines a knob (the scene and camera grids of `prob-grid`, the surface losses,
//! the learning-rate schedule), its struct is used here as it is: one default and one valid range
//! per knob, checked by the library's own `validate`. The trainer's sections set a few of those
//! defaults differently for a 2-core CPU (grids of 64³ and 32 × 32 × 64 instead of the paper's
//! 128³ and 64 × 64 × 128), which `TrainConfig::default` says.
//!
//! Schedules are defined on the *fraction of the run* done, so that a run can be bounded by
//! a number of steps or by training time alike ([`Budget`]): learning rate (warm-up and decay), coarse-to-fine levels,
//! the curvature ramp, the uniform-ray fractions and the grid updates (`guide.updates` per run).

use crate::error::{Context, Result};
use datasets::io::MeshFormat;
use prob_grid::{CameraGridConfig, SceneGridConfig};
use sdf_backbone::{LrSchedule, NormalScheme, Preset};
use serde::{Deserialize, Serialize};
use std::num::NonZeroUsize;
use std::path::Path;
use std::time::Duration;
use surface_losses::{ExtraPoints, SurfaceLossConfig};
use view_sampler::Interpolation;

mod annotated;
mod budget;
mod choices;
mod defaults;
mod off;
mod validate;
pub use annotated::annotated_default;
use budget::budget_from_short_keys;
pub use budget::{Budget, parse_duration, positive_duration};
pub use choices::{
    BackgroundGrid, BackgroundModel, GridSize, InitRadius, MeshFilter, MeshResolution, MomentStorage, Normals, Products, SamplerKind, SmoothingDecay,
    SmoothingRegion,
};

/// The default spacing of the points sampled on meshes for Chamfer (`output.chamfer_spacing`,
/// normalised units): every table in BENCHMARKS.md so far was measured with it, against the
/// built-in scene's stored truth points.
pub const DEFAULT_CHAMFER_SPACING: f64 = 0.004;

/// Everything a run needs. Defaults: the built-in scene on a 2-core CPU in ≤ 5 minutes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// Seed of every random stream.
    pub seed: u64,
    /// How long the run trains: `budget = { seconds = 120.0 }` or `budget = { steps = 300 }`
    /// (also written `steps = N` or `time_budget_s = X` in a file or an override). The schedules
    /// follow the fraction of the budget spent; the run stops at the budget and writes its mesh
    /// and metrics. Default 120 s: the default run takes the same time on any machine, and a
    /// faster build trains more iterations in it.
    pub budget: Budget,
    /// Which pixels train: guided (the paper), uniform, error-map or soft-mining.
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
    /// The loss-guided samplers (`error-map`, `soft-mining`).
    pub mining: MiningConfig,
    /// The surface losses (`surface-losses`' own configuration).
    pub surface: SurfaceLossConfig,
    /// Outputs.
    pub output: OutputConfig,
}

/// Data options.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DataConfig {
    /// Integer downscale of the images (area average; intrinsics follow).
    pub downscale: u32,
    /// Use the dataset's masks when it has them: the colour loss covers the foreground only and
    /// the mask BCE drives the opacity (NeuS).
    pub masks: bool,
    /// Every n-th view is held out for evaluation (0: none).
    #[serde(with = "off::zero_is_none")]
    pub holdout_every: Option<usize>,
    /// The region of interest `[x, y, z, radius]` in the dataset's own units, overriding what
    /// the format gives (COLMAP's sparse points, instant-ngp's `aabb`, NeRF-synthetic's default).
    /// Empty: the format's. An error for the IDR layout (its `scale_mat` is the bound: re-import)
    /// and the built-in scene.
    #[serde(with = "off::empty_is_none")]
    pub bound: Option<[f64; 4]>,
    /// The built-in scene (no `--data`).
    pub builtin: BuiltinConfig,
}

/// The built-in golden scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct BuiltinConfig {
    /// Analytic shape: composite (default), multipart, sphere, torus, box.
    pub shape: prob_grid::ShapeName,
    /// Image width (height = 3/4 of it).
    pub width: u32,
    /// Number of views.
    pub views: usize,
    /// What lies behind the object: `none` (black), `checker` (default), `coarse-checker`,
    /// `gradient`, `noise` (environments at infinity), `floor`, `wall` (near, crossing the bound).
    pub backdrop: datasets::golden::Backdrop,
    /// The cameras: `dtu` (default, an arc in front of and above the object), `ring` (a full
    /// turntable ring), `sphere`, `random`.
    pub rig: datasets::golden::rig::Rig,
    /// The region of interest's radius in the object's units (≥ 1; 1: the object fills the
    /// bound, 1.6: it fills 60 % of it, with free space around it as a capture's bound has).
    pub bound: f64,
}

/// The backbone.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// neuralangelo-cpu, neus-cpu, neuralangelo (paper scale), neus (paper scale).
    pub preset: Preset,
    /// The hash grid: `preset` (the preset's own) or `footprint` (sized by the data: the finest
    /// resolution from the training views' pixel footprint at the region of interest, printed
    /// before training with why; hash-grid presets).
    pub grid: GridSize,
    /// Hidden layers of the SDF network (0: the preset's; its width stays the preset's): fewer
    /// is cheaper per sample, so more steps fit a budget (docs/DECISIONS.md §39).
    #[serde(with = "off::zero_count_is_none")]
    pub sdf_layers: Option<NonZeroUsize>,
    /// Training-view pixels per finest cell of a grid sized by the footprint (1: a cell per
    /// pixel at the region of interest's centre; 2: half as fine).
    pub pixels_per_cell: f64,
    /// log₂ of the hash table's entries per level (0: the grid's own — the preset's 2¹⁶, or with
    /// `model.grid = "footprint"` the preset's grown with the finest level's surface); 14 … 24.
    /// A larger table has fewer hash collisions on the fine levels and more parameters (4× the
    /// table: 3.2× the preset's, the same time per step on a Zen 3, no lower error at a 15-minute
    /// run's steps: docs/DECISIONS.md §63); hash-grid presets.
    #[serde(with = "off::zero_is_none")]
    pub log2_table: Option<u32>,
    /// Radius of the initial sphere (bound radii): `photos` (the default: 0.5, NeuS's, with
    /// masks; without them a first phase of 400 steps finds how far the object reaches in the
    /// photos and the sphere is 0.6 of that, at most 0.5), `auto` (0.5 with masks; without them
    /// the largest up to 0.5 that leaves every view room around it: mends a loose bound on
    /// golden scenes, empties DTU scan 24) or a number in (0, 1); docs/DECISIONS.md §32–§34.
    pub init_radius: InitRadius,
    /// Hash-grid levels active at the start (coarse-to-fine; Neuralangelo: 4).
    pub initial_levels: usize,
    /// Fraction of the run after which all levels are active.
    pub all_levels_at: f64,
    /// Eikonal weight (NeuS: 0.1).
    pub eikonal: f64,
    /// Mask BCE weight. NeuS uses 0.1; with the colour loss over the foreground only (normalised
    /// by its ray count) the BCE alone carves the free space, and on the built-in scene (60 s
    /// budget, one seed) 0.1 / 0.5 / 1 / 2 gave Chamfer 0.0245 / 0.0171 / 0.0156 / 0.0163: 1.
    pub mask: f64,
    /// Curvature loss weight, reached linearly over the learning-rate warm-up (Neuralangelo:
    /// 5e-4; default 0: not measured to help on short runs).
    pub curvature: f64,
    /// Normal smoothness weight, `mean |nᵢ₊₁ − nᵢ|²` over neighbouring samples of each ray
    /// (the Hessian of S along the rays: zero on planes, large on bumps), reached linearly over
    /// the learning-rate warm-up like the curvature, then decayed by `smoothing_decay`. It needs
    /// no probes, so it works with analytic normals (default 0: at 0.1, decayed, Chamfer 0.96–0.98×
    /// on three masked scenes, inside the seeds' spread; docs/DECISIONS.md §41).
    pub normal_smoothness: f64,
    /// How the curvature and normal-smoothness weights follow the coarse-to-fine levels: `levels`
    /// (the default; Neuralangelo's: divided by the grid's growth for each level switched on after
    /// the initial ones) or `none` (as given to the end: normal smoothness 0.1 then costs 1.03–1.04×
    /// the Chamfer of none at all, where decayed it gains; docs/DECISIONS.md §41).
    pub smoothing_decay: SmoothingDecay,
    /// Which neighbouring samples the normal smoothness compares: `everywhere` (the default) or
    /// `outside` (pairs with a sample outside the solid or within `smoothing_depth` of its
    /// surface: not the solid's depth, where smoothing the normals that turn from the near side
    /// to the far side pushes the unseen far side out).
    pub smoothing_region: SmoothingRegion,
    /// With `smoothing_region = "outside"`: how deep inside the solid pairs still count, in cells
    /// of the finest active hash-grid level (0: only pairs with a sample outside; another depth
    /// with `everywhere` is refused, as it would be ignored).
    pub smoothing_depth: f64,
    /// Normals (and curvature) by tetrahedral (4 probes) or central (6 probes) differences, or
    /// `analytic`: the exact ∇ₓS by forward-mode derivatives (every preset; no curvature);
    /// `auto`: analytic where that holds, else tetrahedral ([`ModelConfig::normal_scheme`]).
    pub normals: Normals,
    /// Colour behind the object in renders (and, without masks and without a learned
    /// background, in the loss).
    pub background: [f64; 3],
    /// auto (learned without masks, fixed with them), learned, fixed.
    #[serde(alias = "learned_background")]
    pub background_model: BackgroundModel,
    /// Frequencies of the learned background's positional encoding of (x/r, 1/r) (NeRF++: 10).
    /// With 4 (the earlier default) the background could not carry a textured backdrop early in a
    /// run and the object's network painted it as walls inside the bound (docs/DECISIONS.md §23).
    pub background_frequencies: usize,
    /// Whether the learned background's colour depends on the view direction (NeRF++: yes). Off
    /// by default: with it the background can paint the object itself as a light field and
    /// leave the surface empty (docs/DECISIONS.md §23); surroundings are mostly diffuse.
    pub background_view: bool,
    /// Whether the learned background's network also reads a hash grid over the contracted
    /// background (instant-nsr-pl's remedy; `sdf_backbone::BackgroundModel::cpu_grid`): a
    /// backdrop's detail learnt at its own depth, so the object's network does not paint it
    /// inside the bound (floaters before a near wall) and keep it for the detail the MLP alone
    /// lacks. `auto` (the default): with uniform rays (docs/DECISIONS.md §42).
    pub background_grid: BackgroundGrid,
    /// A floor under the logistic scale s, rising geometrically over the run from the first
    /// value to the second (`[20, 400]`: 20 at the start, 400 at the end; `[]`: none). Without
    /// masks nothing else keeps the foreground from settling as a translucent haze that the
    /// background shows through (docs/DECISIONS.md §32).
    #[serde(with = "off::empty_is_none")]
    pub s_floor: Option<[f64; 2]>,
    /// The logistic scale s at the start (`s = exp(10 v)` of the variance parameter v; 0: the
    /// preset's, NeuS's 20). Neuralangelo starts DTU without masks at ≈ 4: a translucent
    /// foreground lets the learned background see the backdrop through it from the first step.
    #[serde(with = "off::zero_is_none")]
    pub init_s: Option<f64>,
    /// The radius (in bound radii, ≥ 1) from which the learned background holds anything
    /// (NeRF++: 1, the default). Further out, it cannot paint the object on a shell just behind
    /// it, nor a near backdrop (DTU's table) as background (docs/DECISIONS.md §33).
    pub background_near: f64,
    /// Where the learned background starts at the beginning of the run (bound radii, ≥
    /// `background_near`; 0: always at `background_near`; the default 3, docs/DECISIONS.md
    /// §35), moving in to `background_near` by
    /// `background_near_until` of the run: far at first, so that the background cannot take the
    /// object before the foreground has it; near later, so that a near backdrop (a table, a wall)
    /// can be background.
    #[serde(with = "off::zero_is_none")]
    pub background_near_start: Option<f64>,
    /// The fraction of the run over which the background moves in from `background_near_start`.
    pub background_near_until: f64,
    /// Without masks: the fraction of the run during which the geometry (the SDF's encoding and
    /// network, the variance) holds still while the colour network and the learned background
    /// learn (0: none), so that the background explains the backdrop before the foreground's
    /// hash grid can paint it into the bound (docs/DECISIONS.md §35). Unused with masks.
    #[serde(with = "off::zero_is_none")]
    pub geometry_after: Option<f64>,
    /// Without masks: weight of the opacity entropy of each ray (pushes a ray to hit the
    /// surface or miss it; a thin part becomes a surface rather than a haze). Unused with masks,
    /// whose BCE does the same with the truth.
    pub opacity_entropy: f64,
    /// Without masks: weight of each ray's foreground opacity (an L1: where the background
    /// explains a pixel as well as the foreground, it takes it). Unused with masks.
    pub opacity_sparsity: f64,
    /// Without masks: weight of the guard on the foreground, an L1 on the foreground's opacity
    /// of the rays whose learned background alone paints the pixel at least as well as the
    /// composite (and within `opacity_guard_tolerance`, where given): a floater in front of a
    /// backdrop the background paints is taken back (0: off, the default; docs/DECISIONS.md §36:
    /// it mends uniform rays' floaters before a near wall and takes thin parts). Unused with masks
    /// and in the first phase of `init_radius = "photos"`.
    #[serde(with = "off::zero_is_none")]
    pub opacity_guard: Option<f64>,
    /// How close (RMS colour error per channel) the background alone must come to a pixel for
    /// the guard to take the foreground's opacity there, beyond being at least as close as the
    /// composite (0: no such bound, the default).
    #[serde(with = "off::zero_is_none")]
    pub opacity_guard_tolerance: Option<f64>,
    /// The fraction of the run from which the guard works (0: from the start).
    #[serde(with = "off::zero_is_none")]
    pub opacity_guard_after: Option<f64>,
    /// The fraction of the run after which the guard stops (0: never, the default).
    #[serde(with = "off::zero_is_none")]
    pub opacity_guard_until: Option<f64>,
    /// The networks' matrix products: `f32` (default) or `bf16` (the hidden-to-hidden layers in
    /// bf16 where the CPU has AVX512_BF16; see BENCHMARKS.md, "bf16 products").
    pub products: Products,
}

/// Rays and samples per iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RenderConfig {
    /// Rays per iteration.
    pub rays: usize,
    /// Coarse samples per ray (NeuS: 64), stratified over the ray's occupied cells (with
    /// `skip_empty`, the default) or over [near, far]. 16 + 16 where the surface can be cost half
    /// of 32 + 32 over the whole ray per iteration (docs/DECISIONS.md §24: the equal-time gain).
    pub coarse: usize,
    /// Up-sampled samples per ray (NeuS: 64 in 4 rounds); guided runs give `guide.extra_points`
    /// of them to the points around λ̃, so both samplers use coarse + fine per ray.
    pub fine: usize,
    /// Up-sampling rounds (NeuS: 4).
    pub upsample_rounds: usize,
    /// Scale of the first up-sampling round, doubled each round (NeuS: 64).
    pub upsample_s: f64,
    /// Up-sampled samples per ray of the renders (PSNR of held-out and training views,
    /// validation pictures): no λ̃ there, so the up-sampling alone places the samples at the
    /// surface (docs/DECISIONS.md §20: the training's 32 in 2 rounds render as well as 96 in 6).
    pub render_fine: usize,
    /// Up-sampling rounds of the renders (scales `upsample_s` · 2^round).
    pub render_upsample_rounds: usize,
    /// Rendering weight a render may drop on each side of a ray: after up-sampling, a render's
    /// ray keeps only its samples between the first and last that carry more (most of a ray
    /// carries none: before the surface, behind it, or all of a ray that misses), so a pixel's
    /// colour differs by at most twice this and costs a fraction of the samples (0: every
    /// sample; BENCHMARKS.md, "Rendering for evaluation").
    pub render_trim: f64,
    /// A render's up-sampling places no more depths on a ray once no interval of it carries
    /// more than this weight at the model's scale, checked after the first round (0: every ray
    /// every round; like the trim's proof, it needs `render_trim` > 0). Most rays this stops
    /// carry next to nothing (grazing or missing the object, not proven faint), where a last
    /// round placed samples nothing needed: 4–10 % fewer SDF values, the PSNR within 10⁻⁴ dB
    /// (docs/DECISIONS.md §55; BENCHMARKS.md).
    #[serde(with = "off::zero_is_none")]
    pub render_resolved: Option<f64>,
    /// A render's colour stride: the colour and SDF networks run on every k-th of a ray's
    /// consecutive kept intervals (and the last), the intervals between taking the colour on the
    /// line in depth between them (1: every interval its own; opacity and depth never change).
    /// A soft model keeps a dozen or more intervals a ray, along which the colour changes
    /// little (docs/DECISIONS.md §51; BENCHMARKS.md, "A render's colour stride": its cost and PSNR).
    pub render_colour_stride: NonZeroUsize,
    /// Renders skip empty space: an occupancy of the field at the current s is built for each
    /// render, a ray's coarse samples lie in its occupied cells, and a ray that crosses none is
    /// rendered with no interval at all (opacity 0: its colour is the background's), no SDF
    /// evaluated along it.
    pub render_skip_empty: bool,
    /// Rays per work item (gradient chunk). Small enough that a work item's stored activations
    /// (rows × the MLPs' widths) stay in the core's cache between its forward and backward pass:
    /// 8 rays of 64 samples step 4–11 % faster than 32 (BENCHMARKS.md, "Where a step's time goes").
    pub chunk: usize,
    /// Empty-space skipping (both samplers): coarse samples only in the scene-grid cells that
    /// can hold the surface at the current s, refreshed at each grid update (false: over the
    /// whole ray, as NeuS).
    pub skip_empty: bool,
    /// Dilation of the occupancy in scene-grid cells.
    pub occupancy_dilation: u32,
}

/// Optimiser.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OptimConfig {
    /// Learning rate of the MLPs and the variance.
    pub lr: f64,
    /// Learning rate of the hash tables.
    pub lr_grid: f64,
    /// The schedule on the fraction of the run (`sdf-backbone`'s own configuration).
    pub schedule: LrSchedule,
    /// Clip the gradient's global norm (0: off).
    #[serde(with = "off::zero_is_none")]
    pub clip_norm: Option<f64>,
    /// Storage of the hash tables' Adam moments: `f32` (default) or `bf16` (hash-grid presets;
    /// paper-scale Neuralangelo then fits a step in 4 GB).
    pub table_moments: MomentStorage,
}

/// The probability-guided sampler (the paper's knobs and ablation switches).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GuideConfig {
    /// Grid updates per run: the grids are rebuilt at the start of each of `updates` equal parts
    /// of the run (6: every 50 iterations of 300).
    pub updates: u32,
    /// The scene grid (`prob-grid`'s configuration: resolution, partition F, …).
    pub scene: SceneGridConfig,
    /// The camera grids (`prob-grid`'s configuration: ru, rv, rl, view dependency VD, weighting
    /// η⁻² or exact mass, …).
    pub camera: CameraGridConfig,
    /// Interpolation of the conditionals: linear (the paper) or nearest.
    pub interpolation: Interpolation,
    /// FS: a fixed s for the probability update (0: the backbone's current s).
    #[serde(with = "off::zero_is_none")]
    pub fixed_s: Option<f64>,
    /// Fractions of uniform rays over equal parts of the run (paper: 0.2, 0.4, 0.6, 0.8).
    pub uniform_fractions: Vec<f64>,
    /// Extra points per ray around λ̃ (paper: 32 of 128; here half the fine samples).
    pub extra_points: usize,
    /// How the extra points are drawn: gaussian (paper), uniform (RU), log (Log).
    pub extra: ExtraPoints,
    /// Widen the extra points' spread by λ̃'s resolution, one λ bin of the camera grid, in
    /// quadrature (docs/DECISIONS.md §18; false: the paper's σ of the logistic at s alone, which
    /// late in a run is a tenth of a bin).
    pub extra_bin_spread: bool,
}

/// The loss-guided samplers: the competitors of the guided one (view-sampler's `ErrorMap`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MiningConfig {
    /// Cells per side of each view's error map at most (torch-ngp: 128).
    pub cells: u32,
    /// Weight of a new loss in a cell's moving average (torch-ngp: 0.9).
    pub new_weight: f64,
    /// Share of uniform pixels mixed into the error distribution, so that a cell whose loss fell
    /// to zero is still visited and updated.
    pub uniform: f64,
    /// Soft mining's α: each pixel's loss weighted by `(p_uniform / Q)^α` (0: the error map, 1:
    /// unbiased importance sampling).
    pub alpha: f64,
    /// α rises linearly from 0 over this fraction of the run (the paper warms it up).
    pub alpha_warmup: f64,
}

/// Outputs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputConfig {
    /// Validation pictures every n iterations (0: only at the end).
    #[serde(with = "off::zero_is_none")]
    pub validate_every: Option<u64>,
    /// Largest share of the training time spent on validation pictures: a due picture is
    /// skipped while the pictures so far took more than this share of the training time so far
    /// (a picture of a large scene costs many iterations: at 100 iterations apart, DTU scan 24's
    /// took twice the training time). 0 with `validate_every` > 0: no cap. The pictures are not
    /// counted in a time budget, so this is what they add to a run's wall time: 0.03 by default
    /// (3.6 s and 31 pictures in the default 2-minute run on a Xeon, 200–400 iterations apart).
    pub validate_share: f64,
    /// Downscale of the validation renders.
    pub validate_downscale: u32,
    /// Downscale of the renders for the final PSNR (held-out and training views). 1, the
    /// resolution trained on: one ray through the centre of a downscaled pixel, against the
    /// average of the pixels it covers, scores a sharp model below a blurred one
    /// (docs/DECISIONS.md §20).
    pub eval_downscale: u32,
    /// Held-out views rendered for the final PSNR (spread over the held-out set).
    pub eval_views: usize,
    /// Training views rendered for the final training-view PSNR (the render-fit figure).
    pub eval_train_views: usize,
    /// Mesh + Chamfer and PSNR of one held-out view every n iterations, logged (0: only at the
    /// end; not counted in the training time).
    #[serde(with = "off::zero_is_none")]
    pub metrics_every: Option<u64>,
    /// Snapshots at these training times (seconds): the mesh and its metrics (Chamfer,
    /// F-score, PSNR of the evaluation views) in `snapshots/<seconds>s/` and the log, not counted
    /// in the training time — quality against time from one run. Empty: none.
    pub snapshots: Vec<f64>,
    /// Each snapshot keeps the model's checkpoint too (`snapshots/<seconds>s/checkpoint.safetensors`,
    /// the size of the run's own: ≈ 20 MB for the default model), so that `cargo xtask eval --run
    /// RUN --snapshot T` renders or meshes that model again; false: the mesh and metrics only.
    pub snapshot_checkpoints: bool,
    /// Checkpoint every n iterations (0: only at the end; a stop signal writes one too). 1000 by
    /// default: the default model's checkpoint is 22 MB, and one every 100 iterations wrote
    /// 1.4 GB and added 2.5 s to the 2-minute run.
    #[serde(with = "off::zero_is_none")]
    pub checkpoint_every: Option<u64>,
    /// Log scalars every n iterations.
    pub log_every: u64,
    /// Marching-cubes resolution of the meshes (final and snapshots): cells per side of the
    /// bound's cube (8 … 2048), or `"model"`: as fine as the model's finest level
    /// ([`MeshResolution::Model`]).
    pub mesh_resolution: MeshResolution,
    /// Which connected components of the mesh are kept.
    pub mesh_filter: MeshFilter,
    /// `supported` without masks: the smallest component kept, as a fraction of the mesh's area
    /// (by area alone a small real part cannot be told from a floater: 0 keeps everything).
    pub min_component_area: f64,
    /// Mesh formats: any of ply, obj, glb.
    pub mesh_formats: Vec<MeshFormat>,
    /// Vertex colours (rendered along the normal) on the mesh.
    pub vertex_colors: bool,
    /// Spacing of the points sampled on meshes for Chamfer (normalised units).
    pub chamfer_spacing: f64,
    /// Chamfer outlier distance (normalised units; DTU: 20 mm ≈ 0.087 of scan 24's radius).
    pub chamfer_max_dist: f64,
    /// F-score threshold τ (normalised units).
    pub fscore_tau: f64,
}

/// Command-line overrides `key=value` as typed (dotted key, value) pairs for
/// [`TrainConfig::load_values`]: where text from a command line becomes typed.
pub fn parse_overrides(overrides: &[String]) -> Result<Vec<(String, toml::Value)>> {
    overrides
        .iter()
        .map(|o| {
            let (k, v) = o.split_once('=').with_context(|| format!("override {o:?} is not key=value"))?;
            Ok((k.trim().to_string(), override_value(v.trim())))
        })
        .collect()
}

/// A `key=value` override's value as TOML (`5`, `1e-3`, `true`, `[1, 2]`, `"text"`), taken as a
/// bare string when it is not TOML: where text from a command line becomes typed.
pub fn override_value(raw: &str) -> toml::Value {
    toml::from_str::<toml::Table>(&format!("v = {raw}")).ok().and_then(|mut t| t.remove("v")).unwrap_or_else(|| toml::Value::String(raw.to_string()))
}

/// Whether a dotted key names a key of the default configuration (or its budget).
fn is_default_key(key: &str) -> bool {
    if key == "steps" || key == "time_budget_s" || key == "budget" || key.starts_with("budget.") {
        return true;
    }
    let Ok(toml::Value::Table(table)) = toml::Value::try_from(TrainConfig::default()) else { return false };
    let mut value = &toml::Value::Table(table);
    for part in key.split('.') {
        match value.get(part) {
            Some(v) => value = v,
            None => return false,
        }
    }
    true
}

/// Sets `a.b.c = value` in a TOML table.
fn set_dotted(table: &mut toml::Table, key: &str, value: toml::Value) -> Result<()> {
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

/// Whether the override `key = value` alone, on the defaults, makes a configuration.
fn fits_alone(key: &str, value: &toml::Value) -> bool {
    let mut table = toml::Table::new();
    set_dotted(&mut table, key, value.clone()).is_ok() && budget_from_short_keys(&mut table).is_ok() && table.try_into::<TrainConfig>().is_ok()
}

impl RenderConfig {
    /// The bound of `render_resolved` a render applies: none without a trim (`render_trim` 0),
    /// whose weights the rule reads.
    pub fn resolved_applied(&self) -> Option<f64> {
        self.render_resolved.filter(|_| self.render_trim > 0.0)
    }
}

/// The configuration from its TOML table, or what does not fit prefixed by the dotted key it
/// is at (`data.builtin.backdrop: invalid type: …`): serde's own message names neither the key
/// nor its section.
fn from_table(table: toml::Table) -> std::result::Result<TrainConfig, String> {
    serde_path_to_error::deserialize(toml::Value::Table(table)).map_err(|e| {
        let path = e.path().to_string();
        let message = e.into_inner().message().to_string();
        if path == "." { message } else { format!("{path}: {message}") }
    })
}

impl TrainConfig {
    /// The defaults, then `file` (if any), then the `key=value` overrides; validated.
    pub fn load(file: Option<&Path>, overrides: &[String]) -> Result<TrainConfig> {
        TrainConfig::load_values(file, &parse_overrides(overrides)?)
    }

    /// The defaults, then `file` (if any), then typed overrides (dotted key, value: what a
    /// caller that has typed values, such as the Python binding, gives); validated. A budget
    /// among them (`steps`, `time_budget_s`, `budget…`) replaces the file's.
    pub fn load_values(file: Option<&Path>, overrides: &[(String, toml::Value)]) -> Result<TrainConfig> {
        let mut table = match file {
            Some(path) => {
                let text = std::fs::read_to_string(path).with_context(|| format!("cannot read config {}", path.display()))?;
                toml::from_str::<toml::Table>(&text).with_context(|| format!("config {} is not valid TOML", path.display()))?
            }
            None => toml::Table::new(),
        };
        budget_from_short_keys(&mut table).with_context(|| format!("config {}", file.map_or(Default::default(), |p| p.display().to_string())))?;
        for (k, v) in overrides {
            // A budget given on the command line replaces the file's (one budget per run).
            if k == "steps" || k == "time_budget_s" || k == "budget" || k.starts_with("budget.") {
                table.remove("budget");
            }
            set_dotted(&mut table, k, v.clone())?;
            budget_from_short_keys(&mut table)?;
        }
        let origin = file.map_or("the overrides".to_string(), |p| format!("{} and the overrides", p.display()));
        let config = from_table(table).map_err(|message| {
            // Name the override that is not a key, or the one whose value does not fit its key.
            let unknown = overrides.iter().map(|(k, _)| k).find(|k| !is_default_key(k));
            let key = match (unknown, overrides.iter().find(|(k, v)| !fits_alone(k, v))) {
                (Some(k), _) => format!(" (no key {k})"),
                (None, Some((k, v))) => format!(" ({k} = {v})"),
                (None, None) => String::new(),
            };
            crate::Error::Config(format!("config from {origin}{key}: {message}"))
        })?;
        config.validate().with_context(|| format!("config from {origin}"))?;
        Ok(config)
    }

    /// Parses the TOML text of a resolved configuration (a run folder's `config.toml`).
    pub fn from_toml(text: &str) -> Result<TrainConfig> {
        let mut table: toml::Table = toml::from_str(text).map_err(|e| crate::Error::Config(e.message().to_string()))?;
        budget_from_short_keys(&mut table)?;
        let config = from_table(table).map_err(crate::Error::Config)?;
        config.validate()?;
        Ok(config)
    }

    /// Whether the run is bounded by time rather than steps.
    pub fn timed(&self) -> bool {
        matches!(self.budget, Budget::Time(_))
    }

    /// The configuration as TOML (written to the run folder): through a `toml::Value`, the one
    /// serialiser of the configuration in the build (`differences` uses it too; the struct's own
    /// serialiser would double its code), the same text in the fields' order (`preserve_order`).
    pub fn to_toml(&self) -> String {
        let value = toml::Value::try_from(self).expect("the configuration serialises");
        toml::to_string_pretty(&value).expect("a TOML value serialises")
    }

    /// The keys whose values differ between two configurations (dotted paths), for messages.
    pub fn differences(&self, other: &TrainConfig) -> Vec<String> {
        fn walk(prefix: &str, a: &toml::Value, b: &toml::Value, out: &mut Vec<String>) {
            match (a, b) {
                (toml::Value::Table(ta), toml::Value::Table(tb)) => {
                    let mut keys: Vec<&String> = ta.keys().chain(tb.keys()).collect();
                    keys.sort();
                    keys.dedup();
                    for k in keys {
                        let key = if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") };
                        match (ta.get(k), tb.get(k)) {
                            (Some(x), Some(y)) => walk(&key, x, y, out),
                            _ => out.push(key),
                        }
                    }
                }
                _ if a != b => out.push(prefix.to_string()),
                _ => {}
            }
        }
        let (a, b) = (toml::Value::try_from(self).expect("serialises"), toml::Value::try_from(other).expect("serialises"));
        let mut out = Vec::new();
        walk("", &a, &b, &mut out);
        out
    }
}

#[cfg(test)]
mod tests;
