#!/usr/bin/env python3
"""Derive the reference camera decomposition of an IDR/NeuS `cameras_sphere.npz` with OpenCV,
exactly as NeuS's `load_K_Rt_from_P` does, and write it as JSON for the Rust tests.

    pip install numpy opencv-python-headless
    python3 scripts/dtu_opencv_fixture.py ../shared/data/dtu_scan24/cameras_sphere.npz \
        crates/datasets/tests/fixtures/dtu_scan24_opencv.json
"""
import json
import sys

import cv2
import numpy as np


def load_k_rt_from_p(p):
    # NeuS, models/dataset.py
    out = cv2.decomposeProjectionMatrix(p)
    k, r, t = out[0], out[1], out[2]
    k = k / k[2, 2]
    world_from_camera = np.eye(4)
    world_from_camera[:3, :3] = r.transpose()
    world_from_camera[:3, 3] = (t[:3] / t[3])[:, 0]
    return k, world_from_camera


def main():
    src, dst = sys.argv[1], sys.argv[2]
    cams = np.load(src)
    n = len([k for k in cams.files if k.startswith("world_mat_") and "inv" not in k])
    out = []
    for i in range(n):
        world_mat = cams[f"world_mat_{i}"].astype(np.float64)
        scale_mat = cams[f"scale_mat_{i}"].astype(np.float64)
        p = (world_mat @ scale_mat)[:3, :4]
        k, world_from_camera = load_k_rt_from_p(p)
        out.append({"K": k.tolist(), "world_from_camera": world_from_camera.tolist()})
    with open(dst, "w") as f:
        json.dump({"source": src, "opencv": cv2.__version__, "cameras": out}, f, indent=1)
    print(f"wrote {n} cameras to {dst}")


if __name__ == "__main__":
    main()
