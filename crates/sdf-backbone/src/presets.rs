//! The presets: named configurations sized for a 2-core CPU and at the papers' scale, their
//! networks ([`architecture`]), and their parameters initialised as a sphere ([`build`]: NeuS's
//! geometric initialisation, a least-squares readout, a short fit).

use crate::backbone::{Backbone, BackboneError, InputEncoding, SdfNet};
use crate::encoding::{PositionalEncoding, WithInput};
use crate::hashgrid::{HashGrid, HashGridConfig};
use crate::mlp::{Mlp, MlpConfig};
use crate::module::{Activation, Chain, Module};
use crate::optim::Adam;
use crate::pipeline::{ColorLoss, Differences, Pipeline, PipelineConfig, SmoothnessRegion};
use std::num::NonZeroUsize;

/// Named configurations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Preset {
    /// Hash grid 8 levels × 2 features, 2¹⁶ entries, 16 → 256; SDF MLP 1 × 64 (one hidden layer,
    /// as Neuralangelo and instant-nsr-pl; two until docs/DECISIONS.md §39); colour MLP 2 × 64.
    #[default]
    NeuralangeloCpu,
    /// Positional encoding (6 frequencies); SDF MLP 4 × 64; colour MLP 2 × 64.
    NeusCpu,
    /// Neuralangelo's scale: 16 levels × 8 features, 2²² entries, 32 → 2048; SDF MLP 1 × 256;
    /// colour MLP 4 × 256 (our colour input uses SH₄ of the direction, Neuralangelo's too).
    Neuralangelo,
    /// NeuS's scale: positional encoding (6), SDF MLP 8 × 256 with the skip at layer 4, 256
    /// features; colour MLP 4 × 256 (view direction by SH₄ instead of NeuS's PE(4)).
    Neus,
}

impl Preset {
    /// Every preset, in the order the docs list them.
    pub const ALL: [Preset; 4] = [Preset::NeuralangeloCpu, Preset::NeusCpu, Preset::Neuralangelo, Preset::Neus];

    /// Parses a preset's [`Preset::name`].
    pub fn from_name(name: &str) -> Result<Preset, BackboneError> {
        Preset::ALL.into_iter().find(|p| p.name() == name).ok_or_else(|| BackboneError::UnknownPreset(name.to_string()))
    }

    /// The name in configurations and on the command line ([`Preset::from_name`] reads it).
    pub fn name(self) -> &'static str {
        match self {
            Preset::NeuralangeloCpu => "neuralangelo-cpu",
            Preset::NeusCpu => "neus-cpu",
            Preset::Neuralangelo => "neuralangelo",
            Preset::Neus => "neus",
        }
    }

    /// Every preset's name, for messages.
    pub fn names() -> String {
        Preset::ALL.map(Preset::name).join(", ")
    }

    /// Whether the SDF network starts with a hash grid (the Neuralangelo presets): the ones with
    /// input tangents (analytic normals) and hash tables (bf16 table moments).
    pub fn has_hash_grid(self) -> bool {
        self.hash_grid().is_some()
    }

    /// The preset's hash grid (`None` for the positional-encoding presets).
    pub fn hash_grid(self) -> Option<HashGridConfig> {
        match self {
            Preset::NeuralangeloCpu => Some(HashGridConfig::neuralangelo_cpu()),
            Preset::Neuralangelo => Some(HashGridConfig { levels: 16, features: 8, log2_table: 22, base_resolution: 32, finest_resolution: 2048 }),
            Preset::NeusCpu | Preset::Neus => None,
        }
    }
}

/// Builds a preset with its parameters initialised: hash tables ±1e-4, SDF MLP geometric
/// (sphere of radius `radius`) with its readout calibrated by least squares, colour MLP He,
/// v = 0.3 (NeuS: s = e³ ≈ 20). Coarse-to-fine starts with all levels active (see
/// [`Backbone::set_active_levels`]).
pub fn build(preset: Preset, radius: f64, seed: u64) -> (Backbone, Vec<f32>) {
    build_from(assemble(preset, preset.hash_grid(), None), preset, radius, seed)
}

