"""The guided sampler in a PyTorch backbone that is not psneus's: a small NeuS on the CPU.

The loop a researcher would write around their own network: the estimator's `update` reads the
network's SDF (under torch.no_grad), `draw` gives each step's rays (pixel, origin, direction and,
for guided rays, the depth λ̃ where the surface is likely), the network renders them with NeuS's
discrete opacity, and the mesh is scored by `evaluate_mesh` against the scene's truth. Guided and
uniform train for the same wall time; one line each per seed.

    pip install ./python torch
    python python/examples/torch_neus.py                 # 60 s per run, seeds 0 1 2
    python python/examples/torch_neus.py --seconds 30 --seeds 0
"""

import argparse
import math
import time

import numpy as np
import torch
import torch.nn.functional as F

import psneus

COARSE = 32  # stratified samples per ray
EXTRA = 16  # guided rays: points around λ̃; uniform rays: more stratified ones


class NeuS(torch.nn.Module):
    """SDF = |x| − 0.5 + MLP(x) (a sphere at the start, as NeuS's geometric init), colour MLP."""

    def __init__(self, frequencies=6, width=64, feature=16):
        super().__init__()
        self.frequencies = frequencies
        encoded = 3 + 6 * frequencies
        self.sdf_net = torch.nn.Sequential(
            torch.nn.Linear(encoded, width), torch.nn.Softplus(beta=100),
            torch.nn.Linear(width, width), torch.nn.Softplus(beta=100),
            torch.nn.Linear(width, 1 + feature),
        )
        torch.nn.init.zeros_(self.sdf_net[-1].weight)
        torch.nn.init.zeros_(self.sdf_net[-1].bias)
        self.color_net = torch.nn.Sequential(
            torch.nn.Linear(encoded + 3 + feature, width), torch.nn.ReLU(),
            torch.nn.Linear(width, 3), torch.nn.Sigmoid(),
        )
        # s = exp(10 · v): NeuS's learnt logistic scale, 20 at the start.
        self.log_s = torch.nn.Parameter(torch.tensor(math.log(20.0) / 10.0))

    def encode(self, x):
        bands = [x]
        for k in range(self.frequencies):
            bands += [torch.sin((2.0**k) * math.pi * x), torch.cos((2.0**k) * math.pi * x)]
        return torch.cat(bands, -1)

    def sdf_and_feature(self, x):
        out = self.sdf_net(self.encode(x))
        return out[..., 0] + x.norm(dim=-1) - 0.5, out[..., 1:]

    def s(self):
        return torch.exp(10.0 * self.log_s)


def sample_depths(rays, guided, generator):
    """Per ray: COARSE + 1 stratified depths (the estimator's) and EXTRA more."""
    coarse = torch.from_numpy(rays["coarse_depths"])
    near, far = torch.from_numpy(rays["near"])[:, None], torch.from_numpy(rays["far"])[:, None]
    uniform_extra = near + (far - near) * torch.rand(len(near), EXTRA, generator=generator)
    if not guided:
        return torch.sort(torch.cat([coarse, uniform_extra], 1), 1).values
    depth = torch.from_numpy(rays["depth"])[:, None]
    spread = torch.from_numpy(rays["depth_bin"])[:, None]
    has_surface = torch.from_numpy(~rays["background"])[:, None]
    # The paper's extra points: a Gaussian around λ̃, widened to λ̃'s own resolution.
    around = depth + spread * torch.randn(len(near), EXTRA, generator=generator)
    extra = torch.where(has_surface, around.clamp(near, far), uniform_extra)
    return torch.sort(torch.cat([coarse, extra], 1), 1).values


