"""The room mesh: grid, seam, poles, winding, and no rubber sheets at depth discontinuities."""

from __future__ import annotations

import math

import numpy as np
import torch
from support.scenes import box_room

from phyir import pano
from phyir.export.room_mesh import grid_faces, room_mesh
from phyir.lighting.projection import jump_threshold
from phyir.scene import PanoScene


def sphere_scene(H: int = 32, W: int = 64, r: float = 2.0) -> PanoScene:
    return PanoScene(image=torch.ones(3, H, W), depth=torch.full((1, H, W), r))


def facing(pos: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """cos between each face's (right-hand) normal and the direction to the camera."""
    tri = pos[faces].astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    c = tri.mean(1)
    return -(n * c).sum(1) / (np.linalg.norm(n, axis=1) * np.linalg.norm(c, axis=1))


def test_a_sphere_of_constant_depth_is_closed_and_faces_the_camera():
    m = room_mesh(sphere_scene(), grid=(16, 32))
    assert m.positions.shape == (17 * 33, 3) and m.texcoords.shape == (17 * 33, 2)
    np.testing.assert_allclose(np.linalg.norm(m.positions, axis=1), 2.0, rtol=1e-5)
    # every cell's two triangles, less one collapsed triangle per cell of each pole row
    assert len(m.faces) == 2 * 16 * 32 - 2 * 32 and m.dropped == 0
    assert facing(m.positions, m.faces).min() > 0.9  # counter-clockwise seen from the origin
    # the seam column is duplicated: same points, texture u = 0 and u = 1
    grid = m.positions.reshape(17, 33, 3)
    np.testing.assert_allclose(grid[:, 0], grid[:, -1], atol=1e-6)
    uv = m.texcoords.reshape(17, 33, 2)
    assert (uv[:, 0, 0] == 0).all() and (uv[:, -1, 0] == 1).all()
    # the poles are one point each
    np.testing.assert_allclose(grid[0], [[0, 2, 0]] * 33, atol=1e-5)
    np.testing.assert_allclose(grid[-1], [[0, -2, 0]] * 33, atol=1e-5)


def test_texture_coordinates_index_the_panorama_where_the_vertex_is_seen():
    scene = box_room(64, 128)
    m = room_mesh(scene, grid=(32, 64))
    H, W = scene.size
    s, t = torch.from_numpy(m.texcoords.astype(np.float64)).T
    d = pano.uv_to_dir(s * W, t * H, H, W, dim=-1).numpy()
    p = m.positions / np.linalg.norm(m.positions, axis=1, keepdims=True)
    assert np.abs((d * p).sum(1)).min() > 1 - 1e-5
    # ... at the depth the panorama has there (bilinear at the vertex; poles: the row's mean)
    r = pano.sample_bilinear(scene.depth.double(), s * W, t * H)[0].numpy()
    inner = ((t > 0) & (t < 1)).numpy()
    np.testing.assert_allclose(np.linalg.norm(m.positions, axis=1)[inner], r[inner], rtol=1e-4)


def test_no_triangle_bridges_the_tables_silhouette():
    scene = box_room(128, 256)
    m = room_mesh(scene, grid=(64, 128))
    assert m.dropped > 5  # the table's outline against the floor and the walls
    dist = np.linalg.norm(m.positions[m.faces], axis=-1)
    assert (dist.max(1) / dist.min(1) - 1).max() <= jump_threshold(64, 5.0) + 1e-6
    assert facing(m.positions, m.faces).min() >= math.sin(math.radians(5.0)) - 1e-6
    # the table top is kept: faces whose points lie on it (y = -0.8 within 1 cm)
    on_top = np.abs(m.positions[m.faces][..., 1] + 0.8).max(1) < 0.01
    assert on_top.sum() > 10


def test_grid_faces_cover_each_cell_with_two_triangles():
    f = grid_faces(2, 3)
    assert f.shape == (12, 3) and f.max() == 3 * 4 - 1
    assert np.bincount(f.ravel(), minlength=12).min() >= 1
