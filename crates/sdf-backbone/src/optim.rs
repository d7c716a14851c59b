//! Adam and AdamW on flat parameter slices.
//!
//! Moments are f32, or — for a leading part of the parameters, the hash tables of a large
//! preset — bf16 with stochastic rounding ([`Adam::with_compact_prefix`]): half the bytes per
//! moment (paper-scale Neuralangelo: 1.46 GB instead of 2.93 GB for both). Round-to-nearest
//! would not do: the second moment's EMA adds (1 − β₂) = 0.1 % per step, below bf16's
//! resolution (2⁻⁸ ≈ 0.4 %), so it would freeze; rounding up with the probability of the
//! discarded fraction is unbiased. The rounding bits are a hash of the parameter's index and the
//! step: the same for any thread count.

/// Adam (Kingma & Ba) with optional decoupled weight decay (AdamW, Loshchilov & Hutter).
#[derive(Debug, Clone)]
pub struct Adam {
    /// β₁.
    pub beta1: f32,
    /// β₂.
    pub beta2: f32,
    /// ε.
    pub epsilon: f32,
    /// Decoupled weight decay (0 = Adam).
    pub weight_decay: f32,
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
    /// bf16 moments of the first [`Adam::compact_len`] parameters; `m` and `v` then hold the
    /// moments of the parameters after them.
    pub compact: Option<CompactMoments>,
    /// Steps taken.
    pub step: u64,
}

/// bf16 moments (the upper 16 bits of an f32), stochastically rounded.
#[derive(Debug, Clone, Default)]
pub struct CompactMoments {
    /// First moments.
    pub m: Vec<u16>,
    /// Second moments.
    pub v: Vec<u16>,
}

/// Mutable moments of a range of parameters, as they are stored.
#[derive(Debug)]
pub enum Moments<'a> {
    /// f32 moments.
    F32 {
        /// First moments.
        m: &'a mut [f32],
        /// Second moments.
        v: &'a mut [f32],
    },
    /// bf16 moments ([`CompactMoments`]).
    Bf16 {
        /// First moments.
        m: &'a mut [u16],
        /// Second moments.
        v: &'a mut [u16],
    },
}

impl<'a> Moments<'a> {
    /// The moments of `range` (relative to these).
    pub fn range(&mut self, range: std::ops::Range<usize>) -> Moments<'_> {
        match self {
            Moments::F32 { m, v } => Moments::F32 { m: &mut m[range.clone()], v: &mut v[range] },
            Moments::Bf16 { m, v } => Moments::Bf16 { m: &mut m[range.clone()], v: &mut v[range] },
        }
    }

    /// Splits into consecutive blocks ([`crate::module::split_blocks`]).
    pub fn split_blocks(self, ranges: &[std::ops::Range<usize>]) -> Vec<Moments<'a>> {
        fn pairs<'s, T>(m: &'s mut [T], v: &'s mut [T], ranges: &[std::ops::Range<usize>]) -> impl Iterator<Item = (&'s mut [T], &'s mut [T])> {
            let split = |x| crate::module::split_blocks(x, ranges.iter().cloned());
            split(m).into_iter().zip(split(v))
        }
        match self {
            Moments::F32 { m, v } => pairs(m, v, ranges).map(|(m, v)| Moments::F32 { m, v }).collect(),
            Moments::Bf16 { m, v } => pairs(m, v, ranges).map(|(m, v)| Moments::Bf16 { m, v }).collect(),
        }
    }
}

/// The f32 value of a bf16.
#[inline(always)]
pub fn bf16_to_f32(h: u16) -> f32 {
    crate::kernels::bf16::from_bf16(u32::from(h))
}

/// `x` rounded to bf16 away from zero with probability (discarded bits) / 2¹⁶, given 16 uniform
/// bits in the low half of `bits`: unbiased, E[bf16_to_f32(result)] = x (finite x).
#[inline(always)]
pub fn f32_to_bf16_stochastic(x: f32, bits: u32) -> u16 {
    (x.to_bits().wrapping_add(bits & 0xFFFF) >> 16) as u16
}

