//! The backbone API that trainer and sampler use: one pipeline type for both kinds of SDF
//! encoding, presets sized for a 2-core CPU (and the paper-scale ones one name away), the SDF as
//! a `prob_grid::SdfField`, coarse-to-fine levels with the normal step tied to the finest active
//! level, parameter groups for separate learning rates, and checkpoints (safetensors).

use crate::encoding::{PositionalEncoding, WithInput};
use crate::hashgrid::HashGrid;
use crate::mlp::Mlp;
use crate::module::{Chain, DeferringModule, Module, ScatterGradient, ScatterTangent, TangentAdjoints, TangentModule};
use crate::optim::Adam;
use crate::pipeline::Pipeline;
use crate::presets::Preset;
use crate::real::Real;
use glam::Vec3;
use std::ops::Range;

/// Errors of the backbone API.
#[derive(Debug, thiserror::Error)]
pub enum BackboneError {
    /// Unknown preset name.
    #[error("unknown backbone preset {0:?} (expected one of: {names})", names = Preset::names())]
    UnknownPreset(String),
    /// A checkpoint could not be parsed.
    #[error("checkpoint: {0}")]
    Checkpoint(String),
    /// A checkpoint does not fit this model.
    #[error("checkpoint tensor {name:?} has {found} values, the model needs {expected}")]
    SizeMismatch {
        /// Tensor name.
        name: String,
        /// Values found.
        found: usize,
        /// Values needed.
        expected: usize,
    },
    /// A hash grid was asked of a preset that has none.
    #[error("the preset {0} has no hash grid to size (a hash-grid preset: {hash})", hash = Preset::ALL.into_iter().filter(|p| p.has_hash_grid()).map(Preset::name).collect::<Vec<_>>().join(", "))]
    NoHashGrid(&'static str),
}

/// The SDF network's input encoding.
#[derive(Debug, Clone)]
pub enum InputEncoding {
    /// Neuralangelo: raw xyz + multi-resolution hash-grid features.
    HashGrid(WithInput<HashGrid>),
    /// NeuS: positional encoding (raw xyz + sin/cos).
    Positional(PositionalEncoding),
}

impl<R: Real> Module<R> for InputEncoding {
    fn n_params(&self) -> usize {
        match self {
            InputEncoding::HashGrid(g) => Module::<R>::n_params(g),
            InputEncoding::Positional(p) => Module::<R>::n_params(p),
        }
    }
    fn n_inputs(&self) -> usize {
        3
    }
    fn n_outputs(&self) -> usize {
        match self {
            InputEncoding::HashGrid(g) => Module::<R>::n_outputs(g),
            InputEncoding::Positional(p) => Module::<R>::n_outputs(p),
        }
    }
    fn ctx_per_row(&self) -> usize {
        match self {
            InputEncoding::HashGrid(g) => Module::<R>::ctx_per_row(g),
            InputEncoding::Positional(p) => Module::<R>::ctx_per_row(p),
        }
    }
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.forward(params, input, output, ctx),
            InputEncoding::Positional(p) => p.forward(params, input, output, ctx),
        }
    }
    fn backward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        match self {
            InputEncoding::HashGrid(g) => g.backward(params, input, ctx, d_output, d_params, d_input),
            InputEncoding::Positional(p) => p.backward(params, input, ctx, d_output, d_params, d_input),
        }
    }
}

impl<R: Real> ScatterGradient<R> for InputEncoding {
    fn gradient_blocks(&self) -> usize {
        match self {
            InputEncoding::HashGrid(g) => ScatterGradient::<R>::gradient_blocks(g),
            InputEncoding::Positional(p) => ScatterGradient::<R>::gradient_blocks(p),
        }
    }
    fn gradient_block_range(&self, block: usize) -> Range<usize> {
        match self {
            InputEncoding::HashGrid(g) => ScatterGradient::<R>::gradient_block_range(g, block),
            InputEncoding::Positional(p) => ScatterGradient::<R>::gradient_block_range(p, block),
        }
    }
    fn backward_parts(&self, parts: &[(&[R], &[R])], lead: usize, d_params: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.backward_parts(parts, lead, d_params),
            InputEncoding::Positional(p) => p.backward_parts(parts, lead, d_params),
        }
    }
    fn backward_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.backward_parts_block(parts, lead, block, d_block),
            InputEncoding::Positional(p) => p.backward_parts_block(parts, lead, block, d_block),
        }
    }
}