def render(model, origin, direction, t):
    """NeuS's discrete opacity between consecutive samples; colour at section midpoints."""
    points = origin[:, None] + direction[:, None] * t[..., None]
    sdf, _ = model.sdf_and_feature(points)
    s = model.s()
    cdf = torch.sigmoid(s * sdf)
    alpha = ((cdf[:, :-1] - cdf[:, 1:]) / (cdf[:, :-1] + 1e-5)).clamp(0.0, 1.0)
    transmittance = torch.cumprod(torch.cat([torch.ones_like(alpha[:, :1]), 1.0 - alpha + 1e-7], 1), 1)[:, :-1]
    weights = alpha * transmittance
    mid = origin[:, None] + direction[:, None] * (0.5 * (t[:, 1:] + t[:, :-1]))[..., None]
    _, feature = model.sdf_and_feature(mid)
    view = direction[:, None].expand_as(mid)
    color = model.color_net(torch.cat([model.encode(mid), view, feature], -1))
    return (weights[..., None] * color).sum(1), weights.sum(1)


def train(scene, sampler, seed, seconds, rays_per_step=256):
    torch.manual_seed(seed)
    generator = torch.Generator().manual_seed(seed)
    model = NeuS()
    optimizer = torch.optim.Adam(model.parameters(), lr=5e-3)
    estimator = psneus.Estimator(scene, sampler=sampler)
    images = torch.from_numpy(np.stack([scene.image(i) for i in range(len(scene))]))
    masks = torch.from_numpy(np.stack([scene.mask(i) for i in range(len(scene))])).float()

    def sdf(points):
        with torch.no_grad():
            return model.sdf_and_feature(torch.from_numpy(points))[0].numpy()

    start, step, update_seconds = time.perf_counter(), 0, 0.0
    while (elapsed := time.perf_counter() - start) < seconds:
        progress = elapsed / seconds
        if sampler == "guided":
            t0 = time.perf_counter()
            estimator.update_due(progress, sdf, float(model.s().detach()))
            update_seconds += time.perf_counter() - t0
        rays = estimator.draw(rays_per_step, seed=seed, step=step, progress=progress, coarse=COARSE)
        t = sample_depths(rays, sampler == "guided", generator)
        origin, direction = torch.from_numpy(rays["origin"]), torch.from_numpy(rays["direction"])
        view = torch.from_numpy(rays["view"])
        col, row = (torch.from_numpy(rays["pixel"]).long()).unbind(1)
        color, opacity = render(model, origin, direction, t)
        mask = masks[view, row, col]
        target = images[view, row, col] * mask[:, None]
        eikonal_points = torch.rand(1024, 3, generator=generator) * 2.0 - 1.0
        eikonal_points.requires_grad_(True)
        eikonal_sdf, _ = model.sdf_and_feature(eikonal_points)
        (gradient,) = torch.autograd.grad(eikonal_sdf.sum(), eikonal_points, create_graph=True)
        loss = (
            (color - target).abs().mean()
            + 0.1 * ((gradient.norm(dim=-1) - 1.0) ** 2).mean()
            + 0.1 * F.binary_cross_entropy(opacity.clamp(1e-3, 1 - 1e-3), mask)
        )
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        step += 1
    vertices, faces = psneus.extract_mesh(sdf, resolution=128)
    metrics = psneus.evaluate_mesh((vertices, faces), gt_points=scene.ground_truth(), spacing=0.004, max_dist=0.1, tau=0.01)
    return step, update_seconds, metrics


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0, help="training time per run")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--width", type=int, default=100, help="built-in scene's image width")
    parser.add_argument("--threads", type=int, default=2, help="torch threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    scene = psneus.load_scene(builtin={"width": args.width})
    print(f"{scene.description}; {args.seconds:.0f} s per run")
    results = {}
    for sampler in ("guided", "uniform"):
        for seed in args.seeds:
            steps, update_seconds, m = train(scene, sampler, seed, args.seconds)
            results.setdefault(sampler, []).append(m["chamfer"])
            print(
                f"{sampler:8s} seed {seed}: {steps} steps ({update_seconds:.1f} s in guide updates), "
                f"Chamfer {m['chamfer']:.4f} (accuracy {m['accuracy']:.4f}, completeness {m['completeness']:.4f}), F-score {m['fscore']:.3f}"
            )
    for sampler, chamfers in results.items():
        spread = np.std(chamfers, ddof=1) if len(chamfers) > 1 else 0.0
        print(f"{sampler:8s} Chamfer {np.mean(chamfers):.4f} ± {spread:.4f} (sample std) over {len(chamfers)} seed(s)")


if __name__ == "__main__":
    main()