/// [`build`] with another hash grid than the preset's (a model sized by the data): the preset's
/// networks and initialisation on `grid`. An error for a preset without a hash grid.
pub fn build_with_grid(preset: Preset, grid: HashGridConfig, radius: f64, seed: u64) -> Result<(Backbone, Vec<f32>), BackboneError> {
    build_varied(preset, &Variation { grid: Some(grid), ..Variation::default() }, radius, seed)
}

/// What a run may change of a preset's networks; `Variation::default()` is the preset itself.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Variation {
    /// Another hash grid than the preset's (a model sized by the data); hash-grid presets only.
    pub grid: Option<HashGridConfig>,
    /// Hidden layers of the SDF network instead of the preset's (its width stays the preset's).
    pub sdf_layers: Option<NonZeroUsize>,
}

/// [`build`] with `variation` applied: the preset's initialisation on the varied networks.
pub fn build_varied(preset: Preset, variation: &Variation, radius: f64, seed: u64) -> Result<(Backbone, Vec<f32>), BackboneError> {
    Ok(build_from(architecture_varied(preset, variation)?, preset, radius, seed))
}

fn build_from(backbone: Backbone, preset: Preset, radius: f64, seed: u64) -> (Backbone, Vec<f32>) {
    let width = backbone.sdf.b.config().width;
    let n_enc = Module::<f32>::n_outputs(&backbone.sdf.a);
    init_parameters(backbone, preset, radius, seed, width, n_enc)
}

/// A preset's networks without parameters (sizes, layouts, memory estimates); [`build`] adds
/// initialised parameters.
pub fn architecture(preset: Preset) -> Backbone {
    assemble(preset, preset.hash_grid(), None)
}

/// [`architecture`] on another hash grid than the preset's (see [`build_with_grid`]).
pub fn architecture_with_grid(preset: Preset, grid: HashGridConfig) -> Result<Backbone, BackboneError> {
    architecture_varied(preset, &Variation { grid: Some(grid), ..Variation::default() })
}

/// [`architecture`] with `variation` applied. An error for another grid on a preset without a
/// hash grid.
pub fn architecture_varied(preset: Preset, variation: &Variation) -> Result<Backbone, BackboneError> {
    let grid = match &variation.grid {
        Some(_) if !preset.has_hash_grid() => return Err(BackboneError::NoHashGrid(preset.name())),
        Some(grid) => Some(grid.clone()),
        None => preset.hash_grid(),
    };
    Ok(assemble(preset, grid, variation.sdf_layers))
}

/// The preset's networks on `grid` (the encoding: a hash grid, else the positional encoding),
/// with `sdf_layers` hidden layers in the SDF network where given.
fn assemble(preset: Preset, grid: Option<HashGridConfig>, sdf_layers: Option<NonZeroUsize>) -> Backbone {
    let (width, preset_layers, features, color_width, color_layers) = match preset {
        Preset::NeuralangeloCpu => (64, 1, 15, 64, 2),
        Preset::NeusCpu => (64, 4, 15, 64, 2),
        Preset::Neuralangelo => (256, 1, 255, 256, 4),
        Preset::Neus => (256, 8, 256, 256, 4),
    };
    let layers = sdf_layers.map_or(preset_layers, NonZeroUsize::get);
    let encoding = match grid {
        Some(grid) => InputEncoding::HashGrid(WithInput { encoding: HashGrid::new(grid) }),
        None => InputEncoding::Positional(PositionalEncoding { frequencies: 6 }),
    };
    let n_enc = Module::<f32>::n_outputs(&encoding);
    let sdf_mlp = Mlp::new(MlpConfig {
        n_inputs: n_enc,
        width,
        hidden_layers: layers,
        n_outputs: 1 + features,
        skip: (layers >= 8).then_some(layers / 2),
        hidden_activation: Activation::Softplus { beta: 100.0 },
        output_activation: Activation::Identity,
    });
    let color = Mlp::new(MlpConfig {
        n_inputs: 22 + features,
        width: color_width,
        hidden_layers: color_layers,
        n_outputs: 3,
        skip: None,
        hidden_activation: Activation::Relu,
        output_activation: Activation::Sigmoid,
    });
    let finest = match &encoding {
        InputEncoding::HashGrid(g) => g.encoding.resolutions().last().copied().unwrap_or(256),
        InputEncoding::Positional(_) => 512,
    };
    Pipeline {
        sdf: Chain { a: encoding, b: sdf_mlp },
        color,
        background: None,
        config: PipelineConfig {
            color_loss: ColorLoss::L1,
            eikonal_weight: 0.1,
            mask_weight: 0.1,
            normal_step: 1.0 / f64::from(finest),
            normals: Differences::Tetrahedral,
            curvature_weight: 0.0,
            background: [0.0; 3],
            masked_color: false,
            opacity_entropy: 0.0,
            opacity_sparsity: 0.0,
            opacity_guard: None,
            normal_smoothness: 0.0,
            normal_smoothness_region: SmoothnessRegion::Everywhere,
        },
        analytic: None,
    }
}

