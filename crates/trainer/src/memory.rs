//! A memory model of a run, computed before it starts: what stays resident (parameters, Adam's
//! moments, images, the guide's grids) and the largest working set of a phase (a training step,
//! the evaluation renders, meshing), in bytes, with the knobs each part depends on. The runner
//! prints it beside the machine's available memory and refuses a run that cannot fit, naming the
//! knobs that would make it fit (`--max-memory` overrides the limit).
//!
//! The model counts what the code allocates: a training step keeps, for every work item of the
//! batch, its gradient of the parameters after the hash tables and its deferred table-gradient
//! record until the batch is summed, and each thread holds one work item's buffers (the SDF and
//! colour networks' contexts and gradients, reused across work items); the table update holds
//! one level's gradient per thread. Checked against measured peaks in
//! `xtask/tests/memory.rs` (within 25 %).

use crate::config::TrainConfig;
use crate::data::SceneSize;
use sdf_backbone::module::{TangentModule, deferred_block_ranges};
use sdf_backbone::{Backbone, DeferringModule, Module, NormalScheme};

/// Bytes of f32.
const F32: f64 = 4.0;
/// The process without any data: code, libraries, thread stacks, allocator overhead.
const BASE: f64 = 40e6;

/// The parts of a run's peak memory, in bytes.
#[derive(Debug, Clone, PartialEq)]
pub struct MemoryEstimate {
    /// Parameters and Adam's two moments.
    pub parameters: f64,
    /// Images and masks.
    pub images: f64,
    /// The guide's camera grids, samplers and scene-grid evaluation.
    pub guide: f64,
    /// A training step's working set.
    pub step: f64,
    /// The evaluation renders' working set.
    pub evaluation: f64,
    /// Meshing's working set.
    pub meshing: f64,
    /// Whether the training step's buffers stay resident after it (see [`MemoryEstimate::peak`]).
    pub step_retained: bool,
}

impl MemoryEstimate {
    /// The estimated peak: everything resident, then the phases' working sets. The step's
    /// buffers go back to the allocator between phases (the scratch pool is emptied), but glibc
    /// keeps freed blocks below its adaptive mmap threshold (at most 32 MiB) in its arenas, so
    /// with the CPU presets' buffers (a few MB each) the resident size does not fall back and the
    /// post-training phases add to the step's working set (measured); buffers above the threshold
    /// are mapped and unmapped on their own (the paper-scale presets' tens to hundreds of MB), and
    /// then the phases replace each other.
    pub fn peak(&self) -> f64 {
        let after = self.evaluation.max(self.meshing);
        let phases = if self.step_retained { self.step + after } else { self.step.max(after) };
        BASE + self.parameters + self.images + self.guide + phases
    }

    /// One line per part for people.
    pub fn describe(&self) -> String {
        let gb = |b: f64| b / 1e9;
        format!(
            "parameters + Adam {:.2} GB, images {:.2} GB, guide {:.2} GB, training step {:.2} GB, evaluation {:.2} GB, meshing {:.2} GB: peak ≈ {:.2} GB",
            gb(self.parameters),
            gb(self.images),
            gb(self.guide),
            gb(self.step),
            gb(self.evaluation),
            gb(self.meshing),
            gb(self.peak())
        )
    }

