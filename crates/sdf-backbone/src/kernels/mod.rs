//! Dense-layer kernels at the CPU's vector width: plain Rust loops (no `unsafe`) over
//! fixed-size tiles, compiled once per instruction set and chosen at run time by `pulp`
//! (AVX-512 where the CPU has it, else AVX2 + FMA, else SSE2). The loops are written so that
//! LLVM vectorises them: register tiles of `M` rows × `W` columns (`W` a multiple of 16 floats),
//! column counts padded to a multiple of [`LANE`] (zeros in the padding), fused multiply-adds.
//! The tile's accumulators must fit the register file, so its shape follows the CPU
//! ([`wide_tiles`]): 4 × 64 with AVX-512 (16 of its 32 zmm registers), 6 × 16 otherwise (12 of
//! AVX2's 16 ymm registers, with the two vectors of B and the broadcast: 15; the 4 × 64 tile
//! spills there: the layer-shaped product ran at 0.4× — BENCHMARKS.md, "On an AVX2 CPU").
//! How fast a tile runs rests on LLVM's register allocation where the kernel is instantiated,
//! which differs from crate to crate and build to build: judge a shape by the training step and
//! the disassembly of its loop, not by one product's rate alone (DECISIONS §50).
//!
//! One micro-kernel serves every product of a layer: `C[m][0..n] (+)= Σₖ L(m, k) · B[k][0..n]`
//! with L read through strides, so that the forward pass (L = A, B = Wᵀ), the input gradient
//! (L = dZ, B = W) and the weight gradient (L = dZᵀ, B = A) are the same loop. The forward pass
//! adds the bias and applies the activation (keeping its derivative) on the tile while it is in
//! registers: one pass over the output.
//!
//! Everything is generic over [`Real`], so the f64 gradient checks run the very same code. The
//! one exception is opt-in: products in bf16 ([`bf16`], `vdpbf16ps` intrinsics — the crate's only
//! `unsafe` code) for f32 where the CPU has AVX512_BF16, through the same tile loops ([`Product`]).

// The crate's only `unsafe`: intrinsics with runtime detection, a SAFETY argument per block.
#[allow(unsafe_code)]
pub mod bf16;

use crate::module::Activation;
use crate::real::Real;
use crate::scratch::Buf;
use pulp::{Arch, Simd, WithSimd};
use std::sync::atomic::{AtomicU8, Ordering};

/// Column counts are padded to a multiple of this (16 f32 = one AVX-512 register).
pub const LANE: usize = 16;

/// The wide tile, [`WIDE_ROWS`] × [`WIDE_WIDTH`] (AVX-512: 16 accumulators of its 32 registers).
pub(crate) const WIDE_ROWS: usize = 4;
/// See [`WIDE_ROWS`].
const WIDE_WIDTH: usize = 4 * LANE;
/// The narrow tile, [`NARROW_ROWS`] × [`NARROW_WIDTH`]: BLIS's Haswell shape (AVX2: 12
/// accumulators, two vectors of B and one broadcast of L live in a step, 15 of its 16 registers).
/// 3 × 32 (§49) holds the same 12 accumulators but four vectors of B and a broadcast: 17, and
/// LLVM kept two accumulators on the stack, stored and reloaded every step, in the training
/// step's and the render's loops; 6 × 16 gave a Zen 3 1.04–1.20× the default run's iterations
/// (DECISIONS §50). Each output's sum runs over k in the same order in every shape, so the shape
/// changes no bit.
pub(crate) const NARROW_ROWS: usize = 6;
/// See [`NARROW_ROWS`].
const NARROW_WIDTH: usize = LANE;

/// `n` rounded up to a multiple of [`LANE`].
#[inline]
pub fn pad(n: usize) -> usize {
    n.div_ceil(LANE) * LANE
}

