#!/usr/bin/env python3
"""PyTorch-CPU peer of psneus's default backbone training step, for a side-by-side benchmark.

What: the same model and training step as the Rust backbone's default preset
(`sdf_backbone::build(Preset::NeuralangeloCpu, ..)`, run by `cargo xtask bench backbone`) written
in plain PyTorch on the CPU, timed per step. The Rust sources are the ground truth:
`crates/sdf-backbone/src/{backbone,hashgrid,encoding,mlp,pipeline,render,optim}.rs` and the
benchmark's rays in `xtask/src/bench_backbone.rs`.

Requirements: Python 3.9+, `pip install torch numpy` (CPU wheels suffice). This script is a peer
for benchmarking only: it is NOT run by CI and nothing in the Rust workspace depends on it.

Memory allocator: glibc's malloc hands large blocks (every big tensor of a step) back to the OS
when they are freed and maps fresh, zeroed pages for them on the next step, so an eager PyTorch
step pays page faults the Rust code does not. For an honest ratio the runner must start Python
with

    MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=100000000000 python scripts/torch_peer.py ...

(glibc reads them at process start; the script cannot set them for itself). Each figure reports
`malloc_tuned` (both variables set so) and a warning goes to stderr when they are not;
`--tune-malloc` sets them for the per-figure child processes instead.

Usage:
    python scripts/torch_peer.py [--threads 2] [--rays 512] [--samples 128] [--reps 5]
        [--variants all|central,tetrahedral,autograd] [--modes eager,compile] [--quick]

Output: one JSON object per line on stdout (everything else goes to stderr):
  * `{"figure": "torch_check", ...}`: a self-check (autograd gradient of the SDF vs tetrahedral
    differences at a small step, in f64; loss and gradient finite for every normal scheme).
  * `{"figure": "torch_step", ...}` per (normals, mode): median and min seconds of one training
    step = forward + backward of the whole loss + the Adam update (`step_s`, `step_min_s`), and
    the same split into forward + backward (`fwd_bwd_s`) and the Adam update (`adam_s`);
    `cargo xtask bench backbone` compares `step_s` with its own step, Adam included. On failure or timeout (e.g. torch.compile
    and double backward) the figure carries an `"error"` field instead of times.
Each figure runs in its own child process (clean compile state, honest per-figure peak RSS);
warm-up steps (compilation included) are not timed. `warmup_s` includes compilation, which
TorchInductor caches on disk between runs (/tmp/torchinductor_$USER): for a cold compile time
set `TORCHINDUCTOR_CACHE_DIR=$(mktemp -d)`. torch.compile cannot differentiate its own backward
(double backward), so `autograd` / `compile` reports an error figure.

The model (preset neuralangelo-cpu, 795 254 parameters):
  * SDF network: [x, HashGrid(x)] (3 + 8·2 = 19) → 64 → 16 (SDF + 15 features), softplus
    β = 100 (linear where βz > 20). Hash grid: 8 levels × 2 features, 2^16 entries per level,
    resolutions ⌊16·b^l + 1e-9⌋ with b = 16^(1/7) (16, 23, 35, 52, 78, 115, 172, 256), dense
    indexing where (N+1)³ ≤ 2^16 (the first three levels, whose tables hold their (N+1)³
    vertices), else the hash (i ^ j·2654435761 ^ k·805459861) mod 2^16 on u32; x ∈ [−1, 1] maps
    to p = (x+1)/2·N, clamped to [0, N] (zero gradient where clamped), its cell to N − 1;
    trilinear interpolation.
  * Colour network: [x, n, SH₄(d), features] (3 + 3 + 16 + 15 = 37) → 64 → 64 → 3, ReLU, sigmoid.
  * Normals: central (6 probes x ± h e_k), tetrahedral (4 probes x + h v_j) with h = 1/256
    (1 / the finest resolution), or autograd (∇S by torch.autograd.grad with create_graph=True,
    a double backward; the SDF is then evaluated at the samples only, no probes).
  * NeuS rendering at s = exp(10 v) (v learnt, 0.3 at init): α = max(1 − Φ(sS_{i+1})/Φ(sS_i), 0)
    via softplus, T_i = Π_{j<i}(1 − α_j), w = αT; colour Σ w c composited over a black background.
  * Loss per ray, averaged over rays: L1 colour (summed over channels) + 0.1 · mean (|n| − 1)² +
    0.1 · BCE(clamp(opacity, 1e-3, 1 − 1e-3), mask).
  * Adam (β = 0.9, 0.999, ε = 1e-8), hash tables lr 1e-2, everything else (MLPs, v) lr 5e-3.
"""

