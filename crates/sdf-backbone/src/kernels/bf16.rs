//! Products in bf16 with f32 accumulation: `vdpbf16ps` (AVX512_BF16, on AMD Zen 4 and later and
//! Intel Xeon since Cooper Lake) does 32 multiply-adds per instruction where an f32 FMA does 16.
//! Each lane i of its accumulator gets `a[2i]·b[2i] + a[2i+1]·b[2i+1]`: the operands come in
//! pairs along the sum's index k, two bf16 in one u32 (the even k in the low half). The left
//! operand is f32 rows, converted to pairs as a tile reads them (packing them first would cost a
//! pass over memory as long as the product itself: measured 1.3× instead of 2× on a 64 → 64
//! layer); each pair (row m, k and k + 1) is broadcast against the right operand's pairs of
//! rows, packed once per product ([`pack_right`]: the weights).
//!
//! bf16 keeps f32's exponent and 8 bits of its mantissa: each operand is rounded by up to 2⁻⁹
//! of its value (nearest even), the products of two bf16 are exact in f32 and the sum is kept in
//! f32. Used where the CPU has the instruction ([`available`]); [`tile_portable`] is the same
//! arithmetic in plain Rust, for the tests on any CPU (and a CPU without the instruction).
//!
//! This module and its parent are the crate's only `unsafe` code: the intrinsics below, each
//! block with its SAFETY argument.

/// f32 → bf16 bits, rounded to the nearest (ties to even) as `vcvtne2ps2bf16` does; a NaN stays
/// a (quiet) NaN. Branch-free, so that loops over it vectorise.
#[inline(always)]
pub fn to_bf16(x: f32) -> u32 {
    let bits = x.to_bits();
    let rounded = bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16;
    if x.is_nan() { (bits >> 16) | 0x40 } else { rounded }
}

/// bf16 bits (the low 16 of `h`) → f32, exactly.
#[inline(always)]
pub fn from_bf16(h: u32) -> f32 {
    f32::from_bits(h << 16)
}

/// Two values as one pair: `lo` (the even k) in the low half.
#[inline(always)]
pub fn pair(lo: f32, hi: f32) -> u32 {
    to_bf16(lo) | (to_bf16(hi) << 16)
}

/// Whether this CPU runs `vdpbf16ps` (AVX512_BF16 with AVX-512 F), detected once by the
/// standard library, and the kernels may run AVX-512 ([`super::limit_instruction_set`]).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        super::instruction_set_limit().is_none()
            && std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// The right operand `B[k][0..n]` (row stride `bs`) as pairs of rows interleaved: `out[p·n + j]`
/// holds `B[2p][j]` and `B[2p + 1][j]` (zero past `k` rows), ⌈k/2⌉·n values. Element by element,
/// so it vectorises.
#[inline(always)]
pub fn pack_right(b: &[f32], bs: usize, k: usize, n: usize, out: &mut [u32]) {
    for (p, row) in out[..k.div_ceil(2) * n].chunks_exact_mut(n).enumerate() {
        let even = &b[2 * p * bs..2 * p * bs + n];
        if 2 * p + 1 < k {
            let odd = &b[(2 * p + 1) * bs..(2 * p + 1) * bs + n];
            for j in 0..n {
                row[j] = to_bf16(even[j]) | (to_bf16(odd[j]) << 16);
            }
        } else {
            for j in 0..n {
                row[j] = to_bf16(even[j]);
            }
        }
    }
}

/// The operands of a product `L · B` in bf16: L as f32 rows (row m's k values at
/// `left[m·stride ..]`), B packed by [`pack_right`].
#[derive(Clone, Copy)]
pub struct Pairs<'a> {
    /// The left operand's rows.
    pub left: &'a [f32],
    /// Stride between the left operand's rows (≥ `k`).
    pub stride: usize,
    /// Terms of the sum.
    pub k: usize,
    /// Pairs of rows of the right operand, `n` per pair.
    pub right: &'a [u32],
    /// Columns of the right operand.
    pub n: usize,
}

impl Pairs<'_> {
    /// Row `m`'s pair `p` of the left operand, rounded to bf16.
    #[inline(always)]
    fn left_pair(&self, m: usize, p: usize) -> u32 {
        let at = |kk: usize| if kk < self.k { self.left[m * self.stride + kk] } else { 0.0 };
        pair(at(2 * p), at(2 * p + 1))
    }
}