/// The instruction sets the kernels are compiled for, narrowest first: x86-64's baseline (SSE2),
/// x86-64-v3 (AVX2 + FMA) and x86-64-v4 (AVX-512). Other targets run their baseline (NEON on
/// aarch64) whatever the limit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum InstructionSet {
    /// The target's baseline.
    Baseline = 0,
    /// AVX2 with FMA (x86-64-v3).
    Avx2 = 1,
    /// AVX-512 F/BW/CD/DQ/VL (x86-64-v4), and AVX512_BF16 where the CPU has it.
    Avx512 = 2,
}

/// The widest instruction set [`dispatch`] may run ([`limit_instruction_set`]); the widest there
/// is until limited.
static LIMIT: AtomicU8 = AtomicU8::new(InstructionSet::Avx512 as u8);

/// Runs the kernels on at most `widest` from now on, process-wide (the CPU's own detection still
/// bounds it): so that a narrower CPU's path (AVX2's tile shape and instructions, no bf16) can
/// be measured and tested on a wider one (`cargo xtask --isa avx2 …`). Set it before any work:
/// a pass already running keeps the instruction set it started with.
pub fn limit_instruction_set(widest: InstructionSet) {
    LIMIT.store(widest as u8, Ordering::Relaxed);
}

/// The limit set by [`limit_instruction_set`], if one narrower than AVX-512 was set.
pub fn instruction_set_limit() -> Option<InstructionSet> {
    match LIMIT.load(Ordering::Relaxed) {
        0 => Some(InstructionSet::Baseline),
        1 => Some(InstructionSet::Avx2),
        _ => None,
    }
}

/// The instruction set the kernels run on this CPU: `pulp`'s detection within the limit.
#[inline(always)]
fn arch() -> Arch {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    {
        match (Arch::new(), instruction_set_limit()) {
            (arch, None) => arch,
            (Arch::V4(_) | Arch::V3(_), Some(InstructionSet::Avx2)) => pulp::x86::V3::try_new().map_or(Arch::Scalar, Arch::V3),
            (Arch::V4(_) | Arch::V3(_), Some(_)) => Arch::Scalar,
            (arch, Some(_)) => arch,
        }
    }
    #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
    {
        Arch::new()
    }
}

/// Whether [`dispatch`] runs the AVX-512 build (32 vector registers of 16 floats), so that the
/// wide tile (4 × 64) fits in registers; else the narrow one (6 × 16). Asked of the same
/// detection as [`dispatch`], so the tile shape and the instruction set chosen cannot disagree.
#[inline(always)]
pub fn wide_tiles() -> bool {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    {
        matches!(arch(), Arch::V4(_))
    }
    #[cfg(not(any(target_arch = "x86", target_arch = "x86_64")))]
    {
        false
    }
}

/// The instruction set [`dispatch`] runs on this CPU, as `pulp` detects it within
/// [`limit_instruction_set`]'s limit: `"AVX-512 (x86-64-v4)"`, `"AVX2 + FMA (x86-64-v3)"`, or the
/// target's baseline.
pub fn instruction_set() -> &'static str {
    #[cfg(any(target_arch = "x86", target_arch = "x86_64"))]
    {
        match arch() {
            Arch::V4(_) => "AVX-512 (x86-64-v4)",
            Arch::V3(_) => "AVX2 + FMA (x86-64-v3)",
            _ => "SSE2 (x86-64 baseline)",
        }
    }
    #[cfg(target_arch = "aarch64")]
    {
        "NEON (aarch64 baseline)"
    }
    #[cfg(not(any(target_arch = "x86", target_arch = "x86_64", target_arch = "aarch64")))]
    {
        "the target's baseline"
    }
}