import argparse
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import time

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

PRESET = "neuralangelo-cpu"
RUST_PARAMS = 795254  # `cargo xtask bench backbone` for neuralangelo-cpu
GRID = dict(levels=8, features=2, log2_table=16, base_resolution=16, finest_resolution=256)
SDF_HIDDEN = [64]
COLOUR_HIDDEN = [64, 64]
N_FEATURES = 15  # geometry features after the SDF value
SOFTPLUS_BETA = 100.0
EIKONAL_WEIGHT = 0.1
MASK_WEIGHT = 0.1
BACKGROUND = (0.0, 0.0, 0.0)
LR_GRID, LR_REST = 1e-2, 5e-3
MALLOC_ENV = {"MALLOC_MMAP_MAX_": "0", "MALLOC_TRIM_THRESHOLD_": "100000000000"}

# Probe offsets (units of h) and their weight in n per unit h (pipeline.rs `NormalScheme::probes`).
PROBES = {
    "central": ([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], 0.5),
    "tetrahedral": ([[1, -1, -1], [-1, -1, 1], [-1, 1, -1], [1, 1, 1]], 0.25),
}


def log(*a):
    print(*a, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------------------------
# Model


class HashGrid(nn.Module):
    """hashgrid.rs `HashGrid`: L tables of min(T, (N_l + 1)³) × F features (one parameter, level
    after level as the Rust flat buffer), output the L·F interpolated features, level-major."""

    P1, P2 = 2654435761, 805459861

    def __init__(self, levels, features, log2_table, base_resolution, finest_resolution):
        super().__init__()
        self.L, self.F, self.T = levels, features, 1 << log2_table
        lo, hi = float(max(base_resolution, 1)), float(max(finest_resolution, 1))
        growth = math.exp((math.log(hi) - math.log(lo)) / (levels - 1)) if levels > 1 else 1.0
        self.resolutions = [max(int(math.floor(lo * growth**l + 1e-9)), 1) for l in range(levels)]
        self.dense = [(n + 1) ** 3 <= self.T for n in self.resolutions]
        # Resolutions grow, so the dense levels are a prefix.
        self.n_dense = sum(self.dense)
        assert all(self.dense[: self.n_dense]) and not any(self.dense[self.n_dense :])
        # A dense level's table holds its (N + 1)³ vertices (tiny-cuda-nn's layout, as in Rust).
        sizes = [(n + 1) ** 3 if d else self.T for n, d in zip(self.resolutions, self.dense)]
        offsets = np.concatenate([[0], np.cumsum(sizes)])
        self.table = nn.Parameter(torch.empty(int(offsets[-1]), self.F).uniform_(-1e-4, 1e-4))
        res32 = np.array(self.resolutions, dtype=np.float32)
        # Rust: R::of(n as f64 * 0.5); p clamped to [0, N], its cell to N − 1 (the last cell is
        # closed: p = N is its far face).
        self.register_buffer("scale", torch.from_numpy((res32 * np.float32(0.5)).reshape(1, -1, 1)), persistent=False)
        self.register_buffer("upper", torch.from_numpy(res32.reshape(1, -1, 1)), persistent=False)
        self.register_buffer("last", torch.from_numpy((res32 - np.float32(1.0)).reshape(1, -1, 1)), persistent=False)
        self.register_buffer("lower", torch.zeros(1, self.L, 1), persistent=False)
        nd = torch.tensor([n + 1 for n in self.resolutions[: self.n_dense]], dtype=torch.int64)
        self.register_buffer("dense_stride", nd.reshape(1, -1), persistent=False)
        bits = torch.tensor([[c & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], dtype=torch.int64)
        self.register_buffer(
            "dense_corner",
            (bits[None, :, 0] + nd[:, None] * (bits[None, :, 1] + nd[:, None] * bits[None, :, 2])).reshape(1, -1, 8),
            persistent=False,
        )
        self.register_buffer("level_base", torch.from_numpy(offsets[:-1].astype(np.int64)).reshape(1, -1, 1), persistent=False)
        self.register_buffer("unit", torch.tensor([0, 1], dtype=torch.int64), persistent=False)

    def n_outputs(self):
        return self.L * self.F

    def forward(self, x):
        n = x.shape[0]
        raw = (x[:, None, :] + 1.0) * self.scale  # (N, L, 3)
        p = torch.clamp(raw, self.lower, self.upper)  # gradient 0 where clamped, as in Rust
        cell = torch.minimum(torch.floor(p), self.last)
        frac = p - cell  # (floor has zero gradient)
        c = cell.to(torch.int64)
        idx = []
        if self.n_dense:
            cd = c[:, : self.n_dense]
            s = self.dense_stride
            base = cd[..., 0] + s * (cd[..., 1] + s * cd[..., 2])
            idx.append(base[..., None] + self.dense_corner)
        if self.n_dense < self.L:
            ch = c[:, self.n_dense :]
            u = self.unit
            h0 = ch[..., 0:1] + u  # (N, Lh, 2): i·1
            h1 = (ch[..., 1:2] + u) * self.P1
            h2 = (ch[..., 2:3] + u) * self.P2
            # u32 wrap-around then mod T is the low log2(T) bits of the int64 result.
            mask = (self.T - 1) & 0xFFFFFFFF
            hashed = (h2[..., :, None, None] ^ h1[..., None, :, None] ^ h0[..., None, None, :]) & mask
            idx.append(hashed.reshape(n, self.L - self.n_dense, 8))
        idx = torch.cat(idx, dim=1) + self.level_base  # (N, L, 8), corner c = bx + 2 by + 4 bz
        one = 1.0 - frac
        wx = torch.stack([one[..., 0], frac[..., 0]], -1)
        wy = torch.stack([one[..., 1], frac[..., 1]], -1)
        wz = torch.stack([one[..., 2], frac[..., 2]], -1)
        w = (wx[..., None, None, :] * wy[..., None, :, None] * wz[..., :, None, None]).reshape(n, self.L, 8)
        vals = self.table.index_select(0, idx.reshape(-1)).reshape(n, self.L, 8, self.F)
        return (vals * w[..., None]).sum(2).reshape(n, self.L * self.F)


class Mlp(nn.Module):
    """mlp.rs `Mlp` without skip: Linear (W out × in, as Rust) + hidden activation, output
    activation last."""

    def __init__(self, n_in, hidden, n_out, hidden_act, out_act):
        super().__init__()
        sizes = [n_in] + hidden + [n_out]
        self.layers = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes[:-1], sizes[1:]))
        self.hidden_act, self.out_act = hidden_act, out_act

    def forward(self, x):
        for layer in self.layers[:-1]:
            x = self.hidden_act(layer(x))
        return self.out_act(self.layers[-1](x))