/// `acc[i][0..W] += Σₖ L(m0 + i, k) · B[k][n0..n0 + W]` for i < `mr` (rows past `mr` repeat the
/// last valid one), both operands rounded to bf16, by `vdpbf16ps` where the CPU has it, else by
/// [`tile_portable`].
#[inline(always)]
pub fn tile<const M: usize, const W: usize>(acc: &mut [[f32; W]; M], pairs: Pairs<'_>, m0: usize, mr: usize, n0: usize) {
    assert!(mr >= 1 && mr <= M && W.is_multiple_of(16), "tile shape");
    let kh = pairs.k.div_ceil(2);
    assert!(
        pairs.k >= 1
            && pairs.stride >= pairs.k
            && (m0 + mr - 1) * pairs.stride + pairs.k <= pairs.left.len()
            && pairs.right.len() >= kh * pairs.n
            && n0 + W <= pairs.n,
        "tile operands"
    );
    #[cfg(target_arch = "x86_64")]
    if available() {
        // SAFETY: the CPU has AVX-512 F and AVX512_BF16 (checked just above), which is all that
        // `tile_avx512` is compiled for; its reads are within the operands (asserted above).
        unsafe { tile_avx512::<M, W>(acc, pairs, m0, mr, n0) };
        return;
    }
    tile_portable::<M, W>(acc, pairs, m0, mr, n0);
}

/// [`tile`] in plain Rust, the same arithmetic as `vdpbf16ps`: per pair, the odd product then
/// the even one added to the f32 accumulator (each product of two bf16 is exact in f32).
#[inline(always)]
pub fn tile_portable<const M: usize, const W: usize>(acc: &mut [[f32; W]; M], pairs: Pairs<'_>, m0: usize, mr: usize, n0: usize) {
    let Pairs { k, right, n, .. } = pairs;
    for p in 0..k.div_ceil(2) {
        let b = &right[p * n + n0..p * n + n0 + W];
        for (i, row) in acc.iter_mut().enumerate() {
            let a = pairs.left_pair(m0 + i.min(mr - 1), p);
            let (a_lo, a_hi) = (from_bf16(a & 0xffff), from_bf16(a >> 16));
            for j in 0..W {
                let (b_lo, b_hi) = (from_bf16(b[j] & 0xffff), from_bf16(b[j] >> 16));
                row[j] = a_lo.mul_add(b_lo, a_hi.mul_add(b_hi, row[j]));
            }
        }
    }
}

