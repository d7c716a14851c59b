//! Multi-resolution hash-grid encoding (Instant-NGP; Neuralangelo's SDF encoding).
//!
//! Level l has resolution `N_l = ⌊N_min · b^l⌋` with `b = exp((ln N_max − ln N_min)/(L − 1))`.
//! A point x ∈ [−1, 1]³ maps to `p = (x + 1)/2 · N_l`; its 8 surrounding vertices are looked up
//! in the level's table — directly when `(N_l + 1)³ ≤ T` (dense coarse levels, whose table has
//! exactly `(N_l + 1)³` entries), otherwise by the spatial hash
//! `(i · 1 ⊕ j · 2654435761 ⊕ k · 805459861) mod T` in a table of T entries — and their
//! F-dimensional features trilinearly interpolated. Output: the L·F features, level-major.
//! Parameters: the levels' tables one after the other, `min(T, (N_l + 1)³) · F` each (tiny-cuda-nn's
//! layout; a table of T entries for a dense level would leave most of it untouched).
//! Levels above `active_levels` output zeros (coarse-to-fine activation, Neuralangelo).

use crate::module::{Module, ScatterGradient, ScatterTangent, TangentAdjoints, TangentModule};
use crate::real::Real;
use crate::scratch::Buf;

/// `$kernel` with the feature count `$f` and the table layout `$dense` as constants where the
/// kernels are compiled for them (1, 2, 4, 8 features: every preset's), `$other` otherwise.
macro_rules! by_kernel {
    ($f:expr, $dense:expr, |$F:ident, $D:ident| $kernel:expr, $other:expr) => {
        match ($f, $dense) {
            (1, true) => by_kernel!(@one 1, true, $F, $D, $kernel),
            (1, false) => by_kernel!(@one 1, false, $F, $D, $kernel),
            (2, true) => by_kernel!(@one 2, true, $F, $D, $kernel),
            (2, false) => by_kernel!(@one 2, false, $F, $D, $kernel),
            (4, true) => by_kernel!(@one 4, true, $F, $D, $kernel),
            (4, false) => by_kernel!(@one 4, false, $F, $D, $kernel),
            (8, true) => by_kernel!(@one 8, true, $F, $D, $kernel),
            (8, false) => by_kernel!(@one 8, false, $F, $D, $kernel),
            _ => $other,
        }
    };
    (@one $f:literal, $d:literal, $F:ident, $D:ident, $kernel:expr) => {{
        const $F: usize = $f;
        const $D: bool = $d;
        $kernel
    }};
}

/// Hash-grid shape.
#[derive(Debug, Clone, PartialEq)]
pub struct HashGridConfig {
    /// Number of levels L (Neuralangelo: 16).
    pub levels: usize,
    /// Features per level F (2).
    pub features: usize,
    /// log₂ of the table size T (Neuralangelo: 22; a CPU preset uses fewer).
    pub log2_table: u32,
    /// Coarsest resolution N_min (16).
    pub base_resolution: u32,
    /// Finest resolution N_max (2048).
    pub finest_resolution: u32,
}

impl HashGridConfig {
    /// The CPU-sized Neuralangelo-style grid: 8 levels × 2 features, 2¹⁶ entries, 16 → 256.
    pub fn neuralangelo_cpu() -> HashGridConfig {
        HashGridConfig { levels: 8, features: 2, log2_table: 16, base_resolution: 16, finest_resolution: 256 }
    }

    /// This grid's coarsest resolution, features and growth per level, with as many levels as
    /// reach `finest` (the last level is `finest`; one level when `finest` ≤ the coarsest) and
    /// tables of 2^`log2_table` entries: a grid sized for finer or coarser detail that keeps the
    /// spacing of its levels.
    pub fn reaching(&self, finest: u32, log2_table: u32) -> HashGridConfig {
        let (lo, hi) = (f64::from(self.base_resolution.max(1)), f64::from(self.finest_resolution.max(1)));
        let growth = if self.levels > 1 { ((hi.ln() - lo.ln()) / (self.levels - 1) as f64).exp() } else { 2.0 };
        let finest = finest.max(self.base_resolution.max(1));
        let steps = if growth > 1.0 { ((f64::from(finest).ln() - lo.ln()) / growth.ln()).round() as usize } else { 0 };
        HashGridConfig { levels: steps + 1, log2_table, finest_resolution: finest, ..self.clone() }
    }
}

/// The encoding. Parameters: L tables of `min(T, (N_l + 1)³)` × F features, level after level.
#[derive(Debug, Clone)]
pub struct HashGrid {
    config: HashGridConfig,
    resolutions: Vec<u32>,
    dense: Vec<bool>,
    table: usize,
    /// Where each level's table starts, in entries (levels + 1 values: the last is the total).
    offsets: Vec<usize>,
    /// Levels that output features; the rest output zeros and get no gradient.
    pub active_levels: usize,
}