def softplus100(z):
    # module.rs: ln(1 + e^{βz})/β, exactly z where βz > 20 (torch's threshold semantics).
    return F.softplus(z, beta=SOFTPLUS_BETA, threshold=20.0)


class SdfNet(nn.Module):
    """`Chain<WithInput<HashGrid>, Mlp>`: [x, grid(x)] (raw xyz first) → MLP → [SDF, features]."""

    def __init__(self):
        super().__init__()
        self.grid = HashGrid(**GRID)
        self.mlp = Mlp(3 + self.grid.n_outputs(), SDF_HIDDEN, 1 + N_FEATURES, softplus100, lambda z: z)

    def forward(self, x):
        return self.mlp(torch.cat([x, self.grid(x)], dim=-1))


class Model(nn.Module):
    """pipeline.rs `Pipeline`: SDF net, colour net, the variance v (s = exp(10 v))."""

    def __init__(self):
        super().__init__()
        self.sdf = SdfNet()
        self.colour = Mlp(3 + 3 + 16 + N_FEATURES, COLOUR_HIDDEN, 3, torch.relu, torch.sigmoid)
        self.variance = nn.Parameter(torch.tensor(0.3))
        # h = 1/N of the finest level (backbone.rs `build`: 1 / resolutions().last()).
        self.normal_step = 1.0 / self.sdf.grid.resolutions[-1]

    def init_like_rust(self, radius=0.5, seed=1):
        """Shapes and scales as `build` (hash ±1e-4, SDF MLP geometric init with silent encoded
        inputs, colour He, v = 0.3), without its least-squares readout calibration and sphere fit
        (timing does not depend on them; the SDF is still ≈ |x| − r)."""
        g = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            self.sdf.grid.table.uniform_(-1e-4, 1e-4, generator=g)
            layers = self.sdf.mlp.layers
            for l, lin in enumerate(layers):
                n_out, n_in = lin.weight.shape
                if l == len(layers) - 1:
                    lin.weight.normal_(math.sqrt(math.pi) / math.sqrt(n_in), 1e-4, generator=g)
                    lin.bias.zero_()
                    lin.bias[0] = -radius
                else:
                    lin.weight.normal_(0.0, math.sqrt(2.0) / math.sqrt(n_out), generator=g)
                    if l == 0:
                        lin.weight[:, 3:] = 0.0
                    lin.bias.zero_()
            for lin in self.colour.layers:
                lin.weight.normal_(0.0, math.sqrt(2.0 / lin.weight.shape[1]), generator=g)
                lin.bias.zero_()
            self.variance.fill_(0.3)
        return self


