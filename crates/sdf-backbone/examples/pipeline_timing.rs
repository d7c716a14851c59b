//! Times one training step (forward + backward of the whole render + loss pipeline) on random
//! rays, for a Neuralangelo-style CPU configuration (a profiling aid, not the benchmark of
//! issue #4): `cargo run --release -p sdf-backbone --example pipeline_timing [rays] [samples] [chunk]`.
use sdf_backbone::*;
use std::time::Instant;

fn main() {
    if std::env::var("BREAKDOWN").is_ok() {
        breakdown();
        kernels();
        softplus_speed();
        return;
    }
    let args: Vec<usize> = std::env::args().skip(1).filter_map(|a| a.parse().ok()).collect();
    let (n_rays, n_samples) = (args.first().copied().unwrap_or(512), args.get(1).copied().unwrap_or(64));
    let (pipeline, params) = build(Preset::NeuralangeloCpu, 0.5, 1);
    let n = params.len();
    let rays: Vec<RayInput<f32>> = (0..n_rays)
        .map(|r| {
            let a = r as f32 * 0.01;
            RayInput {
                origin: [3.0 * a.cos(), 3.0 * a.sin(), 0.3],
                direction: [-a.cos(), -a.sin(), -0.1],
                depths: (0..=n_samples).map(|i| 2.0 + 2.0 * i as f32 / n_samples as f32).collect(),
                target: [0.5, 0.4, 0.3],
                mask: Some(1.0),
                weight: 1.0,
            }
        })
        .collect();
    let mut grads = vec![0.0f32; n];
    // Rays per work item (each has its own gradient buffer and goes through each network at once).
    let chunk = args.get(2).copied().unwrap_or(32);
    let _ = pipeline.loss_parallel(&params, &rays, &mut grads, chunk, &NoSampleLoss);
    let steps = std::env::var("STEPS").ok().and_then(|s| s.parse().ok()).unwrap_or(3);
    let t = Instant::now();
    for _ in 0..steps {
        grads.fill(0.0);
        let _ = pipeline.loss_parallel(&params, &rays, &mut grads, chunk, &NoSampleLoss);
    }
    let per_step = t.elapsed().as_secs_f64() / steps as f64;
    let evaluations = n_rays * (5 * n_samples + 1);
    println!(
        "{n_rays} rays × {n_samples} samples ({evaluations} SDF evaluations incl. normals), {n} parameters, chunks of {chunk} rays: {:.3} s per step on {} threads",
        per_step,
        rayon::current_num_threads()
    );
}

/// Seconds per call of `f`, best of three after a warm-up.
fn best<F: FnMut()>(mut f: F) -> f64 {
    f();
    (0..3)
        .map(|_| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        })
        .fold(f64::INFINITY, f64::min)
}

/// The parts of a step on one thread: hash grid and MLPs, forward and backward, on the rows of
/// one 32-ray work item of 128 samples (run with `BREAKDOWN=1`).
#[allow(dead_code)]
fn breakdown() {
    let (pipeline, params) = build(Preset::NeuralangeloCpu, 0.5, 1);
    let layout = pipeline.layout();
    let rows = 32 * (5 * 128 + 1);
    let x: Vec<f32> = (0..3 * rows).map(|i| ((i * 7919) % 2000) as f32 / 1000.0 - 1.0).collect();
    let enc = &pipeline.sdf.a;
    let (n_enc, enc_ctx) = (Module::<f32>::n_outputs(enc), Module::<f32>::ctx_per_row(enc));
    let mut e = vec![0.0f32; rows * n_enc];
    let mut ec = vec![0.0f32; rows * enc_ctx];
    let pe = &params[layout.encoding.clone()];
    let t_enc_f = best(|| enc.forward(pe, &x, &mut e, &mut ec));
    let de = vec![1e-3f32; rows * n_enc];
    let mut g = vec![0.0f32; params.len()];
    let t_enc_b = best(|| enc.backward(pe, &x, &ec, &de, &mut g[layout.encoding.clone()], None));
    let mlp = &pipeline.sdf.b;
    let pm = &params[layout.sdf_mlp.clone()];
    let mut y = vec![0.0f32; rows * 16];
    let mut mc = vec![0.0f32; rows * Module::<f32>::ctx_per_row(mlp)];
    let t_mlp_f = best(|| mlp.forward(pm, &e, &mut y, &mut mc));
    let dy = vec![1e-3f32; rows * 16];
    let mut de2 = vec![0.0f32; rows * n_enc];
    let t_mlp_b = best(|| mlp.backward(pm, &e, &mc, &dy, &mut g[layout.sdf_mlp.clone()], Some(&mut de2)));
    println!(
        "one work item ({rows} SDF rows), one thread: hash grid forward {:.1} ms, backward {:.1} ms; SDF MLP forward {:.1} ms, backward {:.1} ms",
        t_enc_f * 1e3,
        t_enc_b * 1e3,
        t_mlp_f * 1e3,
        t_mlp_b * 1e3
    );
}