impl HashGrid {
    /// Builds the level table (all levels active).
    pub fn new(config: HashGridConfig) -> HashGrid {
        assert!(config.levels >= 1 && config.features >= 1 && config.log2_table <= 30, "invalid hash grid");
        let table = 1usize << config.log2_table;
        let (lo, hi) = (config.base_resolution.max(1) as f64, config.finest_resolution.max(1) as f64);
        let growth = if config.levels > 1 { ((hi.ln() - lo.ln()) / (config.levels - 1) as f64).exp() } else { 1.0 };
        // (+1e-9: N_min · b^{L−1} must give N_max exactly despite rounding.)
        let resolutions: Vec<u32> = (0..config.levels).map(|l| (lo * growth.powi(l as i32) + 1e-9).floor().max(1.0) as u32).collect();
        let dense: Vec<bool> = resolutions.iter().map(|&n| ((n as u64 + 1).pow(3)) <= table as u64).collect();
        let mut offsets = vec![0usize];
        for (&n, &d) in resolutions.iter().zip(&dense) {
            let entries = if d { (n as usize + 1).pow(3) } else { table };
            offsets.push(offsets[offsets.len() - 1] + entries);
        }
        let levels = config.levels;
        HashGrid { config, resolutions, dense, table, offsets, active_levels: levels }
    }

    /// The parameters of level `level`'s table (entries × F).
    pub fn level_params(&self, level: usize) -> std::ops::Range<usize> {
        let f = self.config.features;
        self.offsets[level] * f..self.offsets[level + 1] * f
    }

    /// The configuration.
    pub fn config(&self) -> &HashGridConfig {
        &self.config
    }

    /// Resolution of each level.
    pub fn resolutions(&self) -> &[u32] {
        &self.resolutions
    }

    /// Uniform initialisation in ±`scale` (Instant-NGP: 1e-4), deterministic for a seed.
    pub fn init(&self, params: &mut [f32], scale: f32, seed: u64) {
        use rand::{RngExt, SeedableRng, rngs::Xoshiro256PlusPlus};
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        for p in params.iter_mut() {
            *p = (rng.random::<f32>() * 2.0 - 1.0) * scale;
        }
    }

    #[inline(always)]
    fn vertex_index(&self, level: usize, v: [u32; 3]) -> usize {
        let n = self.resolutions[level] as usize + 1;
        if self.dense[level] {
            v[0] as usize + n * (v[1] as usize + n * v[2] as usize)
        } else {
            ((v[0].wrapping_mul(1) ^ v[1].wrapping_mul(2_654_435_761) ^ v[2].wrapping_mul(805_459_861)) as usize) & (self.table - 1)
        }
    }

    /// For one point and level: the 8 vertex table indices, their trilinear weights and the
    /// weights' derivatives with respect to x (chain rule through p = (x + 1)/2 · N).
    #[inline(always)]
    fn corners<R: Real>(&self, level: usize, x: &[R]) -> ([usize; 8], [R; 8], [[R; 3]; 8]) {
        let n = self.resolutions[level];
        let scale = R::of(n as f64 * 0.5);
        let mut cell = [0u32; 3];
        let mut frac = [R::ZERO; 3];
        // Inputs outside [−1, 1] are clamped to the grid; there the gradient in x is zero.
        let mut slope = [scale; 3];
        for d in 0..3 {
            let raw = (x[d] + R::ONE) * scale;
            let p = raw.max(R::ZERO).min(R::of(n as f64));
            if p != raw {
                slope[d] = R::ZERO;
            }
            // The last cell is closed: p = N is its far face (frac = 1), never a cell N (whose
            // corners N + 1 would read another row of a dense table).
            let c = p.floor().min(R::of(f64::from(n) - 1.0));
            cell[d] = c.to_f64() as u32;
            frac[d] = p - c;
        }
        let mut idx = [0usize; 8];
        let mut w = [R::ZERO; 8];
        let mut dw = [[R::ZERO; 3]; 8];
        for c in 0..8 {
            let bit = [c & 1, (c >> 1) & 1, (c >> 2) & 1];
            idx[c] = self.vertex_index(level, [cell[0] + bit[0] as u32, cell[1] + bit[1] as u32, cell[2] + bit[2] as u32]);
            let f = [0, 1, 2].map(|d| if bit[d] == 1 { frac[d] } else { R::ONE - frac[d] });
            let s = [0, 1, 2].map(|d| if bit[d] == 1 { slope[d] } else { -slope[d] });
            w[c] = f[0] * f[1] * f[2];
            dw[c] = [s[0] * f[1] * f[2], f[0] * s[1] * f[2], f[0] * f[1] * s[2]];
        }
        (idx, w, dw)
    }
}

