"""psneus: the probability-guided sampler for neural implicit surfaces (ECCV 2024) on the CPU.

- ``load_scene(path=None, **options)``: a dataset folder (IDR/DTU, NeRF-synthetic, instant-ngp,
  COLMAP) or the built-in golden scene, as a ``Scene`` (cameras, images, masks, ground truth).
- ``Estimator(scene, **guide_options)``: the guide for any backbone; ``update(sdf, s)`` from a
  Python callable, ``draw(n, seed)`` rays as numpy arrays, ``state()`` / ``restore()``.
- ``train(data=None, budget=None, **overrides)``: the trainer of ``cargo xtask train``.
- ``evaluate_mesh(mesh, gt_points=None, gt_mesh=None, **protocol)``: DTU-protocol Chamfer and
  F-score.
- ``extract_mesh(sdf, resolution=128)``: marching cubes of any SDF callable.
- ``Sphere(center, radius)``: an analytic SDF evaluated in Rust (tests, benchmarks).
- ``default_config()``: every configuration key with its default and description (TOML).
"""

from ._psneus import (
    Estimator,
    Scene,
    Sphere,
    __version__,
    default_config,
    evaluate_mesh,
    extract_mesh,
    load_scene,
    train,
)

__all__ = ["Estimator", "Scene", "Sphere", "__version__", "default_config", "evaluate_mesh", "extract_mesh", "load_scene", "train"]