/// Analytic normals through either encoding.
impl<R: Real> TangentModule<R> for InputEncoding {
    fn tangent_ctx_per_row(&self) -> usize {
        match self {
            InputEncoding::HashGrid(g) => TangentModule::<R>::tangent_ctx_per_row(g),
            InputEncoding::Positional(p) => TangentModule::<R>::tangent_ctx_per_row(p),
        }
    }
    fn forward_keeping_tangents(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.forward_keeping_tangents(params, input, output, ctx),
            InputEncoding::Positional(p) => p.forward_keeping_tangents(params, input, output, ctx),
        }
    }
    fn forward_tangents(&self, params: &[R], input: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.forward_tangents(params, input, ctx, k, tangents_in, tangents_out),
            InputEncoding::Positional(p) => p.forward_tangents(params, input, ctx, k, tangents_in, tangents_out),
        }
    }
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        match self {
            InputEncoding::HashGrid(g) => g.backward_tangent(pass, d_params, d_input),
            InputEncoding::Positional(p) => p.backward_tangent(pass, d_params, d_input),
        }
    }
    fn input_gradient(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.input_gradient(params, input, ctx, d_output, d_input),
            InputEncoding::Positional(p) => p.input_gradient(params, input, ctx, d_output, d_input),
        }
    }
    fn input_gradient_of_forward(&self, params: &[R], input: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.input_gradient_of_forward(params, input, ctx, d_output, d_input),
            InputEncoding::Positional(p) => p.input_gradient_of_forward(params, input, ctx, d_output, d_input),
        }
    }
}

impl<R: Real> ScatterTangent<R> for InputEncoding {
    fn tangent_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, block: usize, d_block: &mut [R]) {
        match self {
            InputEncoding::HashGrid(g) => g.tangent_parts_block(parts, lead, block, d_block),
            InputEncoding::Positional(p) => p.tangent_parts_block(parts, lead, block, d_block),
        }
    }
}

/// The SDF network of every preset: encoding → MLP (first output: SDF; the rest: features).
pub type SdfNet = Chain<InputEncoding, Mlp>;

/// The render + loss pipeline of every preset.
pub type Backbone = Pipeline<SdfNet, Mlp>;

/// Where each part of the flat parameter buffer lives.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParamLayout {
    /// Encoding parameters (hash tables; empty for positional encoding).
    pub encoding: Range<usize>,
    /// SDF MLP.
    pub sdf_mlp: Range<usize>,
    /// Colour MLP.
    pub color: Range<usize>,
    /// The variance v (s = exp(10 v)).
    pub variance: usize,
    /// The learned background network (empty without one).
    pub background: Range<usize>,
    /// The learned background's hash tables, the end of `background` (empty without them):
    /// they learn at the tables' rate.
    pub background_tables: Range<usize>,
}

impl Backbone {
    /// Where each part of the parameters lives.
    pub fn layout(&self) -> ParamLayout {
        let n_enc = Module::<f32>::n_params(&self.sdf.a);
        let n_sdf = n_enc + Module::<f32>::n_params(&self.sdf.b);
        let n_col = n_sdf + Module::<f32>::n_params(&self.color);
        let n_bg = self.background.as_ref().map_or(0, crate::background::BackgroundModel::n_params);
        let tables = self.background.as_ref().map_or(n_bg..n_bg, crate::background::BackgroundModel::tables);
        let background = n_col + 1..n_col + 1 + n_bg;
        let background_tables = background.start + tables.start..background.start + tables.end;
        ParamLayout { encoding: 0..n_enc, sdf_mlp: n_enc..n_sdf, color: n_sdf..n_col, variance: n_col, background, background_tables }
    }