/// Initial parameters of `backbone` (see [`build`]).
fn init_parameters(backbone: Backbone, preset: Preset, radius: f64, seed: u64, width: usize, n_enc: usize) -> (Backbone, Vec<f32>) {
    let layout = backbone.layout();
    let mut params = vec![0.0f32; layout.variance + 1];
    if let InputEncoding::HashGrid(g) = &backbone.sdf.a {
        g.encoding.init(&mut params[layout.encoding.clone()], 1e-4, seed);
    }
    let raw = 3;
    backbone.sdf.b.init_geometric(&mut params[layout.sdf_mlp.clone()], radius, raw, seed + 1);
    // Calibrate the SDF readout on points of [−1, 1]³ (the scene bound).
    {
        use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed ^ 0xC0FF_EE00_D15E_A5E5);
        let n = 32 * (width + 1);
        let x: Vec<f32> = (0..3 * n).map(|_| rng.random::<f32>() * 2.0 - 1.0).collect();
        let target: Vec<f32> = x.chunks_exact(3).map(|p| (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - radius as f32).collect();
        let mut enc = vec![0.0; n * n_enc];
        let mut ctx = vec![0.0; n * Module::<f32>::ctx_per_row(&backbone.sdf.a)];
        backbone.sdf.a.forward(&params[layout.encoding.clone()], &x, &mut enc, &mut ctx);
        backbone.sdf.b.calibrate_first_output(&mut params[layout.sdf_mlp.clone()], &enc, &target);
    }
    // The paper-scale presets skip the fit (minutes on a CPU): their max error is ~0.1.
    match preset {
        Preset::NeuralangeloCpu => fit_sphere(&backbone.sdf, &mut params[..layout.sdf_mlp.end], radius, 200, seed + 3),
        Preset::NeusCpu => fit_sphere(&backbone.sdf, &mut params[..layout.sdf_mlp.end], radius, 1000, seed + 3),
        Preset::Neuralangelo | Preset::Neus => {}
    }
    backbone.color.init_default(&mut params[layout.color.clone()], seed + 2);
    params[layout.variance] = 0.3;
    (backbone, params)
}

/// The most encoding parameters [`fit_sphere`] fits together with the network: the CPU presets'
/// tables (≈ 0.5 M) and a grid sized for photos of a few hundred pixels. Beyond it the fit holds
/// the tables at their initial values and fits the network alone: every step of the joint fit
/// writes a gradient of every table entry, and for a grid sized for DTU's 1600 × 1200 photos
/// (≈ 60 M) its 200 steps took minutes.
pub const FIT_TABLES_UP_TO: usize = 1 << 22;