/// 32 well-mixed bits for parameter `index` at `step` (Wellons' lowbias32 finaliser).
#[inline(always)]
fn rounding_bits(index: u64, step: u32) -> u32 {
    let mut h = (index as u32) ^ ((index >> 32) as u32).wrapping_mul(0x9E37_79B9) ^ step.wrapping_mul(0x85EB_CA6B);
    h ^= h >> 16;
    h = h.wrapping_mul(0x7FEB_352D);
    h ^= h >> 15;
    h = h.wrapping_mul(0x846C_A68B);
    h ^ (h >> 16)
}

impl Adam {
    /// Adam for `n` parameters with β = (0.9, 0.999), ε = 1e-8 (NeuS: ε = 1e-15 for hash grids is
    /// Instant-NGP's; set the field).
    pub fn new(n: usize) -> Adam {
        Adam { beta1: 0.9, beta2: 0.999, epsilon: 1e-8, weight_decay: 0.0, m: vec![0.0; n], v: vec![0.0; n], compact: None, step: 0 }
    }

    /// [`Adam::new`] with the moments of the first `compact` parameters in bf16.
    pub fn with_compact_prefix(n: usize, compact: usize) -> Adam {
        let compact = compact.min(n);
        let mut adam = Adam::new(n - compact);
        adam.compact = Some(CompactMoments { m: vec![0; compact], v: vec![0; compact] });
        adam
    }

    /// Parameters whose moments are bf16 (the first ones).
    pub fn compact_len(&self) -> usize {
        self.compact.as_ref().map_or(0, |c| c.m.len())
    }

    /// Parameters this optimiser holds moments for.
    pub fn len(&self) -> usize {
        self.compact_len() + self.m.len()
    }

    /// Whether it holds no moment.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Bytes of the moments.
    pub fn moment_bytes(&self) -> usize {
        4 * self.compact_len() + 8 * self.m.len()
    }

    /// The moments of the parameters before `at` (as stored; `at` must be 0 or
    /// [`Adam::compact_len`] when some are bf16) and the f32 moments of those after it.
    pub fn split_moments(&mut self, at: usize) -> (Moments<'_>, &mut [f32], &mut [f32]) {
        let c = self.compact_len();
        match &mut self.compact {
            Some(compact) if c > 0 => {
                assert_eq!(at, c, "Adam: bf16 moments cover the first {c} parameters, not {at}");
                (Moments::Bf16 { m: &mut compact.m[..], v: &mut compact.v[..] }, &mut self.m[..], &mut self.v[..])
            }
            _ => {
                let (m0, m1) = self.m.split_at_mut(at);
                let (v0, v1) = self.v.split_at_mut(at);
                (Moments::F32 { m: m0, v: v0 }, m1, v1)
            }
        }
    }

    /// One step with learning rate `lr` over all parameters.
    pub fn update(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        let n = params.len();
        self.update_groups(params, grads, &[(0..n, lr)]);
    }

    /// One step with a learning rate per group of parameters (e.g. hash tables and MLPs);
    /// parameters in no group are left as they are (with their moments).
    pub fn update_groups(&mut self, params: &mut [f32], grads: &[f32], groups: &[(std::ops::Range<usize>, f32)]) {
        assert_eq!(params.len(), self.len(), "Adam: parameter count changed");
        assert_eq!(grads.len(), self.len(), "Adam: gradient count differs");
        let step = self.begin_step();
        let c = self.compact_len();
        let (mut head, m_rest, v_rest) = self.split_moments(c);
        for (range, lr) in groups {
            let a = range.start.min(c)..range.end.min(c);
            step.apply_moments(&mut params[a.clone()], head.range(a.clone()), &grads[a.clone()], *lr, a.start);
            let b = range.start.max(c)..range.end.max(c);
            step.apply(&mut params[b.clone()], &mut m_rest[b.start - c..b.end - c], &mut v_rest[b.start - c..b.end - c], &grads[b], *lr);
        }
    }

    /// Starts a step: advances the step count (bias corrections). Apply the returned
    /// [`AdamStep`] to every part of the parameters once, in any order or in parallel.
    pub fn begin_step(&mut self) -> AdamStep {
        self.step += 1;
        let t = self.step as i32;
        AdamStep {
            beta1: self.beta1,
            beta2: self.beta2,
            epsilon: self.epsilon,
            weight_decay: self.weight_decay,
            c1: 1.0 / (1.0 - self.beta1.powi(t)),
            c2: 1.0 / (1.0 - self.beta2.powi(t)),
            t: self.step as u32,
        }
    }
}