def sh16(d):
    """encoding.rs `sh16`: the 16 real SH basis functions (degree 4 in tiny-cuda-nn's sense)."""
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    xx, yy, zz = x * x, y * y, z * z
    return torch.stack(
        [
            torch.full_like(x, 0.28209479177387814),
            -0.4886025119029199 * y,
            0.4886025119029199 * z,
            -0.4886025119029199 * x,
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.9461746957575601 * zz - 0.31539156525252005,
            -1.0925484305920792 * x * z,
            0.5462742152960396 * (xx - yy),
            0.5900435899266435 * y * (-3.0 * xx + yy),
            2.890611442640554 * x * y * z,
            0.4570457994644658 * y * (1.0 - 5.0 * zz),
            0.3731763325901154 * z * (5.0 * zz - 3.0),
            0.4570457994644658 * x * (1.0 - 5.0 * zz),
            1.445305721320277 * z * (xx - yy),
            0.5900435899266435 * x * (-xx + 3.0 * yy),
        ],
        dim=-1,
    )


def probe_matrices(normals, dtype=torch.float32):
    offsets, weight = PROBES[normals]
    off = torch.tensor(offsets, dtype=dtype)
    return off, off * weight  # probe offsets (np, 3); n = (S_probes @ W) / h


def sdf_and_normals(model, pts, normals, h, probe_off=None, probe_w=None):
    """SDF outputs at the n + 1 samples per ray and the normals at the first n of them.
    pts: (R, n+1, 3). Returns (S (R, n+1), features (R, n, F), normals (R, n, 3))."""
    R, n1, _ = pts.shape
    n = n1 - 1
    if normals == "autograd":
        x = pts.reshape(-1, 3)
        if not x.requires_grad:
            x = x.detach().requires_grad_(True)
        out = model.sdf(x)
        s_all = out[:, 0]
        (g,) = torch.autograd.grad(s_all, x, grad_outputs=torch.ones_like(s_all), create_graph=True)
        out = out.reshape(R, n1, -1)
        nrm = g.reshape(R, n1, 3)[:, :n]
    else:
        np_ = probe_off.shape[0]
        probes = pts[:, :n, None, :] + probe_off * h  # (R, n, np, 3)
        out_all = model.sdf(torch.cat([pts.reshape(-1, 3), probes.reshape(-1, 3)], dim=0))
        out = out_all[: R * n1].reshape(R, n1, -1)
        s_probe = out_all[R * n1 :, 0].reshape(R, n, np_)
        nrm = (s_probe @ probe_w) / h
    return out[..., 0], out[:, :n, 1:], nrm


def loss_fn(model, normals, origins, dirs, depths, targets, masks, probe_off=None, probe_w=None):
    """pipeline.rs `Pipeline::accumulate` (no curvature, fixed background, no sample loss):
    the mean over rays of L1 colour + eikonal + mask BCE."""
    R, n1 = depths.shape
    n = n1 - 1
    h = model.normal_step
    pts = origins[:, None, :] + depths[..., None] * dirs[:, None, :]  # (R, n+1, 3)
    S, feat, nrm = sdf_and_normals(model, pts, normals, h, probe_off, probe_w)
    sh = sh16(dirs)[:, None, :].expand(R, n, 16)
    rgb = model.colour(torch.cat([pts[:, :n], nrm, sh, feat], dim=-1))  # (R, n, 3)
    s = torch.exp(10.0 * model.variance)
    # render.rs: ln(Φ(b)/Φ(a)) = softplus(−a) − softplus(−b); α = 1 − ratio, 0 (no gradient)
    # where the ratio is ≥ 1.
    log_ratio = F.softplus(-s * S[:, :-1]) - F.softplus(-s * S[:, 1:])
    alpha = 1.0 - torch.exp(torch.clamp(log_ratio, max=0.0))
    trans = torch.cat([torch.ones_like(alpha[:, :1]), torch.cumprod(1.0 - alpha, dim=1)[:, :-1]], dim=1)
    w = alpha * trans
    colour = (w[..., None] * rgb).sum(1)
    opacity = w.sum(1)
    bg = torch.tensor(BACKGROUND, dtype=colour.dtype)
    composited = colour + (1.0 - opacity)[:, None] * bg
    l1 = (composited - targets).abs().sum(-1)
    eik = EIKONAL_WEIGHT * ((torch.linalg.vector_norm(nrm, dim=-1) - 1.0) ** 2).mean(1)
    o = torch.clamp(opacity, 1e-3, 1.0 - 1e-3)
    bce = -MASK_WEIGHT * (masks * torch.log(o) + (1.0 - masks) * torch.log(1.0 - o))
    return (l1 + eik + bce).mean()