impl<R: Real> Module<R> for HashGrid {
    fn n_params(&self) -> usize {
        self.offsets[self.config.levels] * self.config.features
    }
    fn n_inputs(&self) -> usize {
        3
    }
    fn n_outputs(&self) -> usize {
        self.config.levels * self.config.features
    }
    fn ctx_per_row(&self) -> usize {
        0
    }
    fn forward(&self, params: &[R], input: &[R], output: &mut [R], _: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::HashForward);
        crate::kernels::dispatch(
            #[inline(always)]
            || self.forward_rows(params, input, output),
        );
    }
    fn backward(&self, params: &[R], input: &[R], _: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        let _span = crate::profile::span(crate::profile::Stage::HashScatter);
        crate::kernels::dispatch(
            #[inline(always)]
            || self.backward_rows(params, input, d_output, d_params, d_input),
        );
    }
}

/// The tables' gradient is a scatter from (points, ∂L/∂features) alone, one level per block.
impl<R: Real> ScatterGradient<R> for HashGrid {
    /// One level's table.
    fn gradient_blocks(&self) -> usize {
        self.config.levels
    }
    fn gradient_block_range(&self, block: usize) -> std::ops::Range<usize> {
        self.level_params(block)
    }
    fn backward_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, level: usize, d_table: &mut [R]) {
        if level >= self.active_levels.min(self.config.levels) {
            return;
        }
        let _span = crate::profile::span(crate::profile::Stage::HashScatter);
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (input, d_output) in parts {
                    self.scatter_level(level, input, d_output, lead, d_table);
                }
            },
        );
    }
}

/// The context of [`TangentModule::forward_keeping_tangents`]: the features' Jacobian ∂y/∂x,
/// rows × n_outputs × 3 (§46), which the forward's visit to the corners gives for 48 more
/// multiply-adds a level; the tangents and the input's adjoint are then contractions with it,
/// where they were another pass over every level's 8 corners (their hashing, their gathers).
impl<R: Real> TangentModule<R> for HashGrid {
    fn tangent_ctx_per_row(&self) -> usize {
        3 * self.config.levels * self.config.features
    }
    fn forward_keeping_tangents(&self, params: &[R], input: &[R], output: &mut [R], ctx: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::HashForward);
        crate::kernels::dispatch(
            #[inline(always)]
            || self.forward_rows_keeping(params, input, output, ctx),
        );
    }
    /// ∂(features)/∂x · ẋ: the Jacobian times each direction.
    fn forward_tangents(&self, _: &[R], _: &[R], ctx: &[R], k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::HashTangents);
        let n_out = self.config.levels * self.config.features;
        crate::kernels::dispatch(
            #[inline(always)]
            || jacobian_tangents(ctx, n_out, k, tangents_in, tangents_out),
        );
    }
    /// The tables' gradient: T̄\[c\] += w_c ȳ + (∇ₓw_c · v) ẏ̄. The adjoint of the input is not
    /// computed (a hash grid is the first module of an SDF network, whose inputs are not learnt):
    /// `d_input`, if given, is zeroed.
    fn backward_tangent(&self, pass: TangentAdjoints<'_, R>, d_params: &mut [R], d_input: Option<(&mut [R], &mut [R])>) {
        let TangentAdjoints { params: _, input, ctx: _, tangent_in, d_output, d_tangent_out } = pass;
        let _span = crate::profile::span(crate::profile::Stage::HashTangentScatter);
        debug_assert!(d_input.is_none(), "a hash grid does not propagate tangent adjoints to its input");
        if let Some((a, b)) = d_input {
            a.fill(R::ZERO);
            b.fill(R::ZERO);
        }
        for level in 0..self.active_levels.min(self.config.levels) {
            self.scatter_tangent_level(level, input, tangent_in, (d_output, d_tangent_out), 0, &mut d_params[self.level_params(level)]);
        }
    }
    /// x̄ = Σ_levels Σ_c (T\[c\] · ȳ) ∇ₓw_c: the corners found again, one pass over the levels.
    fn input_gradient_of_forward(&self, params: &[R], input: &[R], _: &[R], d_output: &[R], d_input: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::HashTangents);
        crate::kernels::dispatch(
            #[inline(always)]
            || self.input_adjoint_rows(params, input, d_output, d_input),
        );
    }
    /// x̄ = (∂y/∂x)ᵀ ȳ.
    fn input_gradient(&self, _: &[R], _: &[R], ctx: &[R], d_output: &[R], d_input: &mut [R]) {
        let _span = crate::profile::span(crate::profile::Stage::HashTangents);
        let n_out = self.config.levels * self.config.features;
        crate::kernels::dispatch(
            #[inline(always)]
            || jacobian_adjoint(ctx, n_out, d_output, d_input),
        );
    }
}