/// One Adam step's constants, to apply to parts of the parameters (with their moments).
#[derive(Debug, Clone, Copy)]
pub struct AdamStep {
    beta1: f32,
    beta2: f32,
    epsilon: f32,
    weight_decay: f32,
    c1: f32,
    c2: f32,
    /// The step (its low 32 bits), for the stochastic rounding of bf16 moments.
    t: u32,
}

impl AdamStep {
    /// One parameter's update from its moments `m`, `v` and gradient `g`: returns the new
    /// moments (the update uses them unrounded, whatever their storage).
    #[inline(always)]
    fn element(&self, p: &mut f32, m: f32, v: f32, g: f32, lr: f32) -> (f32, f32) {
        let m = self.beta1 * m + (1.0 - self.beta1) * g;
        let v = self.beta2 * v + (1.0 - self.beta2) * g * g;
        let update = (m * self.c1) / ((v * self.c2).sqrt() + self.epsilon);
        *p -= lr * (update + self.weight_decay * *p);
        (m, v)
    }

    /// Updates `params` (and their moments `m`, `v`) from `grads` with rate `lr` (vectorised).
    pub fn apply(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], grads: &[f32], lr: f32) {
        let s = *self;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (((p, m), v), g) in params.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(grads) {
                    (*m, *v) = s.element(p, *m, *v, *g, lr);
                }
            },
        );
    }

    /// [`AdamStep::apply`] with bf16 moments, stochastically rounded; `first` is the index of
    /// `params[0]` among all parameters (the rounding bits depend on it and on the step).
    pub fn apply_bf16(&self, params: &mut [f32], m: &mut [u16], v: &mut [u16], grads: &[f32], lr: f32, first: usize) {
        let s = *self;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (i, (((p, m), v), g)) in params.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(grads).enumerate() {
                    let (mf, vf) = s.element(p, bf16_to_f32(*m), bf16_to_f32(*v), *g, lr);
                    let bits = rounding_bits((first + i) as u64, s.t);
                    *m = f32_to_bf16_stochastic(mf, bits);
                    *v = f32_to_bf16_stochastic(vf, bits >> 16);
                }
            },
        );
    }

    /// [`AdamStep::apply`] or [`AdamStep::apply_bf16`], as the moments are stored.
    pub fn apply_moments(&self, params: &mut [f32], moments: Moments<'_>, grads: &[f32], lr: f32, first: usize) {
        match moments {
            Moments::F32 { m, v } => self.apply(params, m, v, grads, lr),
            Moments::Bf16 { m, v } => self.apply_bf16(params, m, v, grads, lr, first),
        }
    }
}

/// How the learning rate decays after the warm-up.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Decay {
    /// Cosine to `final_factor` of the base rate at the end of the run (NeuS).
    #[default]
    Cosine,
    /// × `step_factor` at each milestone (Neuralangelo).
    Step,
}

/// A learning-rate schedule on the *fraction of the run* done (so that it works for a budget of
/// steps and for a budget of time alike): linear warm-up over the first `warmup` of the run, then
/// the decay. `factor(p)` is the multiplier of the base rate for a step that ends at progress p.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LrSchedule {
    /// Warm-up, as a fraction of the run.
    pub warmup: f64,
    /// Decay after the warm-up.
    pub decay: Decay,
    /// Cosine: final rate as a fraction of the base.
    pub final_factor: f64,
    /// Step: milestones as fractions of the run.
    pub milestones: Vec<f64>,
    /// Step: multiplier per milestone.
    pub step_factor: f64,
}

impl Default for LrSchedule {
    fn default() -> Self {
        LrSchedule { warmup: 0.05, decay: Decay::Cosine, final_factor: 0.1, milestones: vec![0.5, 0.75], step_factor: 0.3 }
    }
}