/// Fits the SDF network to the sphere SDF `|x| − radius` on points of [−1, 1]³, a quarter of them
/// within 0.15 of the origin (`steps` Adam steps of 2048 points, L1): after the geometric initialisation and the calibrated readout, this
/// removes the residual error near the kink of |x| at the origin that a smooth readout cannot.
/// `params` are the encoding's and the network's; the encoding's are fitted too up to
/// [`FIT_TABLES_UP_TO`] of them, else held. Deterministic in `seed`; ≈ 0.5 s for the CPU
/// presets on 2 cores (a hash grid's tables summed over the entries each chunk touches).
pub fn fit_sphere(sdf: &SdfNet, params: &mut [f32], radius: f64, steps: u64, seed: u64) {
    use crate::module::batch_gradients;
    use crate::optim::WarmupCosine;
    use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
    let n_enc = Module::<f32>::n_params(&sdf.a);
    let joint = n_enc <= FIT_TABLES_UP_TO;
    let fitted = if joint { params.len() } else { params.len() - n_enc };
    let mut adam = Adam::new(fitted);
    adam.epsilon = 1e-15;
    let schedule = WarmupCosine { base: 1e-3, warmup: 10, total: steps, final_factor: 0.05 };
    let batch = 2048;
    let n_out = Module::<f32>::n_outputs(sdf);
    let mut grads = vec![0.0f32; fitted];
    // The loss of a chunk whose rows start with the point (the network's input does too).
    let l1 = |n_in: usize| {
        move |x: &[f32], y: &[f32], dy: &mut [f32]| {
            let mut l = 0.0;
            for r in 0..x.len() / n_in {
                let p = &x[n_in * r..n_in * r + 3];
                let target = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - radius as f32;
                let e = y[r * n_out] - target;
                l += f64::from(e.abs());
                dy[r * n_out] = e.signum() / batch as f32;
            }
            l
        }
    };
    let (n_features, n_ctx) = (Module::<f32>::n_outputs(&sdf.a), Module::<f32>::ctx_per_row(&sdf.a));
    // The encoded points, when the network is fitted alone.
    let rows = if joint { 0 } else { batch };
    let (mut features, mut ctx) = (vec![0.0f32; rows * n_features], vec![0.0f32; rows * n_ctx]);
    for step in 0..steps {
        // A quarter of the points near the origin, where the kink of |x| is hardest to follow.
        let x: Vec<f32> = (0..3 * batch).map(|i| (rng.random::<f32>() * 2.0 - 1.0) * if i < 3 * batch / 4 { 0.15 } else { 1.0 }).collect();
        grads.fill(0.0);
        if let (true, InputEncoding::HashGrid(grid)) = (joint, &sdf.a) {
            grid_network_gradients(sdf, grid, params, &x, &mut grads, l1(3));
            adam.update(params, &grads, schedule.at(step));
        } else if joint {
            batch_gradients(sdf, params, &x, 256, &mut grads, l1(3));
            adam.update(params, &grads, schedule.at(step));
        } else {
            let (encoding, network) = params.split_at_mut(n_enc);
            sdf.a.forward(encoding, &x, &mut features, &mut ctx);
            batch_gradients(&sdf.b, network, &features, 256, &mut grads, l1(n_features));
            adam.update(network, &grads, schedule.at(step));
        }
    }
    // The chunks' pooled buffers are not a training step's: give their memory back rather than
    // carry it into the run.
    crate::scratch::release_all();
}

