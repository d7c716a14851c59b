"""The estimator from Python: determinism, guided rays on an analytic field, the uniform share,
state round trips, callback errors."""

import pickle

import numpy as np
import pytest

import psneus


def dilated(mask, pixels):
    """The mask grown by `pixels` in x and y (a square structuring element)."""
    out = mask.copy()
    for dy in range(-pixels, pixels + 1):
        for dx in range(-pixels, pixels + 1):
            shifted = np.zeros_like(mask)
            h, w = mask.shape
            shifted[max(dy, 0) : h + min(dy, 0), max(dx, 0) : w + min(dx, 0)] = mask[max(-dy, 0) : h + min(-dy, 0), max(-dx, 0) : w + min(-dx, 0)]
            out |= shifted
    return out


@pytest.fixture()
def updated(sphere_scene, sphere_sdf):
    scene, _, _ = sphere_scene
    estimator = psneus.Estimator(scene)
    report = estimator.update(sphere_sdf, 200.0)
    return scene, estimator, report


def test_draws_are_deterministic_for_a_seed(updated):
    _, estimator, _ = updated
    a, b, c = (estimator.draw(500, seed=s, coarse=4) for s in (3, 3, 4))
    assert set(a) == set(b)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert not np.array_equal(a["pixel"], c["pixel"])


def test_guided_rays_fall_in_the_masks_and_their_depths_on_the_surface(updated, sphere_scene):
    scene, estimator, report = updated
    _, centre, radius = sphere_scene
    assert report["scene_mass"] > 0 and report["empty_views"] == []
    rays = estimator.draw(4000, seed=1, uniform_fraction=0.0)
    assert rays["guided"].all()
    # The guide's mass is the surface's within a cell of its grids: at the silhouette it spills
    # a pixel or two past the mask (grazing rays), nowhere else.
    masks = [dilated(scene.mask(i), 2) for i in range(len(scene))]
    inside = [masks[v][int(y), int(x)] for v, (x, y) in zip(rays["view"], rays["pixel"])]
    assert np.mean(inside) > 0.95, f"only {np.mean(inside):.3f} of guided rays inside the masks (dilated by 2 pixels)"
    mask_share = np.mean([scene.mask(i).mean() for i in range(len(scene))])
    strictly = np.mean([scene.mask(v)[int(y), int(x)] for v, (x, y) in zip(rays["view"], rays["pixel"])])
    assert strictly > 3 * mask_share, f"guided rays inside the masks {strictly:.3f}, masks cover {mask_share:.3f}"
    # The guided depth is λ̃ along the ray: the point it names lies on the sphere within a few
    # depth bins.
    points = rays["origin"] + rays["direction"] * rays["depth"][:, None]
    error = np.abs(np.linalg.norm(points - centre, axis=1) - radius)
    assert np.median(error / rays["depth_bin"]) < 2.0
    np.testing.assert_allclose(np.linalg.norm(rays["direction"], axis=1), 1.0, atol=1e-5)


def test_the_uniform_share_is_drawn_uniformly(updated):
    scene, estimator, _ = updated
    n = 6000
    rays = estimator.draw(n, seed=2, uniform_fraction=0.25)
    uniform = ~rays["guided"]
    assert uniform.sum() == round(0.25 * n)
    inside = np.mean([scene.mask(v)[int(y), int(x)] for v, (x, y) in zip(rays["view"][uniform], rays["pixel"][uniform])])
    mask_share = np.mean([scene.mask(i).mean() for i in range(len(scene))])
    assert abs(inside - mask_share) < 0.05, f"uniform rays inside masks {inside:.3f}, masks cover {mask_share:.3f}"
    # The schedule's share when none is given.
    scheduled = estimator.draw(1000, seed=2, progress=0.9)
    assert (~scheduled["guided"]).sum() == round(estimator.uniform_fraction(0.9) * 1000)