impl LrSchedule {
    /// The multiplier at progress `p` ∈ [0, 1] (the end of the step).
    pub fn factor(&self, p: f64) -> f32 {
        let p = p.clamp(0.0, 1.0);
        if p < self.warmup {
            return (p / self.warmup) as f32;
        }
        match self.decay {
            Decay::Cosine => {
                let q = ((p - self.warmup) / (1.0 - self.warmup).max(1e-12)).min(1.0);
                let cosine = 0.5 * (1.0 + (std::f64::consts::PI * q).cos());
                (self.final_factor + (1.0 - self.final_factor) * cosine) as f32
            }
            Decay::Step => self.step_factor.powi(self.milestones.iter().filter(|&&m| p >= m).count() as i32) as f32,
        }
    }

    /// Checks the ranges; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        let unit = |x: f64| (0.0..=1.0).contains(&x);
        if !(unit(self.warmup) && self.warmup < 1.0) {
            return Err(format!("warmup = {} (a fraction of the run in [0, 1))", self.warmup));
        }
        if !unit(self.final_factor) {
            return Err(format!("final_factor = {} (in [0, 1])", self.final_factor));
        }
        if !self.milestones.iter().all(|m| unit(*m)) {
            return Err(format!("milestones = {:?} (fractions of the run in [0, 1])", self.milestones));
        }
        if !unit(self.step_factor) {
            return Err(format!("step_factor = {} (in [0, 1])", self.step_factor));
        }
        Ok(())
    }
}

/// Learning-rate schedule in steps: linear warm-up, then cosine decay to `final_factor` of the
/// base rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WarmupCosine {
    /// Base learning rate.
    pub base: f32,
    /// Warm-up steps.
    pub warmup: u64,
    /// Total steps.
    pub total: u64,
    /// Final rate as a fraction of the base (NeuS: 0.05).
    pub final_factor: f32,
}

impl WarmupCosine {
    /// The rate at `step`.
    pub fn at(&self, step: u64) -> f32 {
        if step < self.warmup {
            return self.base * (step + 1) as f32 / self.warmup as f32;
        }
        let progress = ((step - self.warmup) as f32 / (self.total.saturating_sub(self.warmup)).max(1) as f32).min(1.0);
        let cosine = 0.5 * (1.0 + (std::f32::consts::PI * progress).cos());
        self.base * (self.final_factor + (1.0 - self.final_factor) * cosine)
    }
}

/// Learning-rate schedule: linear warm-up, then the base rate multiplied by `factor` at each
/// milestone (step decay).
#[derive(Debug, Clone, PartialEq)]
pub struct WarmupStep {
    /// Base learning rate.
    pub base: f32,
    /// Warm-up steps.
    pub warmup: u64,
    /// Steps at which the rate is multiplied by `factor`.
    pub milestones: Vec<u64>,
    /// Multiplier per milestone (e.g. 0.1).
    pub factor: f32,
}