def bench_rays(n_rays, n_samples):
    """xtask/src/bench_backbone.rs `rays`, in f32 as there."""
    r = np.arange(n_rays, dtype=np.float32)
    a = r * np.float32(0.01)
    ca, sa = np.cos(a), np.sin(a)
    d = np.stack([-ca, -sa, np.full_like(a, -0.1)], -1).astype(np.float32)
    length = np.sqrt((d * d).sum(-1, dtype=np.float32)).astype(np.float32)
    d = d * (np.float32(1.0) / length)[:, None]  # glam: self * (1 / |self|)
    o = np.stack([np.float32(3.0) * ca, np.float32(3.0) * sa, np.full_like(a, 0.3)], -1).astype(np.float32)
    i = np.arange(n_samples + 1, dtype=np.float32)
    t = np.float32(2.0) + np.float32(2.0) * i / np.float32(n_samples)
    t = np.broadcast_to(t, (n_rays, n_samples + 1)).astype(np.float32)
    target = np.broadcast_to(np.array([0.5, 0.4, 0.3], dtype=np.float32), (n_rays, 3)).copy()
    mask = np.ones(n_rays, dtype=np.float32)
    return tuple(torch.from_numpy(np.ascontiguousarray(v)) for v in (o, d, t, target, mask))


def make_optimizer(model, kind):
    grid = [model.sdf.grid.table]
    rest = [p for name, p in model.named_parameters() if name != "sdf.grid.table"]
    kw = dict(betas=(0.9, 0.999), eps=1e-8)
    if kind == "fused":
        kw["fused"] = True
    elif kind == "foreach":
        kw["foreach"] = True
    else:
        kw["foreach"] = False
    return torch.optim.Adam([{"params": grid, "lr": LR_GRID}, {"params": rest, "lr": LR_REST}], **kw)


# ----------------------------------------------------------------------------------------------
# Figures


def malloc_tuned():
    try:
        return os.environ.get("MALLOC_MMAP_MAX_") == "0" and int(os.environ.get("MALLOC_TRIM_THRESHOLD_", "0")) >= 10**9
    except ValueError:
        return False


def peak_rss_mb():
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def n_params(model):
    return sum(p.numel() for p in model.parameters())


def base_figure(args, normals, mode, model=None):
    model = model or Model()
    grid = model.sdf.grid
    return {
        "figure": "torch_step",
        "preset": PRESET,
        "levels": GRID["levels"],
        "features_per_level": GRID["features"],
        "log2_table_size": GRID["log2_table"],
        "base_resolution": GRID["base_resolution"],
        "max_resolution": GRID["finest_resolution"],
        "resolutions": grid.resolutions,
        "dense_levels": grid.n_dense,
        "sdf_hidden": SDF_HIDDEN,
        "colour_hidden": COLOUR_HIDDEN,
        "normals": normals,
        "normal_step": model.normal_step,
        "mode": mode,
        "rays": args.rays,
        "samples": args.samples,
        "params": n_params(model),
        "params_match_rust": n_params(model) == RUST_PARAMS,
        "threads": args.threads,
        "torch_version": torch.__version__,
        "adam": args.adam,
        "malloc_tuned": malloc_tuned(),
    }