/// [`batch_gradients`]`(sdf, params, x, 256, grads, loss)` for a network on a hash grid, to the
/// bit, without a gradient of every parameter per chunk: each chunk's network gradient and its
/// features' adjoints (`backward_deferring`), the network's summed in chunk order, the tables'
/// added level by level, chunk by chunk, over the entries the chunk touches
/// ([`HashGrid::add_level_gradient`]: the sums of a zeroed table per chunk added in order, where
/// the entries a chunk does not touch would add zeros). Zeroing and summing the 0.8 M parameters
/// of the CPU preset per chunk was most of the fit's time.
fn grid_network_gradients(
    sdf: &SdfNet,
    grid: &WithInput<HashGrid>,
    params: &[f32],
    x: &[f32],
    grads: &mut [f32],
    loss: impl Fn(&[f32], &[f32], &mut [f32]) -> f64 + Sync,
) {
    use crate::module::DeferringModule;
    use crate::scratch::Buf;
    use rayon::prelude::*;
    // Rows per chunk, as `fit_sphere`'s `batch_gradients` has them.
    const CHUNK: usize = 256;
    let n_enc = Module::<f32>::n_params(&sdf.a);
    let (n_out, n_ctx) = (Module::<f32>::n_outputs(sdf), Module::<f32>::ctx_per_row(sdf));
    let width = DeferringModule::<f32>::deferred_width(sdf);
    let parts: Vec<(Buf<f32>, Buf<f32>)> = x
        .par_chunks(CHUNK * 3)
        .map(|x| {
            let rows = x.len() / 3;
            let (mut out, mut ctx) = (Buf::<f32>::to_overwrite(rows * n_out), Buf::<f32>::to_overwrite(rows * n_ctx));
            let mut d_out = Buf::<f32>::zeroed(rows * n_out);
            sdf.forward(params, x, &mut out, &mut ctx);
            loss(x, &out, &mut d_out);
            let (mut d_net, mut record) = (Buf::<f32>::zeroed(params.len() - n_enc), Buf::<f32>::zeroed(rows * width));
            sdf.backward_deferring(params, x, &ctx, &d_out, &mut d_net, &mut record);
            (d_net, record)
        })
        .collect();
    for (d_net, _) in &parts {
        for (g, d) in grads[n_enc..].iter_mut().zip(d_net.iter()) {
            *g += *d;
        }
    }
    // The grid's columns of each record follow the raw input's (the network's input is [x, features]).
    let records: Vec<(&[f32], &[f32])> = x.chunks(CHUNK * 3).zip(&parts).map(|(x, (_, record))| (x, &record[..])).collect();
    let lead = Module::<f32>::n_inputs(&grid.encoding);
    let grid = &grid.encoding;
    let mut scratch = Vec::new();
    for level in 0..grid.config().levels {
        let range = grid.level_params(level);
        scratch.clear();
        scratch.resize(range.len(), 0.0f32);
        for (x, record) in &records {
            grid.add_level_gradient(level, x, record, lead, &mut scratch, &mut grads[range.clone()]);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::module::batch_gradients;

    /// The fit's sparse table gradients are `batch_gradients`' dense ones to the bit: the CPU
    /// preset's network (dense and hashed levels), random points, an L1 loss, a gradient that
    /// already holds values (both add to it).
    #[test]
    fn the_fits_table_gradients_over_touched_entries_are_the_dense_ones() {
        let (backbone, params) = build(Preset::NeuralangeloCpu, 0.5, 3);
        let sdf = &backbone.sdf;
        let InputEncoding::HashGrid(grid) = &sdf.a else { panic!("a hash-grid preset") };
        let n = Module::<f32>::n_params(sdf);
        let n_out = Module::<f32>::n_outputs(sdf);
        use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(11);
        let x: Vec<f32> = (0..3 * 2000).map(|_| rng.random::<f32>() * 2.0 - 1.0).collect();
        let loss = |x: &[f32], y: &[f32], dy: &mut [f32]| {
            for (r, p) in x.chunks_exact(3).enumerate() {
                let e = y[r * n_out] - ((p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt() - 0.4);
                dy[r * n_out] = e.signum() / 2000.0;
            }
            0.0
        };
        let start: Vec<f32> = (0..n).map(|i| if i % 7 == 0 { 1e-3 * (i % 13) as f32 } else { 0.0 }).collect();
        let (mut dense, mut sparse) = (start.clone(), start);
        batch_gradients(sdf, &params[..n], &x, 256, &mut dense, loss);
        grid_network_gradients(sdf, grid, &params[..n], &x, &mut sparse, loss);
        let differ = dense.iter().zip(&sparse).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
        assert_eq!(differ, 0, "{differ} of {n} gradients differ");
        assert!(dense.iter().zip(&params).filter(|(g, _)| **g != 0.0).count() > 1000, "the loss reaches the tables");
    }
}
