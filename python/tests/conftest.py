"""Shared fixtures: a small built-in scene (no files needed) and an analytic sphere."""

import numpy as np
import pytest

import psneus

# The built-in golden scene at a size that loads in a fraction of a second.
SMALL = {"width": 64, "views": 12}


@pytest.fixture(scope="session")
def sphere_scene():
    """The built-in scene with its analytic sphere (centre and radius fitted to its truth)."""
    scene = psneus.load_scene(builtin=dict(SMALL, shape="sphere"))
    truth = scene.ground_truth().astype(np.float64)
    centre = truth.mean(axis=0)
    radius = float(np.linalg.norm(truth - centre, axis=1).mean())
    return scene, centre, radius


@pytest.fixture(scope="session")
def sphere_sdf(sphere_scene):
    _, centre, radius = sphere_scene

    def sdf(points):
        return (np.linalg.norm(points - centre, axis=1) - radius).astype(np.float32)

    return sdf