    /// What to change to bring the peak under `limit`, largest part first.
    pub fn advice(&self, config: &TrainConfig) -> String {
        let mut parts = [
            (
                self.parameters,
                format!(
                    "model.preset (now {}; neuralangelo-cpu needs ~10 MB){}{} or, for a hash-grid preset, optim.table_moments = \"bf16\" (now {})",
                    config.model.preset.name(),
                    config
                        .model
                        .log2_table
                        .map_or(String::new(), |t| format!(", model.log2_table (now {t}; each 1 less halves the fine levels' tables)")),
                    match config.model.grid {
                        crate::config::GridSize::Footprint => {
                            format!(", model.pixels_per_cell (now {}; more: a coarser grid sized by the footprint)", config.model.pixels_per_cell)
                        }
                        crate::config::GridSize::Preset => String::new(),
                    },
                    format!("{:?}", config.optim.table_moments).to_lowercase()
                ),
            ),
            (
                self.step,
                format!("render.rays (now {}), render.chunk (now {}), or fewer threads (RAYON_NUM_THREADS)", config.render.rays, config.render.chunk),
            ),
            (self.images, format!("data.downscale (now {})", config.data.downscale)),
            (
                self.evaluation,
                format!(
                    "output.eval_downscale (now {}) or render.render_fine (now {}): the evaluation renders",
                    config.output.eval_downscale, config.render.render_fine
                ),
            ),
            (self.meshing, format!("output.mesh_resolution (now {}; 192: the default)", config.output.mesh_resolution)),
            (self.guide, format!("guide.camera.ru/rv/rl (now {}×{}×{})", config.guide.camera.ru, config.guide.camera.rv, config.guide.camera.rl)),
        ];
        parts.sort_by(|a, b| b.0.total_cmp(&a.0));
        parts.iter().map(|(b, knob)| format!("{knob}: {:.2} GB", b / 1e9)).collect::<Vec<_>>().join("; ")
    }
}

/// The SDF network's context values per row in a step: with analytic normals, what its
/// tangent passes read ([`TangentModule::forward_keeping_tangents`]).
fn sdf_ctx_per_row(backbone: &Backbone) -> f64 {
    let per_row = if backbone.normal_scheme() == NormalScheme::Analytic {
        TangentModule::<f32>::tangent_ctx_per_row(&backbone.sdf)
    } else {
        Module::<f32>::ctx_per_row(&backbone.sdf)
    };
    per_row as f64
}

/// Bytes of one work item's forward + backward buffers for `rays` rays of `samples` intervals.
fn work_item_bytes(backbone: &Backbone, rays: usize, samples: usize, backward: bool) -> f64 {
    let probes = backbone.normal_scheme().probe_count();
    let sdf_rows = (rays * ((probes + 1) * samples + 1)) as f64;
    let col_rows = (rays * samples) as f64;
    let sdf_out = Module::<f32>::n_outputs(&backbone.sdf) as f64;
    let sdf_ctx = Module::<f32>::ctx_per_row(&backbone.sdf) as f64;
    let col_in = Module::<f32>::n_inputs(&backbone.color) as f64;
    let col_ctx = Module::<f32>::ctx_per_row(&backbone.color) as f64;
    let width = backbone.sdf.b.config().width as f64;
    // Forward: points, outputs, contexts (with analytic normals the tangent passes' context, a
    // hash grid's Jacobian: §46); backward: output gradients, the layers' temporaries (dZ, dA),
    // the colour input gradient.
    let forward = sdf_rows * (3.0 + sdf_out + sdf_ctx_per_row(backbone)) + col_rows * (2.0 * col_in + col_ctx + 6.0);
    // Analytic normals: to train, the tangents along x, y, z of every layer (forward), then along
    // ∂L/∂n with their adjoints (backward); to render, one reverse pass for the input alone
    // (`input_gradient`: a layer's dZ and dA at a time).
    let tangents = match (backbone.normal_scheme() == NormalScheme::Analytic, backward) {
        (false, _) => 0.0,
        (true, true) => sdf_rows * (3.0 * (sdf_ctx + sdf_out) + 2.0 * sdf_ctx + 6.0),
        (true, false) => sdf_rows * (2.0 * width + sdf_out + 3.0),
    };
    let backward = if backward { sdf_rows * (sdf_out + 3.0 * width + 8.0) + col_rows * (col_in + 3.0 * width) } else { 0.0 };
    F32 * (forward + backward + tangents)
}