/// [`tile`] by `vdpbf16ps`: the `M × W/16` accumulators in registers (at most 16 of the 32);
/// the left rows converted 32 values at a time (`vcvtne2ps2bf16`, masked loads at a row's end).
///
/// # Safety
/// The CPU must have AVX-512 F and AVX512_BF16; `pairs.left` must hold `pairs.k` values from
/// `m·pairs.stride` for rows m0 .. m0 + mr, `pairs.right` ⌈k/2⌉ rows of `pairs.n ≥ n0 + W` pairs.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bf16")]
unsafe fn tile_avx512<const M: usize, const W: usize>(acc: &mut [[f32; W]; M], pairs: Pairs<'_>, m0: usize, mr: usize, n0: usize) {
    use std::arch::x86_64::*;
    let Pairs { left, stride, k, right, n } = pairs;
    let rows: [*const f32; M] = std::array::from_fn(|i| left[(m0 + i.min(mr - 1)) * stride..].as_ptr());
    let mut c: [[__m512; 4]; M] = [[_mm512_setzero_ps(); 4]; M];
    for i in 0..M {
        for j in 0..W / 16 {
            // SAFETY: acc[i] holds W ≥ 16 (j + 1) floats.
            c[i][j] = unsafe { _mm512_loadu_ps(acc[i].as_ptr().add(16 * j)) };
        }
    }
    let right = right.as_ptr();
    let kh = k.div_ceil(2);
    let mut pb = 0;
    while pb < kh {
        // Pairs pb .. pb + 16 of each left row: values 2 pb .. 2 pb + 32, those past k masked off.
        let count = (k - 2 * pb).min(32);
        let lanes = |c: usize| if c >= 16 { 0xffff } else { (1u16 << c) - 1 };
        let (mask_lo, mask_hi) = (lanes(count), lanes(count.saturating_sub(16)));
        let mut a = [[0u32; 16]; M];
        for i in 0..M {
            // SAFETY: the masks enable only values 2 pb + t < k of the row, which lie within
            // `left` (asserted in `tile`); masked-off lanes are not read (and the pointers to
            // them are formed with wrapping arithmetic).
            let (lo, hi) = unsafe {
                (_mm512_maskz_loadu_ps(mask_lo, rows[i].wrapping_add(2 * pb)), _mm512_maskz_loadu_ps(mask_hi, rows[i].wrapping_add(2 * pb + 16)))
            };
            let packed = _mm512_cvtne2ps_pbh(hi, lo);
            // SAFETY: a[i] holds 16 u32, 512 bits; __m512bh is 512 bits of plain data.
            unsafe { _mm512_storeu_si512(a[i].as_mut_ptr().cast(), std::mem::transmute::<__m512bh, __m512i>(packed)) };
        }
        for pp in 0..(kh - pb).min(16) {
            let p = pb + pp;
            let mut b = [_mm512_setzero_si512(); 4];
            for j in 0..W / 16 {
                // SAFETY: p < kh and n0 + 16 (j + 1) ≤ n0 + W ≤ n: within the kh × n right operand.
                b[j] = unsafe { _mm512_loadu_si512(right.add(p * n + n0 + 16 * j).cast()) };
            }
            for i in 0..M {
                let ai = _mm512_set1_epi32(a[i][pp] as i32);
                for j in 0..W / 16 {
                    // SAFETY: __m512i and __m512bh are both 512 bits of plain data.
                    let (ai, bj) = unsafe { (std::mem::transmute::<__m512i, __m512bh>(ai), std::mem::transmute::<__m512i, __m512bh>(b[j])) };
                    c[i][j] = _mm512_dpbf16_ps(c[i][j], ai, bj);
                }
            }
        }
        pb += 16;
    }
    for i in 0..M {
        for j in 0..W / 16 {
            // SAFETY: as for the loads.
            unsafe { _mm512_storeu_ps(acc[i].as_mut_ptr().add(16 * j), c[i][j]) };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rounding_to_bf16_is_to_the_nearest_even() {
        for (x, expected) in
            [(1.0f32, 1.0f32), (1.0 + 1.0 / 256.0, 1.0), (1.0 + 3.0 / 256.0, 1.0 + 4.0 / 256.0), (-2.5, -2.5), (1e-3, 0.000_999_450_7)]
        {
            assert_eq!(from_bf16(to_bf16(x)), expected, "{x}");
        }
        for i in 0..10_000 {
            let x = (i as f32 * 0.6173).sin() * 10f32.powi(i % 7 - 3);
            let r = from_bf16(to_bf16(x));
            assert!((r - x).abs() <= x.abs() / 256.0, "{x} → {r}");
        }
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
    }

    /// Products by a kernel on pseudo-random operands (k odd and above 32, so that a tile reads
    /// a second, partial block of pairs; rows longer than k; a partial last tile), against the
    /// product of the bf16-rounded operands in f64 and against the f32 product.
    fn check(kernel: fn(&mut [[f32; 32]; 4], Pairs<'_>, usize, usize, usize)) {
        let (m, k, stride, n) = (7usize, 37usize, 48usize, 32usize);
        let l: Vec<f32> = (0..m * stride).map(|i| if i % stride < k { ((i * 37 % 101) as f32 - 50.0) / 37.0 } else { f32::NAN }).collect();
        let b: Vec<f32> = (0..k * n).map(|i| ((i * 53 % 97) as f32 - 48.0) / 29.0).collect();
        let mut right = vec![0u32; k.div_ceil(2) * n];
        pack_right(&b, n, k, n, &mut right);
        let pairs = Pairs { left: &l, stride, k, right: &right, n };
        for m0 in [0, 4] {
            let mr = (m - m0).min(4);
            let mut acc = [[0.5f32; 32]; 4];
            kernel(&mut acc, pairs, m0, mr, 0);
            for i in 0..mr {
                let row = &l[(m0 + i) * stride..];
                for j in 0..n {
                    let rounded = |x: f32| f64::from(from_bf16(to_bf16(x)));
                    let exact: f64 = 0.5 + (0..k).map(|kk| rounded(row[kk]) * rounded(b[kk * n + j])).sum::<f64>();
                    let size: f64 = (0..k).map(|kk| f64::from((row[kk] * b[kk * n + j]).abs())).sum();
                    // f32 sums of k exact products: a few ulps of the sum of magnitudes.
                    assert!((f64::from(acc[i][j]) - exact).abs() <= 1e-6 * size, "({i}, {j}): {} against {exact}", acc[i][j]);
                    // And against the f32 operands: bf16's rounding, 2⁻⁸ of each product at most.
                    let f32_product: f64 = 0.5 + (0..k).map(|kk| f64::from(row[kk]) * f64::from(b[kk * n + j])).sum::<f64>();
                    assert!((f64::from(acc[i][j]) - f32_product).abs() <= size / 128.0, "({i}, {j}) far from the f32 product");
                }
            }
        }
    }

    #[test]
    fn the_portable_bf16_tile_is_the_product_of_the_rounded_operands() {
        check(tile_portable::<4, 32>);
    }

    #[test]
    fn the_avx512_bf16_tile_agrees_with_the_portable_one() {
        if !available() {
            eprintln!("skipped: this CPU has no AVX512_BF16 (the portable emulation is tested instead)");
            return;
        }
        check(tile::<4, 32>);
        // Tile by tile against the emulation: the same sums, up to the order of the two adds.
        let (k, n) = (18usize, 48usize);
        let left: Vec<f32> = (0..4 * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.23).cos()).collect();
        let mut right = vec![0u32; k.div_ceil(2) * n];
        pack_right(&b, n, k, n, &mut right);
        let pairs = Pairs { left: &left, stride: k, k, right: &right, n };
        let (mut hw, mut emulated) = ([[0.25f32; 48]; 4], [[0.25f32; 48]; 4]);
        tile::<4, 48>(&mut hw, pairs, 0, 3, 0);
        tile_portable::<4, 48>(&mut emulated, pairs, 0, 3, 0);
        for (h, e) in hw.as_flattened().iter().zip(emulated.as_flattened()) {
            assert!((h - e).abs() <= 1e-6 * (1.0 + e.abs()), "{h} against {e}");
        }
    }
}
