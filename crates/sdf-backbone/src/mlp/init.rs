//! An MLP's initial parameters: He's default, NeuS's geometric initialisation (a sphere), and
//! the SDF readout calibrated by least squares.

use super::Mlp;
use crate::kernels::pad;
use crate::module::Module;
use rand::{SeedableRng, rngs::Xoshiro256PlusPlus};
use rand_distr::{Distribution, Normal};

impl Mlp {
    /// Default initialisation: weights N(0, 2/fan_in) (He), zero biases.
    pub fn init_default(&self, params: &mut [f32], seed: u64) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        for &(n_in, n_out, off) in &self.layers {
            let normal = Normal::new(0.0, (2.0 / n_in as f64).sqrt()).expect("finite std");
            for w in &mut params[off..off + n_in * n_out] {
                *w = normal.sample(&mut rng) as f32;
            }
            params[off + n_in * n_out..off + n_in * n_out + n_out].fill(0.0);
        }
    }

    /// NeuS's geometric initialisation (Atzmon & Lipman, SAL): the first output approximates the
    /// signed distance to a sphere of radius `radius`, `|x| − radius`. Only the first `raw`
    /// inputs (the raw coordinates, before any encoding) get weights in the first and the skip
    /// layer, so that the encoding's high frequencies start silent.
    pub fn init_geometric(&self, params: &mut [f32], radius: f64, raw: usize, seed: u64) {
        let mut rng = Xoshiro256PlusPlus::seed_from_u64(seed);
        let last = self.layers.len() - 1;
        for (l, &(n_in, n_out, off)) in self.layers.iter().enumerate() {
            let (w, b) = params[off..off + n_in * n_out + n_out].split_at_mut(n_in * n_out);
            if l == last {
                let normal = Normal::new(std::f64::consts::PI.sqrt() / (n_in as f64).sqrt(), 1e-4).expect("finite");
                for v in w.iter_mut() {
                    *v = normal.sample(&mut rng) as f32;
                }
                b.fill(0.0);
                b[0] = -radius as f32;
            } else {
                let normal = Normal::new(0.0, 2f64.sqrt() / (n_out as f64).sqrt()).expect("finite");
                let skip_part = if self.config.skip == Some(l) { n_in - self.config.n_inputs } else { usize::MAX };
                for o in 0..n_out {
                    for i in 0..n_in {
                        // Encoded inputs start at zero weight: in the first layer everything past
                        // `raw`; in the skip layer the re-injected input's encoded part.
                        let silent = (l == 0 && i >= raw) || (i >= skip_part && i - skip_part >= raw);
                        w[o * n_in + i] = if silent { 0.0 } else { normal.sample(&mut rng) as f32 };
                    }
                }
                b.fill(0.0);
            }
        }
    }

    /// Refits the output layer's first row (weights and bias) by ridge regression so that the
    /// first output matches `target` on `inputs` (rows of `n_inputs`): a cheap calibration after
    /// [`Self::init_geometric`], whose finite-width result is |x| − r only on average (measured
    /// ±0.2 at 8 × 256). The hidden layers stay random features; this solves for the readout.
    pub fn calibrate_first_output(&self, params: &mut [f32], inputs: &[f32], target: &[f32]) {
        let rows = target.len();
        let &(n_in, _, off) = self.layers.last().expect("an MLP has an output layer");
        // The last hidden activations (the output layer's inputs) from the context.
        let per_row = self.ctx_layout();
        let mut out = vec![0.0f32; rows * self.config.n_outputs];
        let mut ctx = vec![0.0f32; rows * per_row];
        Module::<f32>::forward(self, params, inputs, &mut out, &mut ctx);
        // The context is layer-major: the output layer's input A is a rows × pad(n_in) block.
        let a_start = self.last_input_offset(rows);
        let value = |r: usize, k: usize| ctx[a_start + r * pad(n_in) + k];
        // Normal equations for [w, b]: (AᵀA + λI) θ = Aᵀy, in f64.
        let m = n_in + 1;
        let mut ata = vec![0.0f64; m * m];
        let mut aty = vec![0.0f64; m];
        let mut a = vec![0.0f64; m];
        for r in 0..rows {
            for i in 0..n_in {
                a[i] = value(r, i) as f64;
            }
            a[n_in] = 1.0;
            for i in 0..m {
                aty[i] += a[i] * target[r] as f64;
                for j in 0..=i {
                    ata[i * m + j] += a[i] * a[j];
                }
            }
        }
        let ridge = 1e-6 * (0..m).map(|i| ata[i * m + i]).sum::<f64>() / m as f64;
        for i in 0..m {
            ata[i * m + i] += ridge;
            for j in 0..i {
                ata[j * m + i] = ata[i * m + j];
            }
        }
        let theta = cholesky_solve(&mut ata, &aty, m).expect("ridge regression is positive definite");
        let (w, b) = params[off..off + n_in * self.config.n_outputs + self.config.n_outputs].split_at_mut(n_in * self.config.n_outputs);
        for i in 0..n_in {
            w[i] = theta[i] as f32;
        }
        b[0] = theta[n_in] as f32;
    }
}

/// Solves A x = b for a symmetric positive-definite A (row-major, overwritten by its Cholesky
/// factor). `None` if A is not positive definite.
fn cholesky_solve(a: &mut [f64], b: &[f64], n: usize) -> Option<Vec<f64>> {
    for j in 0..n {
        let mut d = a[j * n + j];
        for k in 0..j {
            d -= a[j * n + k] * a[j * n + k];
        }
        if !(d > 0.0) {
            return None;
        }
        let d = d.sqrt();
        a[j * n + j] = d;
        for i in j + 1..n {
            let mut s = a[i * n + j];
            for k in 0..j {
                s -= a[i * n + k] * a[j * n + k];
            }
            a[i * n + j] = s / d;
        }
    }
    let mut y = b.to_vec();
    for i in 0..n {
        for k in 0..i {
            y[i] -= a[i * n + k] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    for i in (0..n).rev() {
        for k in i + 1..n {
            y[i] -= a[k * n + i] * y[k];
        }
        y[i] /= a[i * n + i];
    }
    Some(y)
}