/// The memory model of `config` with `backbone` (`n_params` parameters) on a scene of `size`,
/// meshed at `mesh_resolution` cells per side, with `threads` worker threads.
pub fn estimate(
    config: &TrainConfig,
    backbone: &Backbone,
    n_params: usize,
    size: &SceneSize,
    mesh_resolution: u32,
    threads: usize,
) -> MemoryEstimate {
    let (views, pixel_bytes, view_pixels) = (size.views, size.pixel_bytes, size.largest_view_pixels);
    let t = threads.max(1) as f64;
    let n = n_params as f64;
    let tables = backbone.layout().encoding.len() as f64;
    let samples = config.render.coarse + config.render.fine;
    let chunks = config.render.rays.div_ceil(config.render.chunk) as f64;
    let rows_per_chunk = (config.render.chunk * ((backbone.normal_scheme().probe_count() + 1) * samples + 1)) as f64;
    // Analytic normals record the tangents too: twice the width, twice the points.
    let twice = if backbone.normal_scheme() == NormalScheme::Analytic { 2.0 } else { 1.0 };
    let record = twice * (DeferringModule::<f32>::deferred_width(&backbone.sdf) as f64 + 3.0);
    // The table update's buffer: one level's gradient per thread (the largest level's).
    let level = deferred_block_ranges::<f32, _>(&backbone.sdf).iter().map(|r| r.len()).max().unwrap_or(0) as f64;
    // Every work item's gradient (without the tables) and table record live until the sum.
    let batch = chunks * F32 * ((n - tables) + rows_per_chunk * record);
    let step = batch + t * work_item_bytes(backbone, config.render.chunk, samples, true) + t * F32 * level + F32 * (n - tables);
    // Evaluation renders: work items of `RENDER_CHUNK` rays, forward only, one per thread; a
    // band of rows (`RENDER_BAND_RAYS` pixels) at a time, each of its rays twice (the crossing
    // ones are copied for the up-sampling) with its depths and SDF values (a heap block each)
    // and its output; and for every pixel of the view its output, target, mask and image.
    let render_samples = (config.render.coarse + config.render.render_fine + 1) as f64;
    let rays_at = |downscale: u32| view_pixels as f64 / f64::from(downscale.pow(2));
    let render_rays = rays_at(config.output.eval_downscale.min(config.output.validate_downscale));
    let (ray, output) = (std::mem::size_of::<sdf_backbone::RayInput<f32>>() as f64, std::mem::size_of::<sdf_backbone::RayOutput<f32>>() as f64);
    let band = render_rays.min(crate::trainer::RENDER_BAND_RAYS as f64) * (2.0 * ray + 2.0 * (F32 * render_samples + 40.0) + output);
    // After a render, beside its outputs: PSNR and SSIM copy the predicted colours (SSIM's own
    // window, 5 × 11 rows of f64, is 0.7 MB at 1600 pixels wide); a validation panel is five RGB images side by side,
    // its PNG encoding (at most as large) and the hit pixels' depths.
    let after_render = (rays_at(config.output.eval_downscale) * 3.0 * F32).max(rays_at(config.output.validate_downscale) * (2.0 * 5.0 * 3.0 + F32));
    // The forward pass evaluates every `render_colour_stride`-th kept interval of a run (and its
    // last: one more a ray), at least as many rows as the up-sampling's first pass (coarse + 1).
    let stride = config.render.render_colour_stride.get();
    let evaluated = ((config.render.coarse + config.render.render_fine).div_ceil(stride) + 1).max(config.render.coarse + 1);
    let evaluation = t * work_item_bytes(backbone, crate::trainer::RENDER_CHUNK, evaluated, false)
        + band
        + render_rays * (output + 2.0 * 3.0 * F32 + 1.0)
        + after_render;
    // Meshing: a block of 17³ corners per thread through the SDF network (chunks of 1024
    // rows), and the mesh (~ 12 triangles per surface cell of the resolution's shell).
    let mesh_res = f64::from(mesh_resolution);
    let sdf_ctx = Module::<f32>::ctx_per_row(&backbone.sdf) as f64;
    // The mesh's picture: two views side by side (RGB), drawn one at a time at most
    // `MESH_PICTURE_WIDTH` wide by the golden renderer (which holds a whole view's hits).
    let picture_downscale = f64::from(crate::outputs::mesh_picture_downscale(size.widest_view));
    let picture_pixels = view_pixels as f64 / (picture_downscale * picture_downscale);
    let picture = picture_pixels * (datasets::golden::render::RENDER_BYTES_PER_PIXEL as f64 + 2.0 * 3.0);
    let meshing = t * F32 * 1024.0 * (sdf_ctx + 32.0) + mesh_res * mesh_res * 6.0 * 40.0 + picture;
    let cells = (config.guide.camera.ru * config.guide.camera.rv * config.guide.camera.rl) as f64;
    let guided = config.sampler == crate::config::SamplerKind::Guided;
    let scene_cells = (config.guide.scene.resolution as f64).powi(3);
    // The loss-guided samplers' error map: per view at most cells² errors (f32) and sums (f64).
    let mining_cells = f64::from(config.mining.cells).powi(2);
    let mining = if config.sampler.mines() { views as f64 * mining_cells * (F32 + 8.0) } else { 0.0 };
    let guide = if guided { views as f64 * cells * F32 * 3.0 } else { 0.0 } + scene_cells * 20.0 + mining;
    // The step's largest buffer, a work item's SDF context, against glibc's largest mmap
    // threshold (32 MiB on 64-bit Linux).
    let sdf_ctx_bytes = F32 * rows_per_chunk * sdf_ctx_per_row(backbone);
    let step_retained = sdf_ctx_bytes < 32.0 * 1024.0 * 1024.0;
    // Parameters in f32; Adam's two moments in f32, or bf16 for the tables (`optim.table_moments`).
    let moments = match config.optim.table_moments {
        crate::config::MomentStorage::F32 => 2.0 * F32 * n,
        crate::config::MomentStorage::Bf16 => 2.0 * F32 * (n - tables) + 2.0 * 2.0 * tables,
    };
    MemoryEstimate { parameters: F32 * n + moments, images: pixel_bytes as f64, guide, step, evaluation, meshing, step_retained }
}