def run_figure(args, normals, mode):
    torch.manual_seed(0)
    model = Model().init_like_rust()
    fig = base_figure(args, normals, mode, model)
    opt = make_optimizer(model, args.adam)
    rays = bench_rays(args.rays, args.samples)
    probe_off, probe_w = probe_matrices(normals) if normals != "autograd" else (None, None)

    def compute(*r):
        return loss_fn(model, normals, *r, probe_off=probe_off, probe_w=probe_w)

    if mode == "compile":
        compute = torch.compile(compute, dynamic=False)

    def step():
        t0 = time.perf_counter()
        opt.zero_grad(set_to_none=True)
        loss = compute(*rays)
        loss.backward()
        t1 = time.perf_counter()
        opt.step()
        t2 = time.perf_counter()
        return loss.item(), t1 - t0, t2 - t1

    t = time.perf_counter()
    first = None
    losses = []
    try:
        for i in range(args.warmup):
            loss, a, b = step()
            losses.append(loss)
            if first is None:
                first = a + b
    except Exception as e:  # noqa: BLE001 (compile failures of any kind become a figure)
        msg = f"{type(e).__name__}: {e}".strip().splitlines()
        fig["error"] = " ".join(msg[:3])[:600]
        fig["peak_rss_mb"] = peak_rss_mb()
        return fig
    fig["warmup_s"] = time.perf_counter() - t
    fig["first_step_s"] = first
    fwd_bwd, adam, total = [], [], []
    for _ in range(args.reps):
        loss, a, b = step()
        losses.append(loss)
        fwd_bwd.append(a)
        adam.append(b)
        total.append(a + b)
    step_s = statistics.median(total)
    fig.update(
        {
            "step_s": step_s,
            "step_min_s": min(total),
            "fwd_bwd_s": statistics.median(fwd_bwd),
            "fwd_bwd_min_s": min(fwd_bwd),
            "adam_s": statistics.median(adam),
            "samples_per_s": args.rays * args.samples / step_s,
            "reps": args.reps,
            "warmup_steps": args.warmup,
            "loss_first": losses[0],
            "loss_last": losses[-1],
            "loss_finite": all(math.isfinite(v) for v in losses),
            "peak_rss_mb": peak_rss_mb(),
        }
    )
    return fig


def hash_grid_reference(grid, table, x):
    """hashgrid.rs `HashGrid::forward` point by point in numpy f32 (u32 arithmetic for the hash):
    the vectorised torch version is checked against it."""
    base = grid.level_base.reshape(-1).tolist()
    out = np.zeros((x.shape[0], grid.L * grid.F), dtype=np.float32)
    for r, pt in enumerate(x.astype(np.float32)):
        for level, n in enumerate(grid.resolutions):
            scale = np.float32(n * 0.5)
            cell, frac = [0, 0, 0], [np.float32(0)] * 3
            for d in range(3):
                raw = (pt[d] + np.float32(1.0)) * scale
                p = min(max(raw, np.float32(0.0)), np.float32(n))
                c = min(math.floor(float(p)), n - 1)
                cell[d], frac[d] = c, np.float32(p - np.float32(c))
            for c in range(8):
                bit = [c & 1, (c >> 1) & 1, (c >> 2) & 1]
                v = [cell[d] + bit[d] for d in range(3)]
                if grid.dense[level]:
                    idx = v[0] + (n + 1) * (v[1] + (n + 1) * v[2])
                else:
                    h = (v[0] * 1) & 0xFFFFFFFF
                    h ^= (v[1] * 2654435761) & 0xFFFFFFFF
                    h ^= (v[2] * 805459861) & 0xFFFFFFFF
                    idx = h & (grid.T - 1)
                f = [frac[d] if bit[d] else np.float32(1.0) - frac[d] for d in range(3)]
                w = np.float32(f[0] * f[1] * f[2])
                out[r, level * grid.F : (level + 1) * grid.F] += w * table[base[level] + idx]
    return out


