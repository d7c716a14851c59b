"""Scenes from Python against the loaders: cameras, images, masks, errors."""

import numpy as np
import pytest

import psneus
from conftest import SMALL


def project(camera, points):
    """Pixel coordinates (integer = centre) and depths of normalised-frame points."""
    camera_from_world = np.linalg.inv(camera["world_from_camera"])
    p = points @ camera_from_world[:3, :3].T + camera_from_world[:3, 3]
    uv = p @ camera["K"].T
    return uv[:, :2] / uv[:, 2:], p[:, 2]


def test_builtin_scene_cameras_images_and_masks_agree(sphere_scene):
    scene, centre, radius = sphere_scene
    assert len(scene) == SMALL["views"] == len(scene.cameras)
    for i, camera in enumerate(scene.cameras):
        image, mask = scene.image(i), scene.mask(i)
        assert image.shape == (camera["height"], camera["width"], 3) and image.dtype == np.float32
        assert 0.0 <= image.min() and image.max() <= 1.0
        assert mask.shape == (camera["height"], camera["width"]) and mask.dtype == np.bool_
        rotation = camera["world_from_camera"][:3, :3]
        np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-9)
        # The sphere's centre projects inside its mask; a point far to the side does not.
        (uv,), (depth,) = project(camera, centre[None])
        assert depth > 0
        col, row = np.round(uv).astype(int)
        assert mask[row, col], f"view {i}: the sphere's centre projects to ({col}, {row}), outside its mask"
    np.testing.assert_allclose(scene.world_from_normalized, np.eye(4))


def write_idr(folder, views=3, width=32, height=24):
    (folder / "image").mkdir(parents=True)
    K = np.array([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]])
    scale = np.diag([2.0, 2.0, 2.0, 1.0])
    scale[:3, 3] = [0.1, -0.2, 0.3]
    arrays, poses = {}, []
    for i in range(views):
        angle = 2 * np.pi * i / views
        eye = 3.0 * np.array([np.cos(angle), np.sin(angle), 0.3])
        forward = -eye / np.linalg.norm(eye)
        right = np.cross(forward, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(forward, right)
        R = np.stack([right, down, forward])  # camera_from_world rotation (OpenCV axes)
        t = -R @ eye
        world_from_camera = np.eye(4)
        world_from_camera[:3, :3], world_from_camera[:3, 3] = R.T, eye
        poses.append(world_from_camera)
        P = np.eye(4)
        P[:3, :4] = K @ np.hstack([R, t[:, None]])
        # IDR: world_mat projects the dataset's world; scale_mat maps the normalised frame to it.
        arrays[f"world_mat_{i}"] = P
        arrays[f"scale_mat_{i}"] = scale
        write_png(folder / "image" / f"{i:03d}.png", np.full((height, width, 3), 40 * i, np.uint8))
    np.savez(folder / "cameras_sphere.npz", **arrays)
    return K, scale, poses


def write_png(path, pixels):
    """A minimal RGB PNG writer (zlib only), so the test needs no imaging library."""
    import struct
    import zlib

    h, w, _ = pixels.shape
    raw = b"".join(b"\x00" + pixels[r].tobytes() for r in range(h))

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b""))


def test_idr_cameras_read_back_as_written(tmp_path):
    K, scale, poses = write_idr(tmp_path)
    scene = psneus.load_scene(tmp_path)
    assert len(scene) == 3
    np.testing.assert_allclose(scene.world_from_normalized, scale, atol=1e-9)
    for i, camera in enumerate(scene.cameras):
        np.testing.assert_allclose(camera["K"], K, atol=1e-6)
        # The pose in the normalised frame: the world pose mapped by scale⁻¹ (a similarity).
        centre = np.linalg.inv(scale) @ np.append(poses[i][:3, 3], 1.0)
        np.testing.assert_allclose(camera["world_from_camera"][:3, 3], centre[:3], atol=1e-6)
        np.testing.assert_allclose(camera["world_from_camera"][:3, :3], poses[i][:3, :3], atol=1e-6)
        assert scene.image(i)[0, 0, 0] == pytest.approx(40 * i / 255, abs=1e-6)
        assert scene.mask(i) is None


def test_missing_folder_is_an_oserror_naming_it(tmp_path):
    missing = tmp_path / "nowhere"
    with pytest.raises(OSError, match="nowhere"):
        psneus.load_scene(missing)


def test_corrupt_cameras_are_a_valueerror_naming_the_file(tmp_path):
    write_idr(tmp_path)
    (tmp_path / "cameras_sphere.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="cameras_sphere.npz"):
        psneus.load_scene(tmp_path)


def test_unknown_option_is_a_valueerror_naming_it():
    with pytest.raises(ValueError, match="no_such_option"):
        psneus.load_scene(no_such_option=1)


def test_view_index_out_of_range_is_an_indexerror(sphere_scene):
    scene, _, _ = sphere_scene
    with pytest.raises(IndexError):
        scene.image(len(scene))