    /// Adds a learned background `model` (NeRF++'s inverted sphere beyond the bound,
    /// [`crate::background::BackgroundModel`]) and its parameters at the end of `params`.
    pub fn add_learned_background(&mut self, params: &mut Vec<f32>, model: crate::background::BackgroundModel, seed: u64) {
        let mut p = vec![0.0f32; model.n_params()];
        model.init(&mut p, seed);
        params.truncate(self.layout().variance + 1);
        params.extend_from_slice(&p);
        self.background = Some(model);
    }

    /// The logistic scale s of these parameters ([`crate::pipeline::scale_from_variance`]).
    pub fn scale(&self, params: &[f32]) -> f64 {
        crate::pipeline::scale_from_variance(f64::from(params[self.layout().variance]))
    }

    /// Runs the SDF and colour networks' products in `products` ([`crate::Products`]; the
    /// learned background keeps f32).
    pub fn set_products(&mut self, products: crate::Products) {
        self.sdf.b.set_products(products);
        self.color.set_products(products);
    }

    /// Hash-grid levels (None for positional encoding).
    pub fn levels(&self) -> Option<usize> {
        self.level_resolutions().map(<[u32]>::len)
    }

    /// The hash grid's resolution per level, coarsest first (None for positional encoding).
    pub fn level_resolutions(&self) -> Option<&[u32]> {
        match &self.sdf.a {
            InputEncoding::HashGrid(g) => Some(g.encoding.resolutions()),
            InputEncoding::Positional(_) => None,
        }
    }

    /// Coarse-to-fine: activates the first `active` hash-grid levels and ties the normal step to
    /// the finest active level (h = 1/N, half its cell on [−1, 1]). No effect for positional
    /// encoding.
    pub fn set_active_levels(&mut self, active: usize) {
        if let InputEncoding::HashGrid(g) = &mut self.sdf.a {
            let levels = g.encoding.resolutions().len();
            g.encoding.active_levels = active.clamp(1, levels);
            let finest = g.encoding.resolutions()[g.encoding.active_levels - 1];
            self.config.normal_step = 1.0 / f64::from(finest);
        }
    }

    /// The SDF of these parameters as a field the sampler and the mesher read.
    pub fn field<'a>(&'a self, params: &'a [f32]) -> BackboneField<'a> {
        BackboneField { backbone: self, params, lipschitz: 1.5 }
    }
}

/// A backbone's SDF with fixed parameters (implements `prob_grid::SdfField`).
pub struct BackboneField<'a> {
    backbone: &'a Backbone,
    params: &'a [f32],
    /// Bound on |∇S| the sparse grid update and the mesher may assume (a learnt SDF is ≈ 1;
    /// default 1.5).
    pub lipschitz: f32,
}

impl prob_grid::SdfField for BackboneField<'_> {
    fn sdf_batch(&self, points: &[Vec3], out: &mut [f32]) {
        assert_eq!(points.len(), out.len(), "sdf_batch: points and out differ in length");
        let x: Vec<f32> = points.iter().flat_map(|p| p.to_array()).collect();
        let values = self.backbone.sdf_values(self.params, &x);
        out.copy_from_slice(&values);
    }

    fn lipschitz_bound(&self) -> f32 {
        self.lipschitz
    }
}

/// Learning rates and clipping of one training step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepRates {
    /// Rate of the encoding's parameters (hash tables).
    pub tables: f32,
    /// Rate of everything else (MLPs, variance, background).
    pub rest: f32,
    /// Clip the gradient's global norm to this (None: off).
    pub clip_norm: Option<f32>,
    /// Factor on the geometry's rates — the encoding, the SDF network and the variance — (1: as
    /// above; 0: the geometry holds still while the colour network and the background learn).
    /// Adam's moments see every step either way.
    pub geometry: f32,
}