def run_check(args):
    """Sanity checks of the wiring, in f64 on 2000 random points of [−0.9, 0.9]³ with a random
    (non-silent) hash grid and MLP: (1) central differences at h = 1e-5 equal the autograd
    gradient of the SDF (O(h²)); (2) tetrahedral differences equal the autograd gradient plus
    their leading error h·(H_yz, H_xz, H_xy) (Hessian by double backward) at h = 1e-6: the
    tetrahedral scheme is first-order accurate, Σⱼ vⱼ (vⱼᵀ H vⱼ) = 8 (H_yz, H_xz, H_xy) because
    v_x v_y v_z = 1 at all four vertices; the rest is O(h²) except where a probe straddles a cell
    face of some level (the trilinear gradient jumps there). (3) In f32 with the benchmark's
    init, the loss and the gradient are finite for every normal scheme and the three losses
    agree closely."""
    t0 = time.perf_counter()
    torch.manual_seed(123)
    fig = {"figure": "torch_check", "preset": PRESET, "torch_version": torch.__version__}
    model = Model().double()
    with torch.no_grad():
        model.sdf.grid.table.uniform_(-0.1, 0.1)
    x = (torch.rand(2000, 3, dtype=torch.float64) * 1.8 - 0.9).requires_grad_(True)
    s = model.sdf(x)[:, 0]
    (g,) = torch.autograd.grad(s.sum(), x, create_graph=True)
    hess = torch.stack([torch.autograd.grad(g[:, k].sum(), x, retain_graph=True)[0] for k in range(3)], 1).detach()
    g = g.detach()
    gn = g.norm(dim=-1).clamp_min(1e-12)
    x = x.detach()

    def differences(scheme, h):
        off, w = probe_matrices(scheme, torch.float64)
        with torch.no_grad():
            sp = model.sdf((x[:, None, :] + off * h).reshape(-1, 3))[:, 0].reshape(-1, off.shape[0])
        return (sp @ w) / h

    def rel(a, b):
        return ((a - b).norm(dim=-1) / gn).numpy()

    central = rel(differences("central", 1e-5), g)
    leading = torch.stack([hess[:, 1, 2], hess[:, 0, 2], hess[:, 0, 1]], -1)
    tetra_1e5 = rel(differences("tetrahedral", 1e-5), g)
    n6 = differences("tetrahedral", 1e-6)
    tetra_1e6 = rel(n6, g)
    tetra_corr = rel(n6, g + 1e-6 * leading)
    fig.update(
        {
            "check_points": int(central.size),
            "grad_norm_median": float(gn.median()),
            "central_vs_autograd_rel_err_median_h1e-5": float(np.median(central)),
            "tetra_vs_autograd_rel_err_median_h1e-5": float(np.median(tetra_1e5)),
            "tetra_vs_autograd_rel_err_median_h1e-6": float(np.median(tetra_1e6)),
            "tetra_vs_autograd_plus_h_offdiag_hessian_rel_err_median_h1e-6": float(np.median(tetra_corr)),
            "tetra_vs_autograd_plus_h_offdiag_hessian_frac_over_1e-6": float((tetra_corr > 1e-6).mean()),
        }
    )
    # The vectorised hash grid against the point-by-point reference, points inside and outside
    # [−1, 1]³ and on its faces (clamping).
    grid = Model().sdf.grid
    with torch.no_grad():
        grid.table.uniform_(-1.0, 1.0)
        pts = torch.rand(300, 3) * 2.4 - 1.2
        pts[:20] = torch.tensor([1.0, -1.0, 0.999999])[torch.randint(0, 3, (20, 3))]
        mine = grid(pts).numpy()
    ref = hash_grid_reference(grid, grid.table.detach().numpy(), pts.numpy())
    fig["hash_grid_vs_reference_max_abs"] = float(np.abs(mine - ref).max())
    gradient_ok = fig["hash_grid_vs_reference_max_abs"] < 1e-5 and (
        float(np.median(central)) < 1e-5 and float(np.median(tetra_corr)) < 1e-7 and float((tetra_corr > 1e-6).mean()) < 0.05
    )
    # Loss and gradients on a small batch of the benchmark's rays, f32, the benchmark's init.
    losses = {}
    finite = True
    rays = bench_rays(64, args.samples)
    for normals in ("central", "tetrahedral", "autograd"):
        torch.manual_seed(0)
        m = Model().init_like_rust()
        po, pw = probe_matrices(normals) if normals != "autograd" else (None, None)
        loss = loss_fn(m, normals, *rays, probe_off=po, probe_w=pw)
        loss.backward()
        losses[normals] = loss.item()
        finite &= math.isfinite(loss.item()) and all(bool(torch.isfinite(p.grad).all()) for p in m.parameters())
    spread = max(losses.values()) - min(losses.values())
    fig.update(
        {
            "loss": losses,
            "loss_and_grad_finite": finite,
            "loss_spread": spread,
            "params": n_params(Model()),
            "params_rust": RUST_PARAMS,
            "ok": bool(gradient_ok and finite and spread < 1e-2 * max(abs(v) for v in losses.values()) and n_params(Model()) == RUST_PARAMS),
            "check_s": time.perf_counter() - t0,
        }
    )
    return fig


# ----------------------------------------------------------------------------------------------
# Driver