impl WarmupStep {
    /// The rate at `step`.
    pub fn at(&self, step: u64) -> f32 {
        if step < self.warmup {
            return self.base * (step + 1) as f32 / self.warmup as f32;
        }
        let passed = self.milestones.iter().filter(|&&m| step >= m).count() as i32;
        self.base * self.factor.powi(passed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_schedule_warms_up_then_decays() {
        let s = LrSchedule { warmup: 0.1, ..Default::default() };
        assert!((s.factor(0.05) - 0.5).abs() < 1e-6 && (s.factor(0.1) - 1.0).abs() < 1e-6);
        assert!((s.factor(1.0) - 0.1).abs() < 1e-6 && s.factor(0.55) < 1.0 && s.factor(0.55) > 0.1);
        let s = LrSchedule { warmup: 0.0, decay: Decay::Step, ..Default::default() };
        assert_eq!((s.factor(0.2), s.factor(0.5), s.factor(0.9)), (1.0, 0.3, 0.3 * 0.3));
        assert!(LrSchedule { warmup: 1.0, ..Default::default() }.validate().is_err());
    }

    #[test]
    fn adam_minimises_a_quadratic() {
        // f(p) = Σ (p − c)², gradient 2(p − c).
        let c = [1.0f32, -2.0, 0.5];
        let mut p = [0.0f32; 3];
        let mut adam = Adam::new(3);
        for _ in 0..2000 {
            let g: Vec<f32> = p.iter().zip(&c).map(|(p, c)| 2.0 * (p - c)).collect();
            adam.update(&mut p, &g, 0.01);
        }
        for (p, c) in p.iter().zip(&c) {
            assert!((p - c).abs() < 1e-3, "{p} vs {c}");
        }
    }

    #[test]
    fn stochastic_bf16_rounding_is_unbiased_and_keeps_bf16_values() {
        // 1 + 1e-3 lies between the bf16 values 1 and 1 + 2⁻⁷: round-to-nearest gives 1.
        let x = 1.001f32;
        let n = 1 << 16;
        let mean: f64 = (0..n).map(|i| f64::from(bf16_to_f32(f32_to_bf16_stochastic(x, rounding_bits(i, 7))))).sum::<f64>() / n as f64;
        assert!((mean - f64::from(x)).abs() < 5e-5, "mean {mean} vs {x}");
        for (i, y) in [1.5f32, -0.25, 0.0, 2f32.powi(-60)].into_iter().enumerate() {
            assert_eq!(bf16_to_f32(f32_to_bf16_stochastic(y, rounding_bits(i as u64, 1))), y);
        }
    }

    /// Regression: with round-to-nearest a bf16 second moment freezes (β₂ = 0.999 adds 0.1 % per
    /// step, under bf16's 0.4 % resolution); stochastically rounded it follows the f32 EMA.
    #[test]
    fn bf16_second_moment_does_not_freeze_under_small_increments() {
        // 1024 parameters: one bf16 moment's rounding noise is ~5 % of it after 1000 steps.
        let mut adam = Adam::with_compact_prefix(1024, 1024);
        adam.compact.as_mut().unwrap().v.iter_mut().for_each(|v| *v = f32_to_bf16_stochastic(1.0, 0));
        let mut p = vec![0.0f32; 1024];
        let g = vec![2.0f32.sqrt(); 1024];
        for _ in 0..1000 {
            adam.update(&mut p, &g, 0.0);
        }
        let ema = 2.0 - 0.999f64.powi(1000);
        let v = &adam.compact.as_ref().unwrap().v;
        let mean = v.iter().map(|h| f64::from(bf16_to_f32(*h))).sum::<f64>() / v.len() as f64;
        assert!((mean / ema - 1.0).abs() < 0.01, "bf16 v {mean} vs the f32 EMA {ema}");
    }

    #[test]
    fn adam_with_bf16_moments_minimises_a_quadratic() {
        // Two parameters with bf16 moments, one with f32 ones.
        let c = [1.0f32, -2.0, 0.5];
        let mut p = [0.0f32; 3];
        let mut adam = Adam::with_compact_prefix(3, 2);
        assert_eq!((adam.compact_len(), adam.len(), adam.moment_bytes()), (2, 3, 16));
        for _ in 0..2000 {
            let g: Vec<f32> = p.iter().zip(&c).map(|(p, c)| 2.0 * (p - c)).collect();
            adam.update(&mut p, &g, 0.01);
        }
        for (p, c) in p.iter().zip(&c) {
            assert!((p - c).abs() < 2e-3, "{p} vs {c}");
        }
    }

    #[test]
    fn first_adam_step_has_the_learning_rate_as_size() {
        let mut p = [0.0f32];
        let mut adam = Adam::new(1);
        adam.update(&mut p, &[123.0], 0.1);
        assert!((p[0] + 0.1).abs() < 1e-6);
    }

    #[test]
    fn warmup_then_step_decay() {
        let s = WarmupStep { base: 1.0, warmup: 10, milestones: vec![50, 80], factor: 0.1 };
        assert!((s.at(4) - 0.5).abs() < 1e-6);
        assert_eq!(s.at(49), 1.0);
        assert!((s.at(50) - 0.1).abs() < 1e-7 && (s.at(99) - 0.01).abs() < 1e-8);
    }

    #[test]
    fn warmup_then_cosine() {
        let s = WarmupCosine { base: 1.0, warmup: 10, total: 110, final_factor: 0.05 };
        assert!((s.at(0) - 0.1).abs() < 1e-6 && (s.at(9) - 1.0).abs() < 1e-6);
        assert!((s.at(10) - 1.0).abs() < 1e-6 && (s.at(60) - 0.525).abs() < 1e-3 && (s.at(110) - 0.05).abs() < 1e-6);
    }
}
