//! What the integration tests share.

/// A tiny guided run: 6 iterations on a 40 × 30 built-in scene, small grids and mesh,
/// checkpoints every 2 iterations.
pub const TINY: &[&str] = &[
    "steps=6",
    "render.rays=32",
    "render.coarse=8",
    "render.fine=8",
    "guide.extra_points=4",
    "data.builtin.width=40",
    "output.mesh_resolution=24",
    "output.validate_every=0",
    "output.checkpoint_every=2",
    "output.eval_views=1",
    "output.validate_downscale=4",
    "guide.updates=3",
    "guide.scene.resolution=16",
    "guide.camera.ru=8",
    "guide.camera.rv=8",
    "guide.camera.rl=16",
];