/// The kernels alone on `ROWS` rows (default 20 512): a 64 → 64 layer with and without softplus.
#[allow(dead_code)]
fn kernels() {
    use sdf_backbone::kernels::{Dense, Strided, dense_forward, dispatch, gemm, gemm_in};
    let rows = std::env::var("ROWS").ok().and_then(|r| r.parse().ok()).unwrap_or(20512);
    println!("{rows} rows:");
    let a: Vec<f32> = (0..rows * 64).map(|i| ((i * 7919) % 2000) as f32 / 1000.0 - 1.0).collect();
    let wt: Vec<f32> = (0..64 * 64).map(|i| ((i * 31) % 100) as f32 / 100.0 - 0.5).collect();
    let bias = vec![0.01f32; 64];
    let mut y = vec![0.0f32; rows * 64];
    let mut d = vec![0.0f32; rows * 64];
    let flop = 2.0 * (rows * 64 * 64) as f64;
    let mut right = vec![0u32; 32 * 64];
    sdf_backbone::kernels::bf16::pack_right(&wt, 64, 64, 64, &mut right);
    let packed = sdf_backbone::kernels::bf16::Pairs { left: &a, stride: 64, k: 64, right: &right, n: 64 };
    let in_bf16 = if sdf_backbone::kernels::bf16::available() { vec![None, Some(packed)] } else { vec![None] };
    for (act, pairs) in
        [Activation::Identity, Activation::Relu, Activation::Softplus { beta: 100.0 }].into_iter().flat_map(|a| in_bf16.iter().map(move |p| (a, *p)))
    {
        for keep in [true, false] {
            let t = best(|| {
                dispatch(
                    #[inline(always)]
                    || {
                        dense_forward(
                            &Dense { a: &a, a_s: 64, n_in: 64, wt: &wt, bias: &bias, n_out_pad: 64, act, scale: 1.0, pairs },
                            &mut y,
                            64,
                            0,
                            keep.then_some(&mut d[..]),
                            rows,
                        )
                    },
                )
            });
            let products = if pairs.is_some() { "bf16" } else { "f32" };
            let slopes = if keep { "slopes kept" } else { "no slopes" };
            println!("dense_forward 64 → 64, {act:?}, {products}, {slopes}: {:.2} ms = {:.1} GFLOP/s", t * 1e3, flop / t / 1e9);
        }
    }
    let mut c = vec![0.0f32; rows * 64];
    let t = best(|| {
        dispatch(
            #[inline(always)]
            || gemm(&mut c, 64, Strided { data: &a, sm: 64, sk: 1 }, &wt, 64, rows, 64, 64, false),
        )
    });
    println!("gemm rows × 64 · 64 × 64: {:.2} ms = {:.1} GFLOP/s", t * 1e3, flop / t / 1e9);
    let mut dw = vec![0.0f32; 64 * 64];
    let t = best(|| {
        dispatch(
            #[inline(always)]
            || gemm(&mut dw, 64, Strided { data: &a, sm: 1, sk: 64 }, &a, 64, 64, 64, rows, false),
        )
    });
    println!("gemm (dW) 64 × rows · rows × 64: {:.2} ms = {:.1} GFLOP/s", t * 1e3, flop / t / 1e9);
    for (name, sm, sk, m, k) in [
        ("bf16 gemm rows × 64 · 64 × 64 (packing included)", 64, 1, rows, 64),
        ("bf16 gemm (dW, exact: L column-major) 64 × rows · rows × 64", 1, 64, 64, rows),
    ] {
        let (out, b) = if m == rows { (&mut c, &wt[..]) } else { (&mut dw, &a[..]) };
        let t = best(|| {
            dispatch(
                #[inline(always)]
                || gemm_in(true, out, 64, Strided { data: &a, sm, sk }, b, 64, m, 64, k, false),
            )
        });
        println!("{name}: {:.2} ms = {:.1} GFLOP/s", t * 1e3, flop / t / 1e9);
    }
}

/// Softplus alone over an array, inside the dispatch.
#[allow(dead_code)]
fn softplus_speed() {
    use sdf_backbone::kernels::dispatch;
    let z: Vec<f32> = (0..1 << 20).map(|i| ((i * 7919) % 2000) as f32 / 1000.0 - 1.0).collect();
    let mut y = vec![0.0f32; z.len()];
    let mut d = vec![0.0f32; z.len()];
    let t = best(|| {
        dispatch(
            #[inline(always)]
            || {
                for ((zi, yi), di) in z.iter().zip(y.iter_mut()).zip(d.iter_mut()) {
                    let (a, b) = zi.softplus_with_derivative(100.0);
                    *yi = a;
                    *di = b;
                }
            },
        )
    });
    println!("softplus over 2^20 values: {:.2} ns per value", t * 1e9 / z.len() as f64);
}