/// Runs `f` compiled for the widest instruction set the CPU has (within
/// [`limit_instruction_set`]'s limit). Pass the closure as `dispatch(#[inline(always)] || …)`: a
/// closure that is not inlined into the dispatched function is compiled for the baseline
/// instruction set only (measured on a 4 × 64 tile kernel: 0.9 GFLOP/s instead of 108).
#[inline(always)]
pub fn dispatch<F: FnOnce()>(f: F) {
    struct Run<F>(F);
    impl<F: FnOnce()> WithSimd for Run<F> {
        type Output = ();
        #[inline(always)]
        fn with_simd<S: Simd>(self, _: S) {
            (self.0)()
        }
    }
    arch().dispatch(Run(f));
}

/// A strided read-only operand: element (m, k) at `data[m·sm + k·sk]`.
#[derive(Clone, Copy)]
pub struct Strided<'a, R> {
    /// The values.
    pub data: &'a [R],
    /// Stride between m indices.
    pub sm: usize,
    /// Stride between k indices.
    pub sk: usize,
}

/// One `M × W` tile of `C = Σₖ L(m, k) B[k][n0..n0 + W]` starting at row `m0` (`mr ≤ M` rows
/// valid), added to `acc`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn tile<R: Real, const M: usize, const W: usize>(
    acc: &mut [[R; W]; M],
    l: Strided<'_, R>,
    b: &[R],
    bs: usize,
    m0: usize,
    mr: usize,
    n0: usize,
    k: usize,
) {
    // The accumulators in a local copy, and every operand of a step read (and bounds-checked)
    // before its multiply-adds: so that no panic can come between two of them, and the
    // accumulators stay in registers (else LLVM stores all of them to the stack every step).
    let mut c = *acc;
    let b_row = |kk: usize| -> [R; W] { *<&[R; W]>::try_from(&b[kk * bs + n0..kk * bs + n0 + W]).expect("tile width") };
    if l.sk == 1 {
        // L row-major (forward passes, input adjoints): each row's k terms a slice of its own,
        // so that a step's bounds checks compare registers. With each row's offset recomputed
        // and checked against the whole operand every step, six rows' operands spilled from
        // AVX2's 16 general registers: a 256³ product ran at 33 GFLOP/s on one core of a Xeon
        // limited to AVX2, 61 this way (AVX-512: 96 → 105; products of K = 64 unchanged).
        let l_rows: [&[R]; M] = std::array::from_fn(|i| {
            let at = (m0 + i.min(mr - 1)) * l.sm;
            &l.data[at..at + k]
        });
        // k itself (each row holds k terms), as the shortest row's length: then every read below
        // is provably in bounds and the loop carries no check.
        let k = l_rows.iter().fold(k, |k, row| k.min(row.len()));
        for kk in 0..k {
            let brow = b_row(kk);
            tile_step(&mut c, &std::array::from_fn(|i| l_rows[i][kk]), &brow);
        }
    } else if l.sm == 1 && mr == M {
        // L column-major (weight gradients, L = dZᵀ): a step's M terms lie side by side.
        for kk in 0..k {
            let brow = b_row(kk);
            let at = m0 + kk * l.sk;
            tile_step(&mut c, <&[R; M]>::try_from(&l.data[at..at + M]).expect("tile rows"), &brow);
        }
    } else {
        let rows: [usize; M] = std::array::from_fn(|i| (m0 + i.min(mr - 1)) * l.sm);
        for kk in 0..k {
            let brow = b_row(kk);
            tile_step(&mut c, &std::array::from_fn(|i| l.data[rows[i] + kk * l.sk]), &brow);
        }
    }
    *acc = c;
}

/// One step of a tile: `c[i][j] += x[i] · b[j]`.
#[inline(always)]
fn tile_step<R: Real, const M: usize, const W: usize>(c: &mut [[R; W]; M], x: &[R; M], b: &[R; W]) {
    for i in 0..M {
        for j in 0..W {
            c[i][j] = x[i].mul_add(b[j], c[i][j]);
        }
    }
}

