//! The float types modules compute in: f32 for training, f64 for gradient checks.

use std::ops::{Add, AddAssign, Div, Mul, MulAssign, Neg, Sub, SubAssign};

/// A floating-point scalar (implemented for f32 and f64). Modules are generic over it so that
/// the same code is checked against finite differences in f64 and runs in f32.
pub trait Real:
    Copy
    + Send
    + Sync
    + Default
    + PartialOrd
    + std::fmt::Debug
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
    + SubAssign
    + MulAssign
    + ndarray::LinalgScalar
    + crate::scratch::Element
    + 'static
{
    /// 0.
    const ZERO: Self;
    /// 1.
    const ONE: Self;
    /// Conversion from f64 (rounding for f32).
    fn of(x: f64) -> Self;
    /// Conversion to f64.
    fn to_f64(self) -> f64;
    /// eˣ.
    fn exp(self) -> Self;
    /// eˣ for x ≤ 0 (NaN stays NaN): f32 by [`exp_nonpositive_f32`] (polynomials and selects, so
    /// that a loop of them vectorises; relative error < 2e-7), f64 the standard library's.
    fn exp_nonpositive(self) -> Self;
    /// ln(1 + x), accurate for small x.
    fn ln_1p(self) -> Self;
    /// ln x.
    fn ln(self) -> Self;
    /// sin x.
    fn sin(self) -> Self;
    /// cos x.
    fn cos(self) -> Self;
    /// √x.
    fn sqrt(self) -> Self;
    /// |x|.
    fn abs(self) -> Self;
    /// The larger of two values.
    fn max(self, other: Self) -> Self;
    /// The smaller of two values.
    fn min(self, other: Self) -> Self;
    /// self · a + b with one rounding (an FMA instruction where the CPU has one and the code is
    /// dispatched for it).
    fn mul_add(self, a: Self, b: Self) -> Self;
    /// ⌊x⌋.
    fn floor(self) -> Self;
    /// Softplus with sharpness β and its derivative at z: `(ln(1 + e^{βz}) / β, σ(βz))`, from one
    /// exponential. f64: the standard library's functions (the reference the gradient checks
    /// use); f32: a branch-free polynomial form that vectorises (relative error < 1e-6, tested
    /// against f64).
    fn softplus_with_derivative(self, beta: Self) -> (Self, Self);
    /// [`Real::softplus_with_derivative`] on `N` lanes, each value times `scale` into `y` and,
    /// when given, each derivative into `slope`: the same bits as lane by lane. In f32 each step
    /// of the formula runs on all lanes before the next, so that the lanes' long chains of
    /// dependent steps overlap; in f64 lane by lane.
    fn softplus_lanes<const N: usize>(z: &[Self; N], beta: Self, scale: Self, y: &mut [Self; N], slope: Option<&mut [Self; N]>);
    /// A non-negative integer value below 2²³ as u32, by placing it in the mantissa (adding
    /// 2²³, or 2⁵² in f64) instead of a float → int conversion: loops with it vectorise.
    fn small_index(self) -> u32;
    /// The slice as f32 values when this is f32 (the products in bf16 are for f32 only; the f64
    /// gradient checks keep every product exact).
    fn f32s(s: &[Self]) -> Option<&[f32]>;
    /// [`Real::f32s`], mutable.
    fn f32s_mut(s: &mut [Self]) -> Option<&mut [f32]>;
}