impl Backbone {
    /// One training step on `rays`: the loss and its gradient ([`Pipeline::loss_parallel_split`]),
    /// then Adam, the hash tables updated one level at a time from their deferred gradient (no
    /// gradient buffer the size of the tables: paper-scale Neuralangelo's 366 M table parameters
    /// need only themselves and Adam's moments). The same update as a dense gradient and
    /// [`adam_step`] (tested); the same bits for any thread count. Returns the loss and the
    /// per-ray outputs.
    pub fn train_step(
        &self,
        params: &mut [f32],
        adam: &mut Adam,
        rays: &[crate::pipeline::RayInput<f32>],
        chunk: usize,
        extra: &dyn crate::pipeline::SampleLoss,
        rates: StepRates,
    ) -> (f32, Vec<crate::pipeline::RayOutput<f32>>) {
        use rayon::prelude::*;
        let layout = self.layout();
        let n = params.len();
        let n_def = DeferringModule::<f32>::deferred_params(&self.sdf);
        debug_assert!(n_def == 0 || n_def == layout.encoding.len(), "the encoding's parameters are deferred whole");
        let mut rest = crate::scratch::Buf::<f32>::zeroed(n - n_def);
        let (loss, outputs, deferred) = self.loss_parallel_split(params, rays, &mut rest, chunk, extra);
        // The table blocks (levels; dense coarse levels are smaller than hashed ones).
        let blocks: Vec<Range<usize>> = crate::module::deferred_block_ranges::<f32, _>(&self.sdf);
        // The global norm for clipping (a first pass over the table blocks). Clipping therefore
        // scatters the table gradient twice, once for the norm and once for the update: keeping
        // the first pass's blocks would need a buffer the size of the tables, which this deferred
        // update exists to avoid. Clipping is off by default (`optim.clip_norm` = 0); with it on,
        // a step costs one more scatter (BENCHMARKS.md, "The backbone against PyTorch-CPU").
        let mut scale = 1.0f32;
        if let Some(max) = rates.clip_norm {
            let tables: f64 = blocks
                .par_iter()
                .enumerate()
                .map(|(b, range)| {
                    let mut g = crate::scratch::Buf::<f32>::zeroed(range.len());
                    deferred.apply_block(&self.sdf, b, &mut g);
                    g.iter().map(|x| f64::from(*x) * f64::from(*x)).sum::<f64>()
                })
                .sum();
            let norm = (tables + rest.iter().map(|x| f64::from(*x) * f64::from(*x)).sum::<f64>()).sqrt() as f32;
            if norm > max && norm.is_finite() {
                scale = max / norm;
            }
        }
        if scale != 1.0 {
            rest.iter_mut().for_each(|g| *g *= scale);
        }
        let step = adam.begin_step();
        let (p_tables, p_rest) = params.split_at_mut(n_def);
        // The tables' moments may be bf16 (`Adam::with_compact_prefix`), the rest's are f32.
        let (m_tables, m_rest, v_rest) = adam.split_moments(n_def);
        // Parameters after the tables: the encoding's own (none when deferred) at the table rate.
        let enc_rest = layout.encoding.len() - n_def;
        let (pe, pr) = p_rest.split_at_mut(enc_rest);
        let (me, mr) = m_rest.split_at_mut(enc_rest);
        let (ve, vr) = v_rest.split_at_mut(enc_rest);
        let (tables, geometry) = (rates.tables * rates.geometry, rates.rest * rates.geometry);
        {
            let _span = crate::profile::span(crate::profile::Stage::Adam);
            step.apply(pe, me, ve, &rest[..enc_rest], tables);
            // The parameters after the encoding, each group at its rate (the layout's ranges,
            // shifted to start at the encoding's end): the SDF network, the colour network, the
            // variance, the learned background and its tables.
            let groups = [
                (layout.sdf_mlp.clone(), geometry),
                (layout.color.clone(), rates.rest),
                (layout.variance..layout.variance + 1, geometry),
                (layout.background.start..layout.background_tables.start, rates.rest),
                (layout.background_tables.clone(), rates.tables),
            ];
            debug_assert_eq!(layout.background.end, n, "the groups cover the parameters after the encoding");
            let gr = &rest[enc_rest..];
            for (range, rate) in groups {
                let r = range.start - layout.encoding.end..range.end - layout.encoding.end;
                step.apply(&mut pr[r.clone()], &mut mr[r.clone()], &mut vr[r.clone()], &gr[r], rate);
            }
        }
        if n_def > 0 {
            // Each level: its gradient from the records (a scatter that reads no parameter), then
            // Adam on that level alone.
            let p_blocks = crate::module::split_blocks(p_tables, blocks.iter().cloned());
            let m_blocks = m_tables.split_blocks(&blocks);
            p_blocks.into_par_iter().zip(m_blocks).enumerate().for_each(|(b, (p, moments))| {
                let mut g = crate::scratch::Buf::<f32>::zeroed(p.len());
                deferred.apply_block(&self.sdf, b, &mut g);
                if scale != 1.0 {
                    g.iter_mut().for_each(|x| *x *= scale);
                }
                let _span = crate::profile::span(crate::profile::Stage::Adam);
                step.apply_moments(p, moments, &g, tables, blocks[b].start);
            });
        }
        (loss, outputs)
    }
}