/// What a tile adds to its accumulators: `acc[i][0..W] += Σₖ L(m0 + i, k) · B[k][n0..n0 + W]`
/// for i < `mr` (rows past `mr` repeat the last valid one): exactly ([`Exact`]) or in bf16
/// ([`bf16::Pairs`]).
pub trait Product<R> {
    /// Adds the tile's product to `acc`.
    fn tile<const M: usize, const W: usize>(&self, acc: &mut [[R; W]; M], m0: usize, mr: usize, n0: usize);
}

/// The product in the operands' own precision: L through strides, B row-major (stride `bs`),
/// summed over k < `k`.
#[derive(Clone, Copy)]
pub struct Exact<'a, R> {
    /// The left operand.
    pub l: Strided<'a, R>,
    /// The right operand.
    pub b: &'a [R],
    /// Row stride of `b`.
    pub bs: usize,
    /// Terms of the sum.
    pub k: usize,
}

impl<R: Real> Product<R> for Exact<'_, R> {
    #[inline(always)]
    fn tile<const M: usize, const W: usize>(&self, acc: &mut [[R; W]; M], m0: usize, mr: usize, n0: usize) {
        tile::<R, M, W>(acc, self.l, self.b, self.bs, m0, mr, n0, self.k)
    }
}

impl<R: Real> Product<R> for bf16::Pairs<'_> {
    #[inline(always)]
    fn tile<const M: usize, const W: usize>(&self, acc: &mut [[R; W]; M], m0: usize, mr: usize, n0: usize) {
        let acc = R::f32s_mut(acc.as_flattened_mut()).expect("bf16 products accumulate in f32");
        let acc: &mut [[f32; W]; M] = acc.as_chunks_mut::<W>().0.try_into().expect("tile shape");
        bf16::tile::<M, W>(acc, *self, m0, mr, n0)
    }
}

/// Runs `$run!(W)` for the tile width `$w` (a multiple of [`LANE`], at most `$wmax`): one arm
/// per width, those wider than `$wmax` never taken (and folded away).
macro_rules! width_arms {
    ($w:expr, $wmax:expr, $run:ident) => {
        match $w {
            64 if $wmax >= 64 => $run!(64),
            48 if $wmax >= 48 => $run!(48),
            32 if $wmax >= 32 => $run!(32),
            _ => $run!(16),
        }
    };
}

/// `C[m][0..n] = (accumulate ? C : 0) + Σ_{k<kk} L(m, k) · B[k][0..n]` for m < `m`; `n` a
/// multiple of [`LANE`]; `B` and `C` row-major with strides `bs`, `cs`. Call inside
/// [`dispatch`].
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn gemm<R: Real>(c: &mut [R], cs: usize, l: Strided<'_, R>, b: &[R], bs: usize, m: usize, n: usize, k: usize, accumulate: bool) {
    gemm_with(c, cs, &Exact { l, b, bs, k }, m, n, accumulate)
}

/// [`gemm`] with the products in bf16 ([`bf16`]) when `in_bf16`, `R` is f32 and L is row-major
/// (B packed in pairs first, one pass over it), else exact: so the weight gradients (L = dZᵀ)
/// stay exact.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
pub fn gemm_in<R: Real>(
    in_bf16: bool,
    c: &mut [R],
    cs: usize,
    l: Strided<'_, R>,
    b: &[R],
    bs: usize,
    m: usize,
    n: usize,
    k: usize,
    accumulate: bool,
) {
    if in_bf16
        && l.sk == 1
        && k > 0
        && let (Some(left), Some(b32)) = (R::f32s(l.data), R::f32s(b))
    {
        let mut right = Buf::<u32>::zeroed(k.div_ceil(2) * n);
        bf16::pack_right(b32, bs, k, n, &mut right);
        gemm_with(c, cs, &bf16::Pairs { left, stride: l.sm, k, right: &right, n }, m, n, accumulate);
    } else {
        gemm(c, cs, l, b, bs, m, n, k, accumulate)
    }
}