macro_rules! impl_real {
    ($t:ty, $f32s:expr, $f32s_mut:expr) => {
        impl Real for $t {
            const ZERO: Self = 0.0;
            const ONE: Self = 1.0;
            #[inline]
            fn of(x: f64) -> Self {
                x as $t
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn exp(self) -> Self {
                <$t>::exp(self)
            }
            #[inline(always)]
            fn exp_nonpositive(self) -> Self {
                <$t as SoftplusImpl>::exp_nonpositive(self)
            }
            #[inline]
            fn ln_1p(self) -> Self {
                <$t>::ln_1p(self)
            }
            #[inline]
            fn ln(self) -> Self {
                <$t>::ln(self)
            }
            #[inline]
            fn sin(self) -> Self {
                <$t>::sin(self)
            }
            #[inline]
            fn cos(self) -> Self {
                <$t>::cos(self)
            }
            #[inline]
            fn sqrt(self) -> Self {
                <$t>::sqrt(self)
            }
            #[inline]
            fn abs(self) -> Self {
                <$t>::abs(self)
            }
            #[inline]
            fn max(self, other: Self) -> Self {
                <$t>::max(self, other)
            }
            #[inline]
            fn min(self, other: Self) -> Self {
                <$t>::min(self, other)
            }
            #[inline(always)]
            fn mul_add(self, a: Self, b: Self) -> Self {
                <$t>::mul_add(self, a, b)
            }
            #[inline(always)]
            fn floor(self) -> Self {
                <$t>::floor(self)
            }
            #[inline(always)]
            fn softplus_with_derivative(self, beta: Self) -> (Self, Self) {
                softplus_impl(self, beta)
            }
            #[inline(always)]
            fn softplus_lanes<const N: usize>(z: &[Self; N], beta: Self, scale: Self, y: &mut [Self; N], slope: Option<&mut [Self; N]>) {
                <$t as SoftplusImpl>::softplus_lanes(z, beta, scale, y, slope)
            }
            #[inline(always)]
            fn small_index(self) -> u32 {
                // 2^(mantissa bits): the integer part lands in the low mantissa bits.
                let magic: $t = (1u64 << (<$t>::MANTISSA_DIGITS - 1)) as $t;
                (self + magic).to_bits().wrapping_sub(magic.to_bits()) as u32
            }
            #[inline(always)]
            fn f32s(s: &[Self]) -> Option<&[f32]> {
                $f32s(s)
            }
            #[inline(always)]
            fn f32s_mut(s: &mut [Self]) -> Option<&mut [f32]> {
                $f32s_mut(s)
            }
        }
    };
}
impl_real!(f32, Some, Some);
impl_real!(f64, |_| None, |_| None);

/// f64 softplus and sigmoid from the standard library (`ln_1p`, `exp`).
#[inline(always)]
fn softplus_f64(z: f64, beta: f64) -> (f64, f64) {
    let x = beta * z;
    let e = (-x.abs()).exp();
    let sig = if x > 0.0 { 1.0 / (1.0 + e) } else { e / (1.0 + e) };
    ((x.max(0.0) + e.ln_1p()) / beta, sig)
}

/// e^x for x ≤ 0 in f32 without branches, library calls or float → int conversions (so that
/// loops vectorise): n = round(x log₂e) by adding 1.5·2²³ (which leaves n in the low mantissa
/// bits), x = n ln 2 + r with |r| ≤ ln2/2 (Cody–Waite), e^r by a degree-6 polynomial, 2ⁿ by
/// building the exponent bits. x below −87 is taken as −87 (e^−87 ≈ 1.6e-38, the smallest
/// normal range: no denormals); NaN gives NaN. Relative error < 2e-7.
#[inline(always)]
pub fn exp_nonpositive_f32(x: f32) -> f32 {
    const MAGIC: f32 = 12_582_912.0; // 1.5 · 2²³
    // Not `x.max(-87.0)`: `max` drops a NaN, and the polynomial would make a number of −87, so a
    // NaN (a broken model's SDF value or pre-activation) would leave the softplus and the render's
    // opacities as plausible numbers. The select costs the same and gives every other x's bits.
    let x = if x < -87.0 { -87.0 } else { x };
    let shifted = x.mul_add(std::f32::consts::LOG2_E, MAGIC);
    let n = shifted - MAGIC;
    let r = n.mul_add(-0.693_145_75, x);
    let r = n.mul_add(-1.428_606_8e-6, r);
    let p = 1.0 / 720.0f32;
    let p = p.mul_add(r, 1.0 / 120.0);
    let p = p.mul_add(r, 1.0 / 24.0);
    let p = p.mul_add(r, 1.0 / 6.0);
    let p = p.mul_add(r, 0.5);
    let p = p.mul_add(r, 1.0);
    let p = p.mul_add(r, 1.0);
    let bits = shifted.to_bits().wrapping_sub(MAGIC.to_bits());
    p * f32::from_bits(bits.wrapping_add(127) << 23)
}

/// Below this βz, f32 softplus and its derivative are flushed to exactly 0 (their true values
/// are below e^−40 ≈ 4e-18): the tails would otherwise reach denormal numbers, which x86 handles
/// in microcode, 10 × slower (measured: 1.0 instead of 0.4 ns per value).
const SOFTPLUS_FLUSH: f32 = -40.0;

/// 2 atanh(s) for s ∈ [0, 1/3]: ln(1 + t) where s = t/(2 + t) (t ∈ [0, 1]; exact for small t),
/// odd series to s¹³. Relative error < 2e-7.
#[inline(always)]
fn ln_1p_by_atanh(s: f32) -> f32 {
    let s2 = s * s;
    let p = 1.0 / 13.0f32;
    let p = p.mul_add(s2, 1.0 / 11.0);
    let p = p.mul_add(s2, 1.0 / 9.0);
    let p = p.mul_add(s2, 1.0 / 7.0);
    let p = p.mul_add(s2, 1.0 / 5.0);
    let p = p.mul_add(s2, 1.0 / 3.0);
    let p = p.mul_add(s2, 1.0);
    2.0 * s * p
}

/// The steps of the f32 softplus of x = βz that its value and its slope share: e = e^{−|x|},
/// flushed to 0 below [`SOFTPLUS_FLUSH`] (NaN stays NaN: [`exp_nonpositive_f32`]), and
/// q = 1/((1 + e)(2 + e)), from which both the sigmoid's 1/(1 + e) and the logarithm's
/// e/(2 + e) follow (a division costs as much as a dozen multiply-adds, and there were three:
/// the softplus took a third of the SDF network's forward time).
#[inline(always)]
fn softplus_shared(x: f32) -> (f32, f32) {
    let neg = -x.abs();
    let e = exp_nonpositive_f32(neg);
    let e = if neg < SOFTPLUS_FLUSH { 0.0 } else { e };
    (e, 1.0 / ((1.0 + e) * (2.0 + e)))
}

/// The f32 softplus's slope σ(x) from x, e and q: (2 + e)q = 1/(1 + e) for x > 0, e times it
/// otherwise.
#[inline(always)]
fn softplus_slope(x: f32, e: f32, q: f32) -> f32 {
    let inv = (2.0 + e) * q;
    if x > 0.0 { inv } else { e * inv }
}

/// The f32 softplus's value from x, e and q: `(max(x, 0) + ln(1 + e)) / β`, ln(1 + e) as
/// 2 atanh(e(1 + e)q).
#[inline(always)]
fn softplus_value(x: f32, e: f32, q: f32, beta: f32) -> f32 {
    (x.max(0.0) + ln_1p_by_atanh(e * (1.0 + e) * q)) * beta.recip()
}

/// f32 softplus and sigmoid from one [`exp_nonpositive_f32`] of −|βz| and one division
/// ([`softplus_shared`]). A NaN x leaves e NaN, so the value and the slope are NaN too.
#[inline(always)]
fn softplus_f32(z: f32, beta: f32) -> (f32, f32) {
    let x = beta * z;
    let (e, q) = softplus_shared(x);
    (softplus_value(x, e, q, beta), softplus_slope(x, e, q))
}

/// [`softplus_f32`] on `N` lanes, stage by stage (the same operations on each lane, so the same
/// bits): x = βz, then e and q, then the slopes where asked, then the values times `scale`. Lane
/// by lane, a vector's chain of some 40 dependent steps left the FMA units idle: the core's
/// scheduler holds too few steps to overlap more than two or three such chains (DECISIONS §56).
#[inline(always)]
fn softplus_lanes_f32<const N: usize>(z: &[f32; N], beta: f32, scale: f32, y: &mut [f32; N], slope: Option<&mut [f32; N]>) {
    let (mut x, mut e, mut q) = ([0.0f32; N], [0.0f32; N], [0.0f32; N]);
    for j in 0..N {
        x[j] = beta * z[j];
    }
    for j in 0..N {
        (e[j], q[j]) = softplus_shared(x[j]);
    }
    if let Some(slope) = slope {
        for j in 0..N {
            slope[j] = softplus_slope(x[j], e[j], q[j]);
        }
    }
    for j in 0..N {
        y[j] = softplus_value(x[j], e[j], q[j], beta) * scale;
    }
}

/// Dispatches [`Real::softplus_with_derivative`], [`Real::softplus_lanes`] and
/// [`Real::exp_nonpositive`] to the precision's implementation.
trait SoftplusImpl: Sized {
    fn softplus_impl(z: Self, beta: Self) -> (Self, Self);
    fn exp_nonpositive(x: Self) -> Self;
    fn softplus_lanes<const N: usize>(z: &[Self; N], beta: Self, scale: Self, y: &mut [Self; N], slope: Option<&mut [Self; N]>);
}
impl SoftplusImpl for f32 {
    #[inline(always)]
    fn exp_nonpositive(x: f32) -> f32 {
        exp_nonpositive_f32(x)
    }
    #[inline(always)]
    fn softplus_impl(z: f32, beta: f32) -> (f32, f32) {
        softplus_f32(z, beta)
    }
    #[inline(always)]
    fn softplus_lanes<const N: usize>(z: &[f32; N], beta: f32, scale: f32, y: &mut [f32; N], slope: Option<&mut [f32; N]>) {
        softplus_lanes_f32(z, beta, scale, y, slope)
    }
}
impl SoftplusImpl for f64 {
    #[inline(always)]
    fn exp_nonpositive(x: f64) -> f64 {
        x.exp()
    }
    #[inline(always)]
    fn softplus_impl(z: f64, beta: f64) -> (f64, f64) {
        softplus_f64(z, beta)
    }
    #[inline(always)]
    fn softplus_lanes<const N: usize>(z: &[f64; N], beta: f64, scale: f64, y: &mut [f64; N], mut slope: Option<&mut [f64; N]>) {
        for j in 0..N {
            let (v, g) = softplus_f64(z[j], beta);
            y[j] = v * scale;
            if let Some(slope) = slope.as_deref_mut() {
                slope[j] = g;
            }
        }
    }
}
#[inline(always)]
fn softplus_impl<T: SoftplusImpl>(z: T, beta: T) -> (T, T) {
    T::softplus_impl(z, beta)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nan_pre_activation_gives_a_nan_softplus() {
        assert!(exp_nonpositive_f32(f32::NAN).is_nan());
        for beta in [1.0f32, 100.0] {
            assert!(softplus_f32(f32::NAN, beta).0.is_nan(), "f32, β = {beta}");
            assert!(softplus_f32(f32::NAN, beta).1.is_nan(), "f32's slope, β = {beta}");
            assert!(softplus_f64(f64::NAN, f64::from(beta)).0.is_nan(), "f64, β = {beta}");
        }
        // −0 gives +0's values, and the flushed tail exactly 0 (that no finite value's bits changed
        // was checked end to end: `steps=200` gives the same mesh bytes, DECISIONS §50).
        assert_eq!(softplus_f32(-0.0, 100.0), softplus_f32(0.0, 100.0));
        assert_eq!(softplus_f32(-1.0, 100.0), (0.0, 0.0));
    }

    /// Guards the stage-by-stage softplus the layers run: each lane's value (times the scale)
    /// and slope are [`Real::softplus_with_derivative`]'s to the bit, in f32 and f64, across
    /// both signs, the flushed tail, NaN and ±0; without slopes the values are the same.
    #[test]
    fn softplus_lanes_are_the_softplus_lane_by_lane_to_the_bit() {
        fn check<R: Real>(z: &[R; 16], beta: R, scale: R) {
            let (mut y, mut slope, mut alone) = ([R::ZERO; 16], [R::ZERO; 16], [R::ZERO; 16]);
            R::softplus_lanes(z, beta, scale, &mut y, Some(&mut slope));
            R::softplus_lanes(z, beta, scale, &mut alone, None);
            for j in 0..16 {
                let (v, g) = z[j].softplus_with_derivative(beta);
                let bits = |x: R| x.to_f64().to_bits();
                assert_eq!((bits(y[j]), bits(slope[j]), bits(alone[j])), (bits(v * scale), bits(g), bits(v * scale)), "lane {j}: z = {:?}", z[j]);
            }
        }
        let z: [f64; 16] = [-3.0, -0.45, -0.3, -0.05, -1e-3, -0.0, 0.0, 1e-4, 0.01, 0.2, 0.5, 2.0, f64::NAN, -1e-8, 0.35, -0.17];
        for (beta, scale) in [(100.0, 1.0), (1.0, 0.7), (10.0, 2.0)] {
            check(&z, beta, scale);
            check(&z.map(|v| v as f32), beta as f32, scale as f32);
        }
    }

    #[test]
    fn fast_f32_softplus_matches_f64_to_a_millionth() {
        let mut worst = (0.0f64, 0.0f64, 0.0f64);
        for i in -200_000..=200_000 {
            let z = (i as f64 * 1e-5 * 3.0) as f32; // −3 … 3 with β = 100: βz in −300 … 300
            let (y, d) = softplus_f32(z, 100.0);
            // The reference sees the same f32 product βz (its rounding, ~4e-6 absolute at
            // |βz| ≈ 64, is f32's, not the approximation's).
            let (ye, de) = softplus_f64(f64::from(100.0f32 * z), 1.0);
            let ye = ye / 100.0;
            let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(1e-30);
            // Relative above the flush level, absolute below it.
            if ye > 1e-15 {
                worst.0 = worst.0.max(rel(f64::from(y), ye));
            } else {
                worst.1 = worst.1.max((f64::from(y) - ye).abs());
            }
            worst.2 = worst.2.max((f64::from(d) - de).abs());
        }
        assert!(
            worst.0 < 1e-6 && worst.1 < 1e-15 && worst.2 < 1e-6,
            "softplus: relative error {:e}, absolute {:e}; derivative: absolute error {:e}",
            worst.0,
            worst.1,
            worst.2
        );
        for x in [-1e3f32, -88.0, -20.0, -1.0, -1e-8, 0.0] {
            let (a, b) = (exp_nonpositive_f32(x), f64::from(x).exp());
            assert!((f64::from(a) - b).abs() <= 2e-7 * b + 2e-38, "exp({x}) = {a}, expected {b}");
        }
    }
}