def parse_args(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    p.add_argument("--rays", type=int, default=512)
    p.add_argument("--samples", type=int, default=128, help="samples (intervals) per ray; n + 1 depths")
    p.add_argument("--reps", type=int, default=None, help="timed steps per figure (default 5; --quick: 2)")
    p.add_argument("--warmup", type=int, default=None, help="untimed steps first, compile included (default 2; --quick: 1)")
    p.add_argument("--variants", default="all", help="all or a comma list of central,tetrahedral,autograd")
    p.add_argument("--modes", default="eager,compile", help="comma list of eager,compile")
    p.add_argument("--adam", default="fused", choices=["fused", "foreach", "single"], help="torch.optim.Adam implementation")
    p.add_argument("--timeout", type=float, default=600.0, help="seconds per figure (warm-up and compile included) before it is reported as an error")
    p.add_argument("--quick", action="store_true", help="1 warm-up step and 2 timed steps per figure (sizes unchanged)")
    p.add_argument("--no-check", action="store_true", help="skip the torch_check figure")
    p.add_argument("--in-process", action="store_true", help="run figures in this process (no isolation, no timeout; peak RSS cumulative)")
    p.add_argument("--tune-malloc", action="store_true", help="set MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=1e11 for the per-figure child processes")
    p.add_argument("--child", nargs=2, metavar=("NORMALS", "MODE"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.reps is None:
        a.reps = 2 if a.quick else 5
    if a.warmup is None:
        a.warmup = 1 if a.quick else 2
    a.variants = ["central", "tetrahedral", "autograd"] if a.variants == "all" else [v.strip() for v in a.variants.split(",") if v.strip()]
    a.modes = [m.strip() for m in a.modes.split(",") if m.strip()]
    for v in a.variants:
        if v not in ("central", "tetrahedral", "autograd"):
            p.error(f"unknown variant {v!r}")
    for m in a.modes:
        if m not in ("eager", "compile"):
            p.error(f"unknown mode {m!r}")
    return a


def emit(fig):
    print(json.dumps(fig), flush=True)


def child_argv(args, normals, mode):
    argv = [sys.executable, os.path.abspath(__file__), "--threads", str(args.threads), "--rays", str(args.rays),
            "--samples", str(args.samples), "--reps", str(args.reps), "--warmup", str(args.warmup), "--adam", args.adam,
            "--child", normals, mode]
    return argv


def run_isolated(args, normals, mode):
    env = dict(os.environ)
    if args.tune_malloc:
        env.update(MALLOC_ENV)
    t = time.perf_counter()
    try:
        proc = subprocess.run(child_argv(args, normals, mode), stdout=subprocess.PIPE, stderr=None, env=env, timeout=args.timeout, text=True)
    except subprocess.TimeoutExpired:
        fig = base_figure(args, normals, mode)
        fig["malloc_tuned"] = args.tune_malloc or malloc_tuned()
        fig["error"] = f"timed out after {args.timeout:.0f} s (warm-up/compile included)"
        return fig
    figs = []
    for line in proc.stdout.splitlines():
        try:
            obj = json.loads(line)
            if isinstance(obj, dict) and obj.get("figure") == "torch_step":
                figs.append(obj)
                continue
        except json.JSONDecodeError:
            pass
        log(line)
    if figs:
        figs[-1]["figure_wall_s"] = time.perf_counter() - t
        return figs[-1]
    fig = base_figure(args, normals, mode)
    fig["error"] = f"child exited with status {proc.returncode} without a figure"
    return fig


def main(argv=None):
    args = parse_args(argv)
    torch.set_num_threads(args.threads)
    if args.child:
        emit(run_figure(args, *args.child))
        return 0
    if not malloc_tuned() and not args.tune_malloc:
        log("warning: MALLOC_MMAP_MAX_=0 MALLOC_TRIM_THRESHOLD_=100000000000 are not set: glibc returns large tensors to the OS "
            "every step and the eager figures pay page faults (malloc_tuned: false in the JSON)")
    t0 = time.perf_counter()
    if not args.no_check:
        emit(run_check(args))
    for normals in args.variants:
        for mode in args.modes:
            log(f"torch_peer: {normals} / {mode} ...")
            fig = run_figure(args, normals, mode) if args.in_process else run_isolated(args, normals, mode)
            emit(fig)
            if "error" in fig:
                log(f"torch_peer: {normals} / {mode}: {fig['error']}")
            else:
                log(f"torch_peer: {normals} / {mode}: step {fig['step_s']:.3f} s (min {fig['step_min_s']:.3f})")
    log(f"torch_peer: total {time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