/// [`gemm`] of any [`Product`], with the CPU's tile shape ([`wide_tiles`]).
#[inline(always)]
fn gemm_with<R: Real, P: Product<R>>(c: &mut [R], cs: usize, product: &P, m: usize, n: usize, accumulate: bool) {
    debug_assert!(n.is_multiple_of(LANE));
    if wide_tiles() {
        gemm_tiles::<R, P, WIDE_ROWS, WIDE_WIDTH>(c, cs, product, m, n, accumulate)
    } else {
        gemm_tiles::<R, P, NARROW_ROWS, NARROW_WIDTH>(c, cs, product, m, n, accumulate)
    }
}

/// [`gemm_with`] with tiles of `M` rows and at most `WMAX` columns.
#[inline(always)]
fn gemm_tiles<R: Real, P: Product<R>, const M: usize, const WMAX: usize>(c: &mut [R], cs: usize, product: &P, m: usize, n: usize, accumulate: bool) {
    let mut m0 = 0;
    while m0 < m {
        let mr = M.min(m - m0);
        let mut n0 = 0;
        while n0 < n {
            let w = (n - n0).min(WMAX);
            macro_rules! run {
                ($w:expr) => {{
                    let mut acc = [[R::ZERO; $w]; M];
                    if accumulate {
                        for i in 0..mr {
                            acc[i].copy_from_slice(&c[(m0 + i) * cs + n0..(m0 + i) * cs + n0 + $w]);
                        }
                    }
                    product.tile::<M, $w>(&mut acc, m0, mr, n0);
                    for i in 0..mr {
                        c[(m0 + i) * cs + n0..(m0 + i) * cs + n0 + $w].copy_from_slice(&acc[i]);
                    }
                }};
            }
            width_arms!(w, WMAX, run);
            n0 += w;
        }
        m0 += mr;
    }
}

/// The forward pass of a dense layer on `rows` rows, fused: `Z = A Wᵀ + b`, then `Y = act(Z)·scale`
/// into `y` (row stride `ys`, columns `y0..y0 + n_out_pad`) and, when given, `act'(Z)` into `d`
/// (row stride `n_out_pad`; a pass with no backward after it keeps none), for `rows` rows of
/// the [`Dense`] layer's input. `y` is the same to the bit with or without `d`. Call inside
/// [`dispatch`].
#[inline(always)]
pub fn dense_forward<R: Real>(layer: &Dense<'_, R>, y: &mut [R], ys: usize, y0: usize, d: Option<&mut [R]>, rows: usize) {
    match (wide_tiles(), d) {
        (true, Some(d)) => dense_tiles::<R, WIDE_ROWS, WIDE_WIDTH, true>(layer, y, ys, y0, d, rows),
        (true, None) => dense_tiles::<R, WIDE_ROWS, WIDE_WIDTH, false>(layer, y, ys, y0, &mut [], rows),
        (false, Some(d)) => dense_tiles::<R, NARROW_ROWS, NARROW_WIDTH, true>(layer, y, ys, y0, d, rows),
        (false, None) => dense_tiles::<R, NARROW_ROWS, NARROW_WIDTH, false>(layer, y, ys, y0, &mut [], rows),
    }
}

/// A dense layer's operands for [`dense_forward`]: its input `a` (row stride `a_s`, the first
/// `n_in` columns used), the packed Wᵀ `wt` (`n_in` × `n_out_pad`), the bias, the activation and
/// the output scale.
pub struct Dense<'a, R> {
    /// The input rows.
    pub a: &'a [R],
    /// Row stride of `a`.
    pub a_s: usize,
    /// Inputs used per row.
    pub n_in: usize,
    /// Wᵀ, packed, zero-padded to `n_out_pad` columns.
    pub wt: &'a [R],
    /// `n_out_pad` values.
    pub bias: &'a [R],
    /// Output columns, padded to [`LANE`].
    pub n_out_pad: usize,
    /// The activation.
    pub act: Activation,
    /// Factor on the activated output.
    pub scale: R,
    /// The product in bf16: `a` and `wt` packed in pairs ([`bf16::pack_right`]); `None`: exact.
    pub pairs: Option<bf16::Pairs<'a>>,
}

