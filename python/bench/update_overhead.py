"""What a Python SDF callback adds to an estimator update (psneus issue 24, item 3).

The same analytic sphere, three ways, on the default 64³ scene grid of the built-in scene, the
three alternating in each round (this machine is shared: noise hits them alike):
- native: `psneus.Sphere`, evaluated in Rust (the update's own cost);
- callback: the same `psneus.Sphere` called from Python per batch (the round trip's cost);
- numpy: a numpy sphere as a researcher's callable would be.
The callback's own time is measured inside it; overhead = update − native − callback's own time.

    python python/bench/update_overhead.py [--rounds 10]
"""

import argparse
import time

import numpy as np

import psneus


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--s", type=float, default=200.0, help="logistic scale of the update")
    args = parser.parse_args()
    scene = psneus.load_scene()
    sphere = psneus.Sphere([0.0, 0.0, 0.0], 0.5)
    estimator = psneus.Estimator(scene)
    inside = {"callback": 0.0, "numpy": 0.0}

    def timed(name, f):
        def call(points):
            t = time.perf_counter()
            out = f(points)
            inside[name] += time.perf_counter() - t
            return out

        return call

    fields = {
        "native": sphere,
        "callback": timed("callback", sphere),
        "numpy": timed("numpy", lambda p: (np.linalg.norm(p, axis=1) - 0.5).astype(np.float32)),
    }
    totals = {k: 0.0 for k in fields}
    queries = {}
    estimator.update(sphere, args.s)  # warm-up
    for r in range(args.rounds):
        for name in list(fields)[r % 3 :] + list(fields)[: r % 3]:
            t = time.perf_counter()
            report = estimator.update(fields[name], args.s)
            totals[name] += time.perf_counter() - t
            queries[name] = report["field_queries"]
    n = args.rounds
    native = totals["native"] / n
    print(f"built-in scene, {len(scene)} views, scene grid 64³, s = {args.s}, {n} rounds; field queries per update {queries['native']}")
    print(f"native (Rust sphere): {1e3 * native:.1f} ms per update")
    for name in ("callback", "numpy"):
        total, own = totals[name] / n, inside[name] / n
        print(
            f"{name:8s}: {1e3 * total:.1f} ms per update = native {1e3 * native:.1f} + the callable's own {1e3 * own:.1f}"
            f" + overhead {1e3 * (total - native - own):.1f} ms ({(total - own) / native:.2f}× native without the callable's time)"
        )


if __name__ == "__main__":
    main()