impl<R: Real> ScatterTangent<R> for HashGrid {
    fn tangent_parts_block(&self, parts: &[(&[R], &[R])], lead: usize, level: usize, d_table: &mut [R]) {
        if level >= self.active_levels.min(self.config.levels) {
            return;
        }
        let _span = crate::profile::span(crate::profile::Stage::HashTangentScatter);
        for (points, record) in parts {
            let (x, v) = points.split_at(points.len() / 2);
            self.scatter_tangent_level(level, x, v, record.split_at(record.len() / 2), lead, d_table);
        }
    }
}

impl HashGrid {
    /// (Values per row, the first of `level`'s columns) of adjoint rows that hold `lead` values
    /// before the features' ([`ScatterGradient::backward_parts_block`]).
    fn adjoint_columns(&self, lead: usize, level: usize) -> (usize, usize) {
        let f = self.config.features;
        (lead + self.config.levels * f, lead + level * f)
    }

    /// [`level_tangent_scatter`] for any feature count, a row at a time.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn level_tangent_scatter_any<R: Real>(
        &self,
        level: usize,
        input: &[R],
        v: &[R],
        (d_output, d_tangent_out): (&[R], &[R]),
        lead: usize,
        d_table: &mut [R],
    ) {
        let f = self.config.features;
        let (n_out, at) = self.adjoint_columns(lead, level);
        for (r, x) in input.chunks_exact(3).enumerate() {
            let (idx, w, dw) = self.corners(level, x);
            let t = &v[3 * r..3 * r + 3];
            for c in 0..8 {
                let s = dw[c][0] * t[0] + dw[c][1] * t[1] + dw[c][2] * t[2];
                for q in 0..f {
                    let d = &mut d_table[idx[c] * f + q];
                    *d = w[c].mul_add(d_output[r * n_out + at + q], s.mul_add(d_tangent_out[r * n_out + at + q], *d));
                }
            }
        }
    }
}

/// The 8 corners of the cell around `p` (one point) on a level of resolution `n`: table indices
/// (dense `(n + 1)³` layout or spatial hash masked by `mask`) and trilinear weights. Written for
/// vectorisation across points: no branches, no float → int conversion.
#[inline(always)]
fn corner_weights<R: Real, const DENSE: bool>(p: &[R], n: u32, mask: u32) -> ([u32; 8], [R; 8]) {
    // The gradients are dead code here and compiled away after inlining.
    let (idx, w, _) = corner_gradients::<R, DENSE>(p, n, mask);
    (idx, w)
}