/// [`dense_forward`] with tiles of `M` rows and at most `WMAX` columns, `act'(Z)` into `d` when
/// `KEEP` (else `d` is not touched).
#[inline(always)]
fn dense_tiles<R: Real, const M: usize, const WMAX: usize, const KEEP: bool>(
    layer: &Dense<'_, R>,
    y: &mut [R],
    ys: usize,
    y0: usize,
    d: &mut [R],
    rows: usize,
) {
    let exact = Exact { l: Strided { data: layer.a, sm: layer.a_s, sk: 1 }, b: layer.wt, bs: layer.n_out_pad, k: layer.n_in };
    match &layer.pairs {
        Some(pairs) => dense_product::<R, _, M, WMAX, KEEP>(layer, pairs, y, ys, y0, d, rows),
        None => dense_product::<R, _, M, WMAX, KEEP>(layer, &exact, y, ys, y0, d, rows),
    }
}

/// [`dense_tiles`] with the product `product` (of the layer's operands).
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn dense_product<R: Real, P: Product<R>, const M: usize, const WMAX: usize, const KEEP: bool>(
    layer: &Dense<'_, R>,
    product: &P,
    y: &mut [R],
    ys: usize,
    y0: usize,
    d: &mut [R],
    rows: usize,
) {
    let &Dense { bias, n_out_pad, act, scale, .. } = layer;
    let mut m0 = 0;
    while m0 < rows {
        let mr = M.min(rows - m0);
        let mut n0 = 0;
        while n0 < n_out_pad {
            let w = (n_out_pad - n0).min(WMAX);
            macro_rules! run {
                ($w:expr) => {{
                    let mut acc = [[R::ZERO; $w]; M];
                    let b: &[R; $w] = bias[n0..n0 + $w].try_into().expect("bias width");
                    for row in acc.iter_mut() {
                        *row = *b;
                    }
                    product.tile::<M, $w>(&mut acc, m0, mr, n0);
                    for i in 0..mr {
                        let yr = &mut y[(m0 + i) * ys + y0 + n0..(m0 + i) * ys + y0 + n0 + $w];
                        let dr =
                            KEEP.then(|| <&mut [R; $w]>::try_from(&mut d[(m0 + i) * n_out_pad + n0..(m0 + i) * n_out_pad + n0 + $w]).expect("width"));
                        activate::<R, $w>(&acc[i], act, scale, yr.try_into().expect("width"), dr);
                    }
                }};
            }
            width_arms!(w, WMAX, run);
            n0 += w;
        }
        m0 += mr;
    }
}