/// The memory the kernel says is available for new work (`MemAvailable`), in bytes.
pub fn available_bytes() -> Option<f64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    Some(line.split_whitespace().nth(1)?.parse::<f64>().ok()? * 1024.0)
}

/// This process's peak resident memory (`VmHWM`), in bytes.
pub fn peak_rss_bytes() -> Option<f64> {
    status_kib("VmHWM:").map(|k| k * 1024.0)
}

/// This process's resident size now (bytes), `VmRSS` of `/proc/self/status` (Linux).
pub fn rss_bytes() -> Option<f64> {
    status_kib("VmRSS:").map(|k| k * 1024.0)
}

/// A `kB` line of `/proc/self/status`.
fn status_kib(key: &str) -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status.lines().find(|l| l.starts_with(key))?.split_whitespace().nth(1)?.parse::<f64>().ok()
}

/// Parses a size such as `8G`, `512M`, `2.5GB` into bytes.
pub fn parse_size(text: &str) -> crate::Result<f64> {
    let t = text.trim().to_ascii_uppercase();
    let t = t.trim_end_matches('B');
    let (number, scale) = match t.chars().last() {
        Some('K') => (&t[..t.len() - 1], 1e3),
        Some('M') => (&t[..t.len() - 1], 1e6),
        Some('G') => (&t[..t.len() - 1], 1e9),
        Some('T') => (&t[..t.len() - 1], 1e12),
        _ => (t, 1.0),
    };
    let value: f64 = number.trim().parse().map_err(|_| crate::Error::Config(format!("{text:?} is not a size (e.g. 8G, 512M)")))?;
    if !(value.is_finite() && value > 0.0) {
        crate::bail!(Config, "{text:?}: a size must be positive");
    }
    Ok(value * scale)
}