/// [`corner_weights`] with the weights' gradients in x (zero along an axis where the input is
/// clamped to the grid), for the tangents of analytic normals.
#[inline(always)]
fn corner_gradients<R: Real, const DENSE: bool>(p: &[R], n: u32, mask: u32) -> ([u32; 8], [R; 8], [[R; 3]; 8]) {
    let scale = R::of(f64::from(n) * 0.5);
    let (nf, last) = (R::of(f64::from(n)), R::of(f64::from(n) - 1.0));
    let mut cell = [0u32; 3];
    let mut fr = [R::ZERO; 3];
    let mut slope = [R::ZERO; 3];
    for d in 0..3 {
        let raw = (p[d] + R::ONE) * scale;
        let q = raw.max(R::ZERO).min(nf);
        slope[d] = if q == raw { scale } else { R::ZERO };
        let c = q.floor().min(last);
        cell[d] = c.small_index();
        fr[d] = q - c;
    }
    let n1 = n + 1;
    let mut idx = [0u32; 8];
    let mut w = [R::ZERO; 8];
    let mut dw = [[R::ZERO; 3]; 8];
    for c in 0..8u32 {
        let (bx, by, bz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let (ix, iy, iz) = (cell[0] + bx, cell[1] + by, cell[2] + bz);
        idx[c as usize] = if DENSE { ix + n1 * (iy + n1 * iz) } else { (ix ^ iy.wrapping_mul(2_654_435_761) ^ iz.wrapping_mul(805_459_861)) & mask };
        let wx = if bx == 1 { fr[0] } else { R::ONE - fr[0] };
        let wy = if by == 1 { fr[1] } else { R::ONE - fr[1] };
        let wz = if bz == 1 { fr[2] } else { R::ONE - fr[2] };
        let sx = if bx == 1 { slope[0] } else { -slope[0] };
        let sy = if by == 1 { slope[1] } else { -slope[1] };
        let sz = if bz == 1 { slope[2] } else { -slope[2] };
        w[c as usize] = wx * wy * wz;
        dw[c as usize] = [sx * wy * wz, wx * sy * wz, wx * wy * sz];
    }
    (idx, w, dw)
}

/// Rows per block of [`level_features`], [`level_features_jacobian`] and [`level_input_adjoint`]:
/// one AVX-512 register of f32.
const JACOBIAN_BLOCK: usize = 16;

/// The points of a block of at most `B` rows (rows × 3), as `B` rows: the last repeated.
#[inline(always)]
fn block_points<R: Real, const B: usize>(points: &[R]) -> [[R; 3]; B] {
    let rows = points.len() / 3;
    std::array::from_fn(|i| {
        let from = 3 * i.min(rows - 1);
        [points[from], points[from + 1], points[from + 2]]
    })
}

/// One level's features (into columns `at..at + F` of `out`'s rows of `n_out`, as
/// [`level_features`], to the same bits) and
/// their Jacobian: ∂y_(at+q)/∂x_d at `(r · n_out + at + q) · 3 + d` of `jacobian` (rows × n_out ×
/// 3), from the same corners and table values. In blocks of [`JACOBIAN_BLOCK`] rows computed into
/// arrays of one component each (the last block repeats its last row), then copied to the rows:
/// the rows' interleaved, strided stores kept the row loop from vectorising (with AVX-512 the
/// level's pass takes half the time; with AVX2, whose 16 registers cannot hold a row's corners in
/// vectors, blocks of 16, of 8 and rows alone train at the same speed). [`level_features`] is
/// blocked the same way since §57.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn level_features_jacobian<R: Real, const F: usize, const DENSE: bool>(
    table: &[R],
    n: u32,
    mask: u32,
    input: &[R],
    out: &mut [R],
    jacobian: &mut [R],
    n_out: usize,
    at: usize,
) {
    const B: usize = JACOBIAN_BLOCK;
    let entries = table.as_chunks::<F>().0;
    for ((points, o), jac) in input.chunks(3 * B).zip(out.chunks_mut(n_out * B)).zip(jacobian.chunks_mut(3 * n_out * B)) {
        let p = block_points::<R, B>(points);
        let mut acc = [[R::ZERO; B]; F];
        let mut grad = [[[R::ZERO; B]; 3]; F];
        for i in 0..B {
            let (idx, w, dw) = corner_gradients::<R, DENSE>(&p[i], n, mask);
            for c in 0..8 {
                let entry = entries.get(idx[c] as usize).copied().unwrap_or([R::ZERO; F]);
                for q in 0..F {
                    let t = entry[q];
                    acc[q][i] = w[c].mul_add(t, acc[q][i]);
                    for d in 0..3 {
                        grad[q][d][i] = dw[c][d].mul_add(t, grad[q][d][i]);
                    }
                }
            }
        }
        for (i, (o, jac)) in o.chunks_exact_mut(n_out).zip(jac.chunks_exact_mut(3 * n_out)).enumerate() {
            for q in 0..F {
                o[at + q] = acc[q][i];
                for d in 0..3 {
                    jac[3 * (at + q) + d] = grad[q][d][i];
                }
            }
        }
    }
}

/// `k` tangents a row from the Jacobian rows (rows × n_out × 3): ẏ = (∂y/∂x) ẋ, `tangents_in`
/// rows × k × 3, `tangents_out` rows × k × n_out (written).
#[inline(always)]
fn jacobian_tangents<R: Real>(jacobian: &[R], n_out: usize, k: usize, tangents_in: &[R], tangents_out: &mut [R]) {
    for ((jac, t), y) in jacobian.chunks_exact(3 * n_out).zip(tangents_in.chunks_exact(3 * k)).zip(tangents_out.chunks_exact_mut(k * n_out)) {
        for (t, y) in t.chunks_exact(3).zip(y.chunks_exact_mut(n_out)) {
            for (y, g) in y.iter_mut().zip(jac.chunks_exact(3)) {
                *y = g[2].mul_add(t[2], g[1].mul_add(t[1], g[0] * t[0]));
            }
        }
    }
}

/// The input's adjoint from the Jacobian rows: x̄ = (∂y/∂x)ᵀ ȳ, `d_output` rows × n_out,
/// `d_input` rows × 3 (written).
#[inline(always)]
fn jacobian_adjoint<R: Real>(jacobian: &[R], n_out: usize, d_output: &[R], d_input: &mut [R]) {
    for ((jac, dy), d_in) in jacobian.chunks_exact(3 * n_out).zip(d_output.chunks_exact(n_out)).zip(d_input.chunks_exact_mut(3)) {
        let mut g = [R::ZERO; 3];
        for (&y, j) in dy.iter().zip(jac.chunks_exact(3)) {
            for d in 0..3 {
                g[d] = y.mul_add(j[d], g[d]);
            }
        }
        d_in.copy_from_slice(&g);
    }
}