/// `y = act(z)·scale` on one tile row, and `d = act'(z)` when given (the slopes are computed into a
/// local row, dropped as dead code where `d` is `None` after inlining; the softplus's by
/// [`Real::softplus_lanes`], only where asked).
#[inline(always)]
fn activate<R: Real, const W: usize>(z: &[R; W], act: Activation, scale: R, y: &mut [R; W], d: Option<&mut [R; W]>) {
    let mut slope = [R::ONE; W];
    match act {
        Activation::Identity => {
            for j in 0..W {
                y[j] = z[j] * scale;
            }
        }
        Activation::Relu => {
            for j in 0..W {
                let positive = z[j] > R::ZERO;
                y[j] = if positive { z[j] * scale } else { R::ZERO };
                slope[j] = if positive { R::ONE } else { R::ZERO };
            }
        }
        Activation::Softplus { beta } => {
            // The row's lanes stage by stage (their chains of dependent steps overlap), the
            // slopes computed only where kept.
            return R::softplus_lanes::<W>(z, R::of(beta), scale, y, d);
        }
        Activation::Sigmoid => {
            for j in 0..W {
                let (v, g) = act.apply_with_derivative(z[j]);
                y[j] = v * scale;
                slope[j] = g;
            }
        }
    }
    if let Some(d) = d {
        *d = slope;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A NaN reaching a softplus layer leaves it NaN (it once came out ≈ 0, so a broken network
    /// trained on silently), in f32's polynomial softplus, on every row it touches and no other.
    #[test]
    fn a_nan_input_makes_the_softplus_layers_outputs_nan() {
        let (rows, n_in, n_out) = (7usize, 3usize, LANE);
        let mut a: Vec<f32> = (0..rows * n_in).map(|i| (i % 5) as f32 * 0.1 - 0.2).collect();
        a[4 * n_in + 1] = f32::NAN;
        let wt: Vec<f32> = (0..n_in * n_out).map(|i| (i % 7) as f32 * 0.05 - 0.1).collect();
        let bias = vec![0.01f32; n_out];
        let (mut y, mut d) = (vec![0.0f32; rows * n_out], vec![0.0f32; rows * n_out]);
        let layer = Dense {
            a: &a,
            a_s: n_in,
            n_in,
            wt: &wt,
            bias: &bias,
            n_out_pad: n_out,
            act: Activation::Softplus { beta: 100.0 },
            scale: 1.0,
            pairs: None,
        };
        dispatch(
            #[inline(always)]
            || dense_forward(&layer, &mut y, n_out, 0, Some(&mut d), rows),
        );
        for (r, row) in y.chunks_exact(n_out).enumerate() {
            assert_eq!(row.iter().all(|v| v.is_nan()), r == 4, "row {r}: {row:?}");
            assert!(r == 4 || row.iter().all(|v| v.is_finite()), "row {r}: {row:?}");
        }
    }

    #[test]
    fn gemm_equals_the_naive_product_for_every_operand_layout() {
        let (m, n, k) = (11usize, 48usize, 7usize);
        let lv: Vec<f64> = (0..m * k).map(|i| ((i * 37) % 17) as f64 - 8.0).collect();
        let b: Vec<f64> = (0..k * n).map(|i| ((i * 13) % 11) as f64 * 0.5 - 2.0).collect();
        // L row-major (sm = k, sk = 1), column-major (sm = 1, sk = m), and neither (every other
        // value of rows of 2k): the tile's three ways of reading it, full tiles and the last.
        let lt: Vec<f64> = (0..k * m).map(|i| lv[(i % m) * k + i / m]).collect();
        let lw: Vec<f64> = (0..2 * k * m).map(|i| if i % 2 == 0 { lv[i / 2] } else { f64::NAN }).collect();
        for (l, accumulate) in [
            (Strided { data: &lv[..], sm: k, sk: 1 }, false),
            (Strided { data: &lt[..], sm: 1, sk: m }, true),
            (Strided { data: &lw[..], sm: 2 * k, sk: 2 }, false),
        ] {
            // The wide tile (AVX-512), the narrow one (else), and whichever this CPU chooses.
            for shape in 0..3 {
                let mut c = vec![1.0f64; m * n];
                dispatch(
                    #[inline(always)]
                    || match shape {
                        0 => gemm_tiles::<f64, _, WIDE_ROWS, WIDE_WIDTH>(&mut c, n, &Exact { l, b: &b, bs: n, k }, m, n, accumulate),
                        1 => gemm_tiles::<f64, _, NARROW_ROWS, NARROW_WIDTH>(&mut c, n, &Exact { l, b: &b, bs: n, k }, m, n, accumulate),
                        _ => gemm(&mut c, n, l, &b, n, m, n, k, accumulate),
                    },
                );
                for i in 0..m {
                    for j in 0..n {
                        let expected: f64 = (0..k).map(|kk| lv[i * k + kk] * b[kk * n + j]).sum::<f64>() + if accumulate { 1.0 } else { 0.0 };
                        assert_eq!(c[i * n + j], expected, "shape {shape}: ({i}, {j})");
                    }
                }
            }
        }
    }
}
