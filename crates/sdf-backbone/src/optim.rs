//! Adam and AdamW on flat parameter slices.

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
    /// Steps taken.
    pub step: u64,
}

impl Adam {
    /// Adam for `n` parameters with β = (0.9, 0.999), ε = 1e-8 (NeuS: ε = 1e-15 for hash grids is
    /// Instant-NGP's; set the field).
    pub fn new(n: usize) -> Adam {
        Adam { beta1: 0.9, beta2: 0.999, epsilon: 1e-8, weight_decay: 0.0, m: vec![0.0; n], v: vec![0.0; n], step: 0 }
    }

    /// One step with learning rate `lr` over all parameters.
    pub fn update(&mut self, params: &mut [f32], grads: &[f32], lr: f32) {
        let n = params.len();
        self.update_groups(params, grads, &[(0..n, lr)]);
    }

    /// One step with a learning rate per group of parameters (e.g. hash tables and MLPs);
    /// parameters in no group are left as they are (with their moments).
    pub fn update_groups(&mut self, params: &mut [f32], grads: &[f32], groups: &[(std::ops::Range<usize>, f32)]) {
        assert_eq!(params.len(), self.m.len(), "Adam: parameter count changed");
        assert_eq!(grads.len(), self.m.len(), "Adam: gradient count differs");
        let step = self.begin_step();
        for (range, lr) in groups {
            let r = range.clone();
            step.apply(&mut params[r.clone()], &mut self.m[r.clone()], &mut self.v[r.clone()], &grads[r], *lr);
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
}

impl AdamStep {
    /// Updates `params` (and their moments `m`, `v`) from `grads` with rate `lr` (vectorised).
    pub fn apply(&self, params: &mut [f32], m: &mut [f32], v: &mut [f32], grads: &[f32], lr: f32) {
        let s = *self;
        crate::kernels::dispatch(
            #[inline(always)]
            || {
                for (((p, m), v), g) in params.iter_mut().zip(m.iter_mut()).zip(v.iter_mut()).zip(grads) {
                    *m = s.beta1 * *m + (1.0 - s.beta1) * g;
                    *v = s.beta2 * *v + (1.0 - s.beta2) * g * g;
                    let update = (*m * s.c1) / ((*v * s.c2).sqrt() + s.epsilon);
                    *p -= lr * (update + s.weight_decay * *p);
                }
            },
        );
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