/// One level's table gradient through the features and their tangents along `v` (rows × 3):
/// T̄[c] += w_c ȳ + (∇ₓw_c · v) ẏ̄ (sequential scatter: rows share entries).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn level_tangent_scatter<R: Real, const F: usize, const DENSE: bool>(
    n: u32,
    mask: u32,
    input: &[R],
    v: &[R],
    d_output: &[R],
    d_tangent_out: &[R],
    n_out: usize,
    at: usize,
    d_table: &mut [R],
) {
    for (r, p) in input.chunks_exact(3).enumerate() {
        let (idx, w, dw) = corner_gradients::<R, DENSE>(p, n, mask);
        let t = &v[3 * r..3 * r + 3];
        let dy = &d_output[r * n_out + at..r * n_out + at + F];
        let dt = &d_tangent_out[r * n_out + at..r * n_out + at + F];
        for c in 0..8 {
            let s = dw[c][0] * t[0] + dw[c][1] * t[1] + dw[c][2] * t[2];
            let base = idx[c] as usize * F;
            for q in 0..F {
                if let Some(d) = d_table.get_mut(base + q) {
                    *d = w[c].mul_add(dy[q], s.mul_add(dt[q], *d));
                }
            }
        }
    }
}

/// One level's share of the input's adjoint for every row: `d_input` (rows × 3) += Σ_c (T\[c\] ·
/// ȳ) ∇ₓw_c, ȳ the level's columns `at..at + F` of `d_output` (rows × `n_out`). In blocks of
/// [`JACOBIAN_BLOCK`] rows, as [`level_features_jacobian`] and for the same reason (a render's
/// normal).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn level_input_adjoint<R: Real, const F: usize, const DENSE: bool>(
    table: &[R],
    n: u32,
    mask: u32,
    input: &[R],
    d_output: &[R],
    n_out: usize,
    at: usize,
    d_input: &mut [R],
) {
    const B: usize = JACOBIAN_BLOCK;
    let entries = table.as_chunks::<F>().0;
    for ((points, dy), d_in) in input.chunks(3 * B).zip(d_output.chunks(n_out * B)).zip(d_input.chunks_mut(3 * B)) {
        let p = block_points::<R, B>(points);
        let rows = points.len() / 3;
        let dy: [[R; F]; B] = std::array::from_fn(|i| {
            let from = n_out * i.min(rows - 1) + at;
            std::array::from_fn(|q| dy[from + q])
        });
        let mut g = [[R::ZERO; B]; 3];
        for i in 0..B {
            let (idx, _, dw) = corner_gradients::<R, DENSE>(&p[i], n, mask);
            for c in 0..8 {
                let entry = entries.get(idx[c] as usize).copied().unwrap_or([R::ZERO; F]);
                let mut s = R::ZERO;
                for q in 0..F {
                    s = entry[q].mul_add(dy[i][q], s);
                }
                for d in 0..3 {
                    g[d][i] = s.mul_add(dw[c][d], g[d][i]);
                }
            }
        }
        for (i, d_in) in d_in.chunks_exact_mut(3).enumerate() {
            for d in 0..3 {
                d_in[d] += g[d][i];
            }
        }
    }
}

/// One level's features for every row into columns `at..at + F` of `out` (rows of `n_out`),
/// in blocks of [`JACOBIAN_BLOCK`] rows accumulated into arrays of one feature each, then
/// written to the rows, as [`level_features_jacobian`] does: row by row, the loop did not
/// vectorise with AVX-512 (each corner hashed and read in scalar code), and each row's features
/// were copied from a level buffer by a call (DECISIONS §57). Table reads go through `get` (out
/// of range reads 0, which the indices never are): a bounds check that panics is an early exit,
/// and loops with early exits do not vectorise. A corner's F features are read as one entry
/// (`[R; F]`, one check): read feature by feature, each with its own check, the level's pass ran
/// 1.2–1.45× slower on a Zen 3 (AVX2; DECISIONS §55).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn level_features<R: Real, const F: usize, const DENSE: bool>(table: &[R], n: u32, mask: u32, input: &[R], out: &mut [R], n_out: usize, at: usize) {
    const B: usize = JACOBIAN_BLOCK;
    let entries = table.as_chunks::<F>().0;
    for (points, o) in input.chunks(3 * B).zip(out.chunks_mut(n_out * B)) {
        let p = block_points::<R, B>(points);
        let mut acc = [[R::ZERO; B]; F];
        for i in 0..B {
            let (idx, w) = corner_weights::<R, DENSE>(&p[i], n, mask);
            for c in 0..8 {
                let entry = entries.get(idx[c] as usize).copied().unwrap_or([R::ZERO; F]);
                for q in 0..F {
                    acc[q][i] = w[c].mul_add(entry[q], acc[q][i]);
                }
            }
        }
        for (i, o) in o.chunks_exact_mut(n_out).enumerate() {
            for q in 0..F {
                o[at + q] = acc[q][i];
            }
        }
    }
}

