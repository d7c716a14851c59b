"""train on the built-in scene for a few steps; evaluate_mesh against known geometry and against
the trainer's own evaluation."""

import numpy as np
import pytest

import psneus

# A few-step run of the built-in scene at a tiny size (seconds).
TINY = {
    "steps": 4,
    "render.rays": 32,
    "render.coarse": 8,
    "render.fine": 8,
    "guide.extra_points": 4,
    "data.builtin.width": 40,
    "output.mesh_resolution": 24,
    "output.validate_every": 0,
    "output.eval_views": 1,
    "output.validate_downscale": 4,
    "guide.updates": 2,
    "guide.scene.resolution": 16,
    "guide.camera.ru": 8,
    "guide.camera.rv": 8,
    "guide.camera.rl": 16,
}


def square(z):
    vertices = np.array([[0, 0, z], [1, 0, z], [1, 1, z], [0, 1, z]], np.float32)
    return vertices, np.array([[0, 1, 2], [0, 2, 3]], np.uint32)


def test_evaluate_mesh_of_two_parallel_squares_is_their_distance(tmp_path):
    # Distances are between surface samples `spacing` apart: δ up to (spacing / δ)² / 2.
    delta, spacing = 0.05, 0.002
    m = psneus.evaluate_mesh(square(0.0), gt_mesh=square(delta), spacing=spacing, max_dist=0.2, tau=0.06)
    for key in ("accuracy", "completeness", "chamfer"):
        assert m[key] == pytest.approx(delta, rel=1e-3)
    assert m["fscore"] == 1.0
    # Parallel faces: their normals agree, whatever the distance; a face across the truth's does not.
    assert m["normal_consistency"] == pytest.approx(1.0, abs=1e-6)
    upright = (np.array([[0, 0, 0], [1, 0, 0], [1, 0, 1], [0, 0, 1]], np.float32), square(0.0)[1])
    assert psneus.evaluate_mesh(upright, gt_mesh=square(delta), spacing=0.01, max_dist=2.0)["normal_consistency"] == pytest.approx(0.0, abs=1e-6)
    assert psneus.evaluate_mesh(square(0.0), gt_mesh=square(delta), spacing=spacing, max_dist=0.2, tau=0.04)["fscore"] == 0.0
    # Beyond the outlier distance nothing counts: an infinite Chamfer.
    assert psneus.evaluate_mesh(square(0.0), gt_mesh=square(delta), spacing=spacing, max_dist=0.01)["chamfer"] == float("inf")
    # The same mesh from a PLY file, and ground-truth points instead of a mesh.
    ply = tmp_path / "square.ply"
    v, f = square(0.0)
    header = f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\nelement face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n"
    ply.write_text(header + "".join(f"{a} {b} {c}\n" for a, b, c in v) + "".join(f"3 {a} {b} {c}\n" for a, b, c in f))
    from_file = psneus.evaluate_mesh(ply, gt_mesh=square(delta), spacing=spacing, max_dist=0.2, tau=0.06)
    assert from_file["chamfer"] == pytest.approx(m["chamfer"], rel=1e-6)
    grid = np.stack(np.meshgrid(np.linspace(0, 1, 201), np.linspace(0, 1, 201)), -1).reshape(-1, 2)
    points = np.hstack([grid, np.full((len(grid), 1), delta)])
    from_points = psneus.evaluate_mesh(ply, gt_points=points, spacing=spacing, max_dist=0.2)
    assert from_points["completeness"] == pytest.approx(delta, rel=1e-3)
    assert from_points["normal_consistency"] is None


def test_evaluate_mesh_bad_input_raises():
    with pytest.raises(OSError, match="missing.ply"):
        psneus.evaluate_mesh("missing.ply", gt_points=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="exactly one"):
        psneus.evaluate_mesh(square(0.0))
    with pytest.raises(ValueError, match="degenerate"):
        psneus.evaluate_mesh(square(0.0), gt_points=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="indexes past"):
        psneus.evaluate_mesh((square(0.0)[0], np.array([[0, 1, 9]])), gt_mesh=square(0.0))


def test_train_a_few_steps_and_evaluate_its_mesh_as_the_trainer_did(tmp_path):
    out = tmp_path / "run"
    metrics = psneus.train(out=out, seed=1, **TINY)
    assert metrics["steps"] == 4 and metrics["sampler"] == "guided"
    assert (out / "metrics.json").exists() and (out / "checkpoint.safetensors").exists()
    assert metrics["mesh"].endswith("mesh.ply")
    # The built-in scene's world is its normalised frame: the trainer's Chamfer is reproduced by
    # evaluate_mesh with the run's protocol on the scene's truth (the mesh sampled afresh).
    truth = psneus.load_scene(builtin={"width": 40}).ground_truth()
    m = psneus.evaluate_mesh(metrics["mesh"], gt_points=truth, spacing=0.004, max_dist=0.1, tau=0.01)
    assert m["chamfer"] == pytest.approx(metrics["chamfer"], rel=0.05)
    assert m["fscore"] == pytest.approx(metrics["f_score"], abs=0.03)


def test_train_refuses_bad_input_before_touching_anything(tmp_path):
    with pytest.raises(ValueError, match="render.no_such_key"):
        psneus.train(out=tmp_path / "a", **{"render.no_such_key": 1})
    with pytest.raises(ValueError, match="budget"):
        psneus.train(out=tmp_path / "b", budget="soon")
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("my notes")
    with pytest.raises(ValueError, match="not a run folder of psneus"):
        psneus.train(out=mine, **TINY)
    assert (mine / "notes.txt").read_text() == "my notes" and len(list(mine.iterdir())) == 1
    with pytest.raises(ValueError, match="resume"):
        psneus.train(resume=tmp_path / "a", seed=3)


def test_keyword_spellings_reach_the_same_key(tmp_path):
    """`data__masks=False` is `**{"data.masks": False}`: both train without the masks."""
    tiny = {k: v for k, v in TINY.items() if k != "steps"}
    a = psneus.train(out=tmp_path / "a", steps=1, data__masks=False, **tiny)
    b = psneus.train(out=tmp_path / "b", steps=1, **{"data.masks": False}, **tiny)
    assert a["psnr"] == b["psnr"] and a["chamfer"] == b["chamfer"]


def test_ctrl_c_in_train_writes_the_checkpoint_and_resume_finishes(tmp_path):
    """KeyboardInterrupt reaches Python while the Rust run trains with the GIL released: the
    run stops after its iteration with a checkpoint, and `train(resume=out)` finishes it."""
    import json
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    options = {k: v for k, v in TINY.items() if k != "steps"}
    options["output.log_every"] = 1
    # As in an interactive interpreter: a child of a background job inherits SIGINT ignored.
    script = (
        "import psneus, signal, sys\n"
        "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
        "try:\n"
        f"    psneus.train(out={str(out)!r}, budget='6s', **{options!r})\n"
        "except KeyboardInterrupt:\n"
        "    print('interrupted'); sys.exit(3)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    log = out / "log.jsonl"
    deadline = time.time() + 60
    while time.time() < deadline and not (log.exists() and '"loss"' in log.read_text()):
        time.sleep(0.05)
    child.send_signal(signal.SIGINT)
    stdout, stderr = child.communicate(timeout=60)
    assert child.returncode == 3 and "interrupted" in stdout, stderr
    assert (out / "checkpoint.safetensors").exists() and not (out / "metrics.json").exists()
    steps = [json.loads(line)["step"] for line in log.read_text().splitlines() if '"loss"' in line]
    metrics = psneus.train(resume=out)
    assert metrics["steps"] > max(steps) and (out / "metrics.json").exists()
