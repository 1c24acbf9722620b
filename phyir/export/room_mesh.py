"""The room as a triangle mesh: the depth panorama triangulated on a longitude/latitude grid.

Vertex (r, c) of a ``gh x gw`` grid sits at the panorama's continuous pixel coordinates
(u, v) = (c W/gw, r H/gh) — pixel *corners*, so row 0 is the zenith, row gh the nadir and columns 0
and gw are both at longitude -180°: the seam column is duplicated, with texture u = 0 on one copy and
u = 1 on the other, so no triangle spans the whole texture.  Each vertex is the camera ray's point at
the bilinear depth there (docs/conventions.md: camera at the origin, +y up, metres, radial depth); the
vertices of a pole row all sit at the mean depth of the panorama's first (last) row, one point with a
fan of texture coordinates.  Texture coordinates are (u/W, v/H): glTF's, top-left origin, into the
panorama itself and every layer of its size.

No rubber sheets: a triangle is dropped where its vertices' depths differ by more than a continuous
surface seen at ``min_grazing_deg`` could step across one grid cell (the projection lighting's rule,
:func:`phyir.lighting.projection.jump_threshold`), or where its face turns more than
``90° - min_grazing_deg`` away from the camera ray through its centre.  Triangles are wound
counter-clockwise as seen from the camera (glTF front faces), so every kept face faces the origin.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from phyir import pano
from phyir.lighting.projection import jump_threshold
from phyir.scene import PanoScene

DEFAULT_GRID = (256, 512)
MIN_GRAZING_DEG = 5.0


@dataclass
class RoomMesh:
    """Triangles of the room (float32 / uint32, world frame)."""

    positions: np.ndarray  # [V, 3]
    normals: np.ndarray  # [V, 3] unit, facing the camera
    texcoords: np.ndarray  # [V, 2] glTF UV (u right, v down) into the panorama
    faces: np.ndarray  # [F, 3], counter-clockwise seen from the origin
    grid: tuple[int, int]
    dropped: int  # triangles removed at depth discontinuities and grazing faces


def vertex_grid(gh: int, gw: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Texture coordinates (s, t) in [0, 1] of the (gh+1) x (gw+1) vertices, float64 [gh+1, gw+1]."""
    t = torch.arange(gh + 1, dtype=torch.float64) / gh
    s = torch.arange(gw + 1, dtype=torch.float64) / gw
    tt, ss = torch.meshgrid(t, s, indexing="ij")
    return ss, tt


def _vertex_layers(scene: PanoScene, gh: int, gw: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Depth [gh+1, gw+1] and unit normals [3, gh+1, gw+1] at the grid's vertices."""
    H, W = scene.size
    depth = torch.nan_to_num(scene.depth.double(), nan=0.0).clamp_min(1e-3)
    normal = (pano.normals_from_depth(depth) if scene.normal is None
              else torch.nan_to_num(scene.normal.double()))
    s, t = vertex_grid(gh, gw)
    d = pano.sample_bilinear(depth, s * W, t * H)[0]
    n = pano.sample_bilinear(normal, s * W, t * H)
    d[0], d[-1] = depth[0, 0].mean(), depth[0, -1].mean()  # each pole is one point
    for row, sign in ((0, 1.0), (-1, -1.0)):  # ... with one normal: the mean, else the pole's axis
        m = n[:, row].mean(-1, keepdim=True)
        n[:, row] = m if float(m.norm()) > 0.5 else torch.tensor([[0.0], [-sign], [0.0]], dtype=n.dtype)
    n = n / n.norm(dim=0, keepdim=True).clamp_min(1e-12)
    return d, n


def grid_faces(gh: int, gw: int) -> np.ndarray:
    """The two triangles of every grid cell, vertex indices into the row-major (gh+1) x (gw+1) grid,
    counter-clockwise seen from the centre of the sphere."""
    r, c = np.meshgrid(np.arange(gh), np.arange(gw), indexing="ij")
    a = (r * (gw + 1) + c).ravel()  # top-left; columns grow to the viewer's right (east), rows down
    b, cc, dd = a + 1, a + gw + 1, a + gw + 2  # top-right, bottom-left, bottom-right
    return np.concatenate([np.stack((a, cc, b), 1), np.stack((b, cc, dd), 1)]).astype(np.uint32)


def room_mesh(scene: PanoScene, grid: tuple[int, int] = DEFAULT_GRID,
              min_grazing_deg: float = MIN_GRAZING_DEG) -> RoomMesh:
    """Triangulate ``scene``'s depth on a ``grid = (rows, columns)`` grid (see the module doc)."""
    gh, gw = grid
    d, n = _vertex_layers(scene, gh, gw)
    s, t = vertex_grid(gh, gw)
    H, W = scene.size
    dirs = pano.uv_to_dir(s * W, t * H, H, W, dim=0)
    pos = (dirs * d).reshape(3, -1).T.numpy()
    faces = grid_faces(gh, gw)
    tri = pos[faces]  # [F, 3, 3]
    dist = np.linalg.norm(tri, axis=-1)
    ratio = dist.max(1) / dist.min(1).clip(1e-9)
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area2 = np.linalg.norm(cross, axis=-1)
    centre = tri.mean(1)
    facing = -(cross * centre).sum(-1) / (area2 * np.linalg.norm(centre, axis=-1)).clip(1e-30)
    keep = ((ratio - 1 <= jump_threshold(gh, min_grazing_deg)) & (area2 > 1e-12 * dist.max(1) ** 2)
            & (facing >= math.sin(math.radians(min_grazing_deg))))
    degenerate = int((area2 <= 1e-12 * dist.max(1) ** 2).sum())  # the poles' collapsed triangles
    return RoomMesh(
        positions=pos.astype(np.float32),
        normals=n.reshape(3, -1).T.numpy().astype(np.float32),
        texcoords=torch.stack((s, t), -1).reshape(-1, 2).numpy().astype(np.float32),
        faces=np.ascontiguousarray(faces[keep]),
        grid=(gh, gw),
        dropped=int((~keep).sum()) - degenerate,
    )