/// One level's corner indices and weights for every row (rows × 8 each).
#[inline(always)]
fn level_corners<R: Real, const DENSE: bool>(n: u32, mask: u32, input: &[R], idx: &mut [u32], w: &mut [R]) {
    for ((p, i), wr) in input.chunks_exact(3).zip(idx.chunks_exact_mut(8)).zip(w.chunks_exact_mut(8)) {
        let (ci, cw) = corner_weights::<R, DENSE>(p, n, mask);
        i.copy_from_slice(&ci);
        wr.copy_from_slice(&cw);
    }
}

impl HashGrid {
    /// Level-major, one level's table (512 KB for the CPU preset) at a time, so that its
    /// gathers and scatters stay in the cache; the rows of a level are vectorised (gathers).
    #[inline(always)]
    fn forward_rows<R: Real>(&self, params: &[R], input: &[R], output: &mut [R]) {
        let f = self.config.features;
        let mask = (self.table - 1) as u32;
        let n_out = self.config.levels * f;
        output.fill(R::ZERO);
        for level in 0..self.active_levels.min(self.config.levels) {
            let table = &params[self.level_params(level)];
            let (n, dense) = (self.resolutions[level], self.dense[level]);
            by_kernel!(f, dense, |F, DENSE| level_features::<R, F, DENSE>(table, n, mask, input, output, n_out, level * f), {
                for (x, row) in input.chunks_exact(3).zip(output.chunks_exact_mut(n_out)) {
                    let (idx, w, _) = self.corners(level, x);
                    let y = &mut row[level * f..level * f + f];
                    for c in 0..8 {
                        for k in 0..f {
                            y[k] = w[c].mul_add(table[idx[c] * f + k], y[k]);
                        }
                    }
                }
            });
        }
    }

    /// [`Self::forward_rows`] with the features' Jacobian into `jacobian` (rows × n_out × 3,
    /// [`TangentModule::forward_keeping_tangents`]). A function of its own, its fallback for other
    /// feature counts written out in it as the plain forward's is: with the two loops in one
    /// function, or the fallback a method, the plain forward's gathers ran 2.3× slower (renders).
    #[inline(always)]
    fn forward_rows_keeping<R: Real>(&self, params: &[R], input: &[R], output: &mut [R], jacobian: &mut [R]) {
        let f = self.config.features;
        let n_out = self.config.levels * f;
        let mask = (self.table - 1) as u32;
        output.fill(R::ZERO);
        if self.active_levels < self.config.levels {
            jacobian.fill(R::ZERO);
        }
        for level in 0..self.active_levels.min(self.config.levels) {
            let table = &params[self.level_params(level)];
            let (n, dense) = (self.resolutions[level], self.dense[level]);
            by_kernel!(
                f,
                dense,
                |F, DENSE| level_features_jacobian::<R, F, DENSE>(table, n, mask, input, output, jacobian, n_out, level * f),
                for (r, (x, row)) in input.chunks_exact(3).zip(output.chunks_exact_mut(n_out)).enumerate() {
                    let (idx, w, dw) = self.corners(level, x);
                    let grad = &mut jacobian[3 * (r * n_out + level * f)..3 * (r * n_out + level * f + f)];
                    let y = &mut row[level * f..level * f + f];
                    grad.fill(R::ZERO);
                    for c in 0..8 {
                        for k in 0..f {
                            let t = table[idx[c] * f + k];
                            y[k] = w[c].mul_add(t, y[k]);
                            for d in 0..3 {
                                grad[3 * k + d] = dw[c][d].mul_add(t, grad[3 * k + d]);
                            }
                        }
                    }
                }
            );
        }
    }

    /// Adds one level's table gradient for `rows` points: corners of every row (vectorised),
    /// then the scatter (sequential: rows share entries).
    #[inline(always)]
    fn scatter_level<R: Real>(&self, level: usize, input: &[R], d_output: &[R], lead: usize, d_table: &mut [R]) {
        self.scatter_level_corners(level, input, d_output, lead, d_table);
    }

    /// [`Self::scatter_level`], giving back each row's 8 corners (their entries in the level's
    /// table).
    #[inline(always)]
    fn scatter_level_corners<R: Real>(&self, level: usize, input: &[R], d_output: &[R], lead: usize, d_table: &mut [R]) -> Buf<u32> {
        let f = self.config.features;
        let (n_out, at) = self.adjoint_columns(lead, level);
        let rows = input.len() / 3;
        let mut idx = Buf::<u32>::to_overwrite(rows * 8);
        let mut w = Buf::<R>::to_overwrite(rows * 8);
        let mask = (self.table - 1) as u32;
        let (n, dense) = (self.resolutions[level], self.dense[level]);
        if dense {
            level_corners::<R, true>(n, mask, input, &mut idx, &mut w);
        } else {
            level_corners::<R, false>(n, mask, input, &mut idx, &mut w);
        }
        for ((ri, rw), dy) in idx.chunks_exact(8).zip(w.chunks_exact(8)).zip(d_output.chunks_exact(n_out)) {
            let dy = &dy[at..at + f];
            for c in 0..8 {
                let entry = ri[c] as usize * f;
                for k in 0..f {
                    d_table[entry + k] = rw[c].mul_add(dy[k], d_table[entry + k]);
                }
            }
        }
        idx
    }