def test_uniform_sampler_draws_without_a_guide(sphere_scene):
    scene, _, _ = sphere_scene
    estimator = psneus.Estimator(scene, sampler="uniform")
    rays = estimator.draw(100, seed=0)
    assert not rays["guided"].any() and np.isnan(rays["depth"]).all() and rays["background"].all()


def test_state_restores_the_same_draws_in_a_new_estimator(updated, sphere_scene):
    scene, estimator, _ = updated
    state = pickle.loads(pickle.dumps(estimator.state()))
    fresh = psneus.Estimator(scene)
    fresh.restore(state)
    a, b = estimator.draw(300, seed=9), fresh.draw(300, seed=9)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    with pytest.raises(ValueError, match="camera grids"):
        psneus.Estimator(scene, views=[0, 1]).restore(state)


def test_scheduled_updates_come_once_per_part(sphere_scene, sphere_sdf):
    scene, _, _ = sphere_scene
    estimator = psneus.Estimator(scene, updates=3)
    due = [estimator.update_due(p, sphere_sdf, 100.0) is not None for p in (0.0, 0.1, 0.34, 0.5, 0.7, 0.99)]
    assert due == [True, False, True, False, True, False]


def test_callback_errors_are_raised_and_leave_the_guide_as_it_was(updated, sphere_sdf):
    _, estimator, _ = updated
    before = estimator.draw(200, seed=5)

    def broken(points):
        raise RuntimeError("the network is on fire")

    with pytest.raises(RuntimeError, match="on fire"):
        estimator.update(broken, 64.0)
    with pytest.raises(ValueError, match="expected shape"):
        estimator.update(lambda p: np.zeros(3, np.float32), 64.0)
    with pytest.raises(ValueError, match="NaN"):
        estimator.update(lambda p: np.full(len(p), np.nan, np.float32), 64.0)
    with pytest.raises(TypeError, match="callable"):
        estimator.update(42, 64.0)
    after = estimator.draw(200, seed=5)
    for key in before:
        np.testing.assert_array_equal(before[key], after[key])


def test_bad_options_are_valueerrors_naming_the_key(sphere_scene):
    scene, _, _ = sphere_scene
    with pytest.raises(ValueError, match="guide.no_such_key"):
        psneus.Estimator(scene, no_such_key=1)
    with pytest.raises(ValueError, match="updates"):
        psneus.Estimator(scene, updates=0)
    with pytest.raises(ValueError, match="view 99"):
        psneus.Estimator(scene, views=[99])
    with pytest.raises(ValueError, match="uniform_fraction"):
        psneus.Estimator(scene).draw(10, seed=0, uniform_fraction=1.5)
    # The loss-guided samplers are not the estimator's: refused, not drawn uniformly in silence.
    with pytest.raises(ValueError, match="error-map"):
        psneus.Estimator(scene, sampler="error-map")


def test_extract_mesh_of_an_analytic_sphere(sphere_scene, sphere_sdf):
    _, centre, radius = sphere_scene
    vertices, faces = psneus.extract_mesh(sphere_sdf, resolution=64)
    assert vertices.shape[1] == 3 and faces.shape[1] == 3 and faces.max() < len(vertices)
    np.testing.assert_allclose(np.linalg.norm(vertices - centre, axis=1), radius, atol=2 / 64)


def test_a_python_callable_and_the_native_sphere_build_the_same_guide(sphere_scene):
    scene, centre, radius = sphere_scene
    sphere = psneus.Sphere(centre.tolist(), radius)
    native, called = psneus.Estimator(scene), psneus.Estimator(scene)
    a, b = native.update(sphere, 150.0), called.update(lambda p: sphere(p), 150.0)
    assert a["field_queries"] == b["field_queries"] and a["scene_mass"] == b["scene_mass"]
    for key, value in native.draw(400, seed=3).items():
        np.testing.assert_array_equal(value, called.draw(400, seed=3)[key])