/// Adam over parameter groups with their own learning rates and optional clipping of the
/// gradient's global norm.
pub fn adam_step(adam: &mut Adam, params: &mut [f32], grads: &mut [f32], groups: &[(Range<usize>, f32)], clip_norm: Option<f32>) {
    if let Some(max) = clip_norm {
        let norm = grads.iter().map(|g| f64::from(*g) * f64::from(*g)).sum::<f64>().sqrt() as f32;
        if norm > max && norm.is_finite() {
            let k = max / norm;
            grads.iter_mut().for_each(|g| *g *= k);
        }
    }
    adam.update_groups(params, grads, groups);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hashgrid::HashGridConfig;
    use crate::presets::{build, build_with_grid};
    use camera_geom::{Intrinsics, PinholeCamera, PixelCenters};
    use glam::DVec3;
    use prob_grid::{CameraGridConfig, SceneGridConfig, SdfField, Shape, update};

    #[test]
    fn the_sampler_reads_a_backbone_initialised_as_a_sphere() {
        // The paper initialises the camera grids "as a sphere" (the backbone's initial SDF):
        // the grids from the network at init match those from the analytic sphere.
        let (backbone, params) = build(Preset::NeuralangeloCpu, 0.5, 7);
        let k = Intrinsics { fx: 300.0, fy: 300.0, cx: 99.5, cy: 74.5, skew: 0.0 };
        let cam = PinholeCamera::look_at(DVec3::new(0.0, -3.0, 0.5), DVec3::ZERO, DVec3::Z, k, 200, 150, PixelCenters::Integer).unwrap();
        let scene = SceneGridConfig { resolution: 48, ..Default::default() };
        let cams = CameraGridConfig { ru: 16, rv: 16, rl: 32, ..Default::default() };
        let from_net = update(&backbone.field(&params), 20.0, &[cam], &scene, &cams).unwrap();
        let from_sphere = update(&Shape::Sphere { center: DVec3::ZERO, radius: 0.5 }, 20.0, &[cam], &scene, &cams).unwrap();
        let (a, b) = (from_net.cameras[0].pixel_marginal(), from_sphere.cameras[0].pixel_marginal());
        let (sa, sb) = (a.iter().sum::<f32>(), b.iter().sum::<f32>());
        let tv: f32 = 0.5 * a.iter().zip(&b).map(|(x, y)| (x / sa - y / sb).abs()).sum::<f32>();
        assert!(tv < 0.05, "total variation between the pixel marginals: {tv}");
    }

    /// Max and mean of |SDF(x) − (|x| − r)| over 5000 points inside the unit sphere.
    fn init_error(preset: Preset) -> (f32, f32) {
        let (backbone, params) = build(preset, 0.5, 3);
        sphere_error(&backbone, &params)
    }

    /// Max and mean of |SDF(x) − (|x| − 0.5)| over 5000 points inside the unit sphere.
    fn sphere_error(backbone: &Backbone, params: &[f32]) -> (f32, f32) {
        let mut state = 12345u64;
        let mut points = Vec::new();
        while points.len() < 5000 {
            let p = Vec3::ZERO.map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 40) as f32 / (1u64 << 24) as f32 * 2.0 - 1.0
            });
            if p.length() < 1.0 {
                points.push(p);
            }
        }
        let mut out = vec![0.0; points.len()];
        backbone.field(params).sdf_batch(&points, &mut out);
        let errors: Vec<f32> = points.iter().zip(&out).map(|(p, d)| (d - (p.length() - 0.5)).abs()).collect();
        (errors.iter().fold(0.0f32, |m, e| m.max(*e)), errors.iter().sum::<f32>() / errors.len() as f32)
    }

    #[test]
    fn calibrated_init_is_a_sphere_sdf_within_one_hundredth_on_average() {
        for preset in [Preset::NeuralangeloCpu, Preset::NeusCpu] {
            let (worst, mean) = init_error(preset);
            eprintln!("{}: max |SDF − (|x| − r)| = {worst}, mean {mean}", preset.name());
            assert!(mean <= 1e-2, "{}: mean |SDF − (|x| − r)| inside the unit sphere: {mean}", preset.name());
            assert!(worst <= 1e-2, "{}: max |SDF − (|x| − r)| inside the unit sphere: {worst}", preset.name());
        }
    }

    /// Guards the initialisation of a grid sized for large photos: with more table entries than
    /// [`crate::presets::FIT_TABLES_UP_TO`] the fit holds the tables and fits the network alone
    /// (the joint fit took minutes at DTU's full resolution), and the field is still the sphere:
    /// on average within the presets' bound (1e-2; the preset's one-layer network alone ≈ 0.006),
    /// worst at the kink of |x| at the origin, which the tables helped follow (≈ 0.03 there; the
    /// unfitted paper-scale presets ≈ 0.1).
    #[test]
    fn a_grid_too_large_to_fit_with_its_tables_starts_as_the_sphere_all_the_same() {
        let grid = crate::HashGridConfig { levels: 8, features: 2, log2_table: 19, base_resolution: 16, finest_resolution: 256 };
        let (backbone, params) = crate::presets::build_with_grid(Preset::NeuralangeloCpu, grid, 0.5, 3).unwrap();
        let layout = backbone.layout();
        assert!(layout.encoding.len() > crate::presets::FIT_TABLES_UP_TO, "{} table entries", layout.encoding.len());
        let (worst, mean) = sphere_error(&backbone, &params);
        assert!(mean <= 1e-2 && worst <= 5e-2, "max |SDF − (|x| − r)| = {worst}, mean {mean}");
        // The tables kept their initial values: uniform within ±1e-4.
        assert!(params[layout.encoding.clone()].iter().all(|v| v.abs() <= 1e-4));
    }

    /// Guards `model.sdf_layers`: a varied SDF network has the layers asked (the preset's width,
    /// encoding and colour network unchanged) and starts as the sphere as closely as the preset.
    #[test]
    fn an_sdf_network_of_other_depth_has_its_layers_and_starts_as_the_sphere() {
        let preset_params = build(Preset::NeuralangeloCpu, 0.5, 3).1.len();
        for layers in [2, 3] {
            let variation = crate::Variation { sdf_layers: std::num::NonZeroUsize::new(layers), ..Default::default() };
            let (backbone, params) = crate::build_varied(Preset::NeuralangeloCpu, &variation, 0.5, 3).unwrap();
            let config = backbone.sdf.b.config();
            assert_eq!((config.hidden_layers, config.width), (layers, 64));
            // A 64 × 64 layer (+ bias) more per layer than the preset's one.
            assert_eq!(params.len() - preset_params, (layers - 1) * 64 * 65);
            let (worst, mean) = sphere_error(&backbone, &params);
            assert!(mean <= 1e-2 && worst <= 1e-2, "{layers} layers: max |SDF − (|x| − r)| = {worst}, mean {mean}");
        }
        let grid = crate::Variation { grid: Some(HashGridConfig::neuralangelo_cpu()), ..Default::default() };
        assert!(matches!(crate::build_varied(Preset::NeusCpu, &grid, 0.5, 3), Err(BackboneError::NoHashGrid("neus-cpu"))));
    }

    /// The fused step (tables updated level by level from their deferred gradient) is the dense
    /// gradient + Adam, with and without clipping.
    #[test]
    fn train_step_equals_dense_gradient_and_adam() {
        for background_grid in [false, true] {
            train_step_equals_dense_gradient_and_adam_with(background_grid);
        }
    }

    /// With `background_grid`, a learned background with a hash grid, whose tables learn at the
    /// tables' rate.
    fn train_step_equals_dense_gradient_and_adam_with(background_grid: bool) {
        let (mut backbone, mut params) = build(Preset::NeuralangeloCpu, 0.5, 2);
        if background_grid {
            let grid = crate::HashGridConfig { levels: 3, features: 2, log2_table: 10, base_resolution: 4, finest_resolution: 16 };
            backbone.add_learned_background(&mut params, crate::BackgroundModel::cpu(4, false).with_grid(grid), 5);
            let layout = backbone.layout();
            assert!(!layout.background_tables.is_empty() && layout.background_tables.end == layout.background.end);
        }
        backbone.set_active_levels(6);
        let rays: Vec<crate::pipeline::RayInput<f32>> = (0..40)
            .map(|r| {
                let a = r as f32 * 0.05;
                crate::pipeline::RayInput {
                    origin: [3.0 * a.cos(), 3.0 * a.sin(), 0.2],
                    direction: glam::Vec3::new(-a.cos(), -a.sin(), -0.05).normalize().to_array(),
                    depths: (0..=24).map(|i| 2.0 + 2.0 * i as f32 / 24.0).collect(),
                    target: [0.4, 0.5, 0.6],
                    mask: Some(if r % 4 == 0 { 0.0 } else { 1.0 }),
                    weight: 1.0,
                }
            })
            .collect();
        let layout = backbone.layout();
        let n = params.len();
        // bf16 table moments too: the level-by-level update and the dense one round alike.
        // A geometry factor of 0.5 too: the encoding, the SDF network and the variance at half rate.
        for (clip, compact, geometry) in [(None, false, 1.0), (Some(1e-3), false, 1.0), (None, true, 1.0), (None, false, 0.5)] {
            let rates = StepRates { tables: 1e-2, rest: 5e-3, clip_norm: clip, geometry };
            let adam = || if compact { Adam::with_compact_prefix(n, layout.encoding.len()) } else { Adam::new(n) };
            let (mut fused, mut adam_f) = (params.clone(), adam());
            let (lf, _) = backbone.train_step(&mut fused, &mut adam_f, &rays, 8, &crate::pipeline::NoSampleLoss, rates);
            let (mut dense, mut adam_d) = (params.clone(), adam());
            let mut grads = vec![0.0f32; n];
            let (ld, _) = backbone.loss_parallel(&dense, &rays, &mut grads, 8, &crate::pipeline::NoSampleLoss);
            let tables = layout.background_tables.clone();
            let ranges = [
                (layout.encoding.clone(), 1e-2 * geometry),
                (layout.sdf_mlp.clone(), 5e-3 * geometry),
                (layout.color.clone(), 5e-3),
                (layout.variance..layout.variance + 1, 5e-3 * geometry),
                (layout.background.start..tables.start, 5e-3),
                (tables, 1e-2),
            ];
            adam_step(&mut adam_d, &mut dense, &mut grads, &ranges, clip);
            assert_eq!(lf, ld);
            let worst = fused.iter().zip(&dense).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-7,
                "clip {clip:?}, compact {compact}, geometry {geometry}, background grid {background_grid}: parameters differ by {worst}"
            );
            let t = layout.background_tables.clone();
            assert!(!background_grid || fused[t.clone()] != params[t], "the background's tables learn");
            assert_eq!(adam_f.step, adam_d.step);
            assert_eq!(adam_f.compact.as_ref().map(|c| &c.v), adam_d.compact.as_ref().map(|c| &c.v));
        }
    }

    /// The learned background's tables are left out of the chunks' gradient buffers and added
    /// from the chunks' records (`BackgroundModel::add_deferred`): the gradient is the same, to the
    /// bit, as one dense buffer per chunk summed in chunk order — on hashed levels whose entries
    /// several points and chunks share, and with a level switched off.
    #[test]
    fn the_background_tables_gradient_from_records_is_the_per_chunk_sum_to_the_bit() {
        let (mut backbone, mut params) = build(Preset::NeuralangeloCpu, 0.5, 3);
        let grid = crate::HashGridConfig { levels: 3, features: 2, log2_table: 8, base_resolution: 4, finest_resolution: 24 };
        backbone.add_learned_background(&mut params, crate::BackgroundModel::cpu(4, false).with_grid(grid), 6);
        let rays: Vec<crate::pipeline::RayInput<f32>> = (0..44)
            .map(|r| {
                let a = r as f32 * 0.07;
                crate::pipeline::RayInput {
                    origin: [3.0 * a.cos(), 3.0 * a.sin(), 0.3],
                    direction: glam::Vec3::new(-a.cos(), -a.sin(), 0.1 - 0.01 * r as f32).normalize().to_array(),
                    depths: (0..=16).map(|i| 2.0 + 2.0 * i as f32 / 16.0).collect(),
                    target: [0.3, 0.5, 0.7],
                    mask: None,
                    weight: 1.0,
                }
            })
            .collect();
        let n_def = DeferringModule::<f32>::deferred_params(&backbone.sdf);
        let tables = backbone.layout().background_tables;
        for active in [3, 2] {
            backbone.background.as_mut().unwrap().grid.as_mut().unwrap().active_levels = active;
            let mut split = vec![0.0f32; params.len() - n_def];
            let (loss, _, _) = backbone.loss_parallel_split(&params, &rays, &mut split, 8, &crate::pipeline::NoSampleLoss);
            let mut dense = vec![0.0f32; params.len() - n_def];
            let reference = backbone.loss_split_dense_reference(&params, &rays, &mut dense, 8);
            assert_eq!(loss.to_bits(), reference.to_bits());
            let t = tables.start - n_def..tables.end - n_def;
            assert!(split[t.clone()].iter().filter(|g| **g != 0.0).count() > 100, "the tables get a gradient");
            let differ = split.iter().zip(&dense).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
            assert_eq!(differ, 0, "{active} levels: {differ} of {} gradients differ in their bits", split.len());
        }
    }

    #[test]
    fn coarse_to_fine_ties_the_normal_step_to_the_finest_active_level() {
        let (mut backbone, _) = build(Preset::NeuralangeloCpu, 0.5, 1);
        backbone.set_active_levels(1);
        assert!((backbone.config.normal_step - 1.0 / 16.0).abs() < 1e-12);
        backbone.set_active_levels(100);
        assert!((backbone.config.normal_step - 1.0 / 256.0).abs() < 1e-12);
        assert_eq!(Preset::from_name("neus").unwrap(), Preset::Neus);
        assert!(Preset::from_name("nerf").is_err());
    }

    /// A grid sized by the data keeps the preset's level spacing, ends at the asked resolution,
    /// starts as a sphere like the preset, and is refused by the presets without a hash grid.
    #[test]
    fn a_grid_reaching_another_resolution_keeps_the_presets_spacing() {
        let cpu = HashGridConfig::neuralangelo_cpu();
        assert_eq!(cpu.reaching(256, 16), cpu);
        let finer = cpu.reaching(512, 18);
        assert_eq!((finer.levels, finer.finest_resolution, finer.log2_table, finer.base_resolution), (10, 512, 18, 16));
        let grid = HashGrid::new(finer.clone());
        let r = grid.resolutions();
        assert_eq!((r[0], r[r.len() - 1]), (16, 512));
        let coarse = cpu.reaching(8, 14);
        assert_eq!((coarse.levels, coarse.finest_resolution), (1, 16));
        let (backbone, params) = build_with_grid(Preset::NeuralangeloCpu, finer, 0.5, 7).unwrap();
        assert_eq!(backbone.n_params::<f32>(), params.len());
        assert!(params.len() > build(Preset::NeuralangeloCpu, 0.5, 7).1.len());
        assert!(matches!(build_with_grid(Preset::NeusCpu, cpu, 0.5, 7), Err(BackboneError::NoHashGrid("neus-cpu"))));
    }
}