    /// Adds one work item's gradient of level `level`'s table (rows `input`, feature adjoints
    /// `d_output`) to `d_table`, bit for bit as [`Module::backward`] into a zeroed buffer of the
    /// whole table and then added entry by entry would, at the cost of the entries the rows touch:
    /// the item's sums are made in `scratch` (the level's size, zero on entry and again on return),
    /// then each touched entry is added once (a second visit adds 0, which changes no sum).
    /// Summing several items this way, in order, gives the bits of one dense buffer per item
    /// summed in that order (the learned background's tables, `Pipeline::loss_parallel_split`).
    /// Each row of `d_output` holds `lead` values before the features' adjoints
    /// ([`ScatterGradient::backward_parts_block`]).
    pub fn add_level_gradient<R: Real>(&self, level: usize, input: &[R], d_output: &[R], lead: usize, scratch: &mut [R], d_table: &mut [R]) {
        if level >= self.active_levels.min(self.config.levels) {
            return;
        }
        let _span = crate::profile::span(crate::profile::Stage::HashScatter);
        let f = self.config.features;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                let idx = self.scatter_level_corners(level, input, d_output, lead, scratch);
                for &i in idx.iter() {
                    let at = i as usize * f;
                    for k in 0..f {
                        d_table[at + k] += scratch[at + k];
                        scratch[at + k] = R::ZERO;
                    }
                }
            },
        );
    }

    /// One level's table gradient through the features and their tangents along `v` (rows × 3):
    /// T̄[c] += w_c ȳ + (∇ₓw_c · v) ẏ̄.
    fn scatter_tangent_level<R: Real>(&self, level: usize, input: &[R], v: &[R], adjoints: (&[R], &[R]), lead: usize, d_table: &mut [R]) {
        let f = self.config.features;
        let (n_out, at) = self.adjoint_columns(lead, level);
        let (d_output, d_tangent_out) = adjoints;
        let mask = (self.table - 1) as u32;
        let (n, dense) = (self.resolutions[level], self.dense[level]);
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                by_kernel!(
                    f,
                    dense,
                    |F, DENSE| level_tangent_scatter::<R, F, DENSE>(n, mask, input, v, d_output, d_tangent_out, n_out, at, d_table),
                    self.level_tangent_scatter_any(level, input, v, adjoints, lead, d_table)
                );
            },
        );
    }

    #[inline(always)]
    fn backward_rows<R: Real>(&self, params: &[R], input: &[R], d_output: &[R], d_params: &mut [R], d_input: Option<&mut [R]>) {
        for level in 0..self.active_levels.min(self.config.levels) {
            self.scatter_level(level, input, d_output, 0, &mut d_params[self.level_params(level)]);
        }
        if let Some(d_in) = d_input {
            self.input_adjoint_rows(params, input, d_output, d_in);
        }
    }

    /// The input's adjoint (rows × 3, written) for the features' adjoints `d_output`, level by
    /// level ([`level_input_adjoint`]).
    #[inline(always)]
    fn input_adjoint_rows<R: Real>(&self, params: &[R], input: &[R], d_output: &[R], d_input: &mut [R]) {
        let f = self.config.features;
        let n_out = self.config.levels * f;
        d_input.fill(R::ZERO);
        let mask = (self.table - 1) as u32;
        for level in 0..self.active_levels.min(self.config.levels) {
            let table = &params[self.level_params(level)];
            let (n, dense) = (self.resolutions[level], self.dense[level]);
            by_kernel!(f, dense, |F, DENSE| level_input_adjoint::<R, F, DENSE>(table, n, mask, input, d_output, n_out, level * f, d_input), {
                for (row, (x, dy)) in input.chunks_exact(3).zip(d_output.chunks_exact(n_out)).enumerate() {
                    let dy = &dy[level * f..level * f + f];
                    let (idx, _, dw) = self.corners(level, x);
                    for c in 0..8 {
                        let g = (0..f).fold(R::ZERO, |g, k| table[idx[c] * f + k].mul_add(dy[k], g));
                        for d in 0..3 {
                            d_input[3 * row + d] = g.mul_add(dw[c][d], d_input[3 * row + d]);
                        }
                    }
                }
            });
        }
    }
}
