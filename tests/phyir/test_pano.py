"""Equirectangular geometry (phyir.pano) against the formulas of docs/conventions.md."""

import math

import pytest
import torch

from phyir import pano


def formula_dirs(H: int, W: int) -> torch.Tensor:
    """d(i, j) written out from the convention, independently of phyir.pano."""
    out = torch.empty(3, H, W, dtype=torch.float64)
    for i in range(H):
        lat = math.pi / 2 - math.pi * (i + 0.5) / H
        for j in range(W):
            lon = 2 * math.pi * (j + 0.5) / W - math.pi
            out[:, i, j] = torch.tensor([math.cos(lat) * math.sin(lon), math.sin(lat),
                                         -math.cos(lat) * math.cos(lon)])
    return out


def box_room(H: int, W: int):
    """Radial depth and inward normals of an axis-aligned box around the camera (ray-box by hand)."""
    lo = torch.tensor([-2.0, -1.5, -2.5], dtype=torch.float64)
    hi = torch.tensor([3.0, 1.2, 1.7], dtype=torch.float64)
    d = formula_dirs(H, W)
    bound = torch.where(d > 0, hi[:, None, None], lo[:, None, None])
    t = torch.where(d.abs() > 1e-12, bound / d, torch.full_like(d, math.inf))
    depth, axis = t.min(0, keepdim=True)
    normal = torch.zeros_like(d).scatter_(0, axis, -torch.sign(torch.gather(d, 0, axis)))
    return depth, normal


def angle_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos((a.double() * b.double()).sum(0).clamp(-1, 1)))


def test_directions_match_formula():
    for H, W in ((8, 16), (31, 64)):
        assert torch.allclose(pano.directions(H, W).double(), formula_dirs(H, W), atol=1e-6, rtol=0)


def test_directions_pin_centre_x_and_top():
    H, W = 64, 128
    d = pano.directions(H, W, dtype=torch.float64)
    # image centre (between the 4 middle pixels) looks along -z
    centre = d[:, H // 2 - 1 : H // 2 + 1, W // 2 - 1 : W // 2 + 1].mean((1, 2))
    assert torch.allclose(centre / centre.norm(), torch.tensor([0.0, 0, -1], dtype=torch.float64), atol=1e-9)
    # column 3W/4 (its left edge; average of the two neighbouring centres) looks along +x at the equator
    east = d[:, H // 2 - 1 : H // 2 + 1, 3 * W // 4 - 1 : 3 * W // 4 + 1].mean((1, 2))
    assert torch.allclose(east / east.norm(), torch.tensor([1.0, 0, 0], dtype=torch.float64), atol=1e-9)
    # top row points up, bottom row down
    assert (d[1, 0] > 0.99).all() and (d[1, -1] < -0.99).all()
    # the seam (column 0 and W-1) is behind the camera: +z
    assert (d[2, H // 2, [0, -1]] > 0.99).all()


def test_uv_direction_round_trip():
    g = torch.Generator().manual_seed(0)
    H, W = 32, 64
    u = torch.rand(1000, generator=g, dtype=torch.float64) * W
    v = 0.5 + torch.rand(1000, generator=g, dtype=torch.float64) * (H - 1)  # away from the exact poles
    u2, v2 = pano.dir_to_uv(pano.uv_to_dir(u, v, H, W), H, W)
    du = torch.remainder(u2 - u + W / 2, W) - W / 2
    assert du.abs().max() < 1e-9 and (v2 - v).abs().max() < 1e-9
    d = torch.nn.functional.normalize(torch.randn(3, 500, generator=g, dtype=torch.float64), dim=0)
    assert torch.allclose(pano.uv_to_dir(*pano.dir_to_uv(d, H, W), H, W), d, atol=1e-9)


def test_pixel_centres_map_to_their_uv():
    H, W = 16, 32
    u, v = pano.dir_to_uv(pano.directions(H, W, dtype=torch.float64), H, W)
    assert torch.allclose(u, torch.arange(W, dtype=torch.float64) + 0.5, atol=1e-9)
    assert torch.allclose(v, (torch.arange(H, dtype=torch.float64) + 0.5)[:, None].expand(H, W), atol=1e-9)


def test_depth_points_uv_round_trip():
    g = torch.Generator().manual_seed(1)
    H, W = 32, 64
    depth = 0.5 + 4 * torch.rand(2, 1, H, W, generator=g, dtype=torch.float64)  # batched
    pts = pano.depth_to_points(depth)
    assert torch.allclose(pts.norm(dim=1, keepdim=True), depth)
    u, v, r = pano.points_to_uv(pts, H, W, dim=1)
    assert torch.allclose(u, (torch.arange(W, dtype=torch.float64) + 0.5).expand_as(u), atol=1e-9)
    assert torch.allclose(v, (torch.arange(H, dtype=torch.float64) + 0.5)[:, None].expand_as(v), atol=1e-9)
    assert torch.allclose(r, depth[:, 0])


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_normals_from_depth_box_room(dtype):
    H, W = 64, 128
    depth, normal = box_room(H, W)
    n = pano.normals_from_depth(depth.to(dtype))
    err = angle_deg(n, normal)
    assert err.median() < 1.0
    assert err[:, [0, W - 1]].median() < 1.0  # the seam columns
    assert err[[0, H - 1]].median() < 1.0  # the pole rows
    # creases don't smear: only pixels where a face is one pixel wide are off
    assert (err > 1.0).float().mean() < 0.01
    assert torch.allclose(n.double().norm(dim=0), torch.ones(H, W, dtype=torch.float64), atol=1e-5)


def test_normals_from_depth_batched_and_differentiable():
    depth, _ = box_room(16, 32)
    depth = depth.float().expand(2, 1, 16, 32).clone().requires_grad_(True)
    n = pano.normals_from_depth(depth)
    assert n.shape == (2, 3, 16, 32)
    (n * torch.linspace(-1, 1, 32)).sum().backward()
    assert torch.isfinite(depth.grad).all()


def test_solid_angles_sum_to_sphere():
    total = float(pano.solid_angles(16, 32, dtype=torch.float64).sum())
    assert total == pytest.approx(4 * math.pi, rel=1e-12)


def test_sample_bilinear_at_centres_and_wrap():
    g = torch.Generator().manual_seed(2)
    img = torch.rand(3, 8, 16, generator=g, dtype=torch.float64)
    u = (torch.arange(16, dtype=torch.float64) + 0.5).expand(8, 16)
    v = (torch.arange(8, dtype=torch.float64) + 0.5)[:, None].expand(8, 16)
    assert torch.allclose(pano.sample_bilinear(img, u, v), img)
    # halfway across the seam: mean of the first and last column
    mid = pano.sample_bilinear(img, torch.zeros(8, dtype=torch.float64), v[:, 0])
    assert torch.allclose(mid, 0.5 * (img[:, :, 0] + img[:, :, -1]))
    # clamped at the poles
    top = pano.sample_bilinear(img, u[0], torch.zeros(16, dtype=torch.float64))
    assert torch.allclose(top, img[:, 0])


def test_circular_pad():
    x = torch.arange(2 * 3 * 4, dtype=torch.float32).reshape(2, 3, 4)
    y = pano.circular_pad(x, (2, 1, 1, 2))
    assert y.shape == (2, 3 + 3, 4 + 3)
    assert torch.equal(y[:, 1:4, 2:6], x)
    assert torch.equal(y[:, 1:4, :2], x[:, :, -2:])  # wrap in longitude
    assert torch.equal(y[:, 1:4, 6:], x[:, :, :1])
    assert torch.equal(y[:, 0, 2:6], x[:, 0]) and torch.equal(y[:, 4, 2:6], x[:, -1])  # replicate rows
    assert torch.equal(y[:, 5, 2:6], x[:, -1])
    assert torch.equal(pano.circular_pad(x, 1)[:, 1:-1, 0], x[:, :, -1])


def test_yaw_shift_angle_matches_directions():
    H, W, s = 8, 32, 5
    d = pano.directions(H, W, dtype=torch.float64)
    m = pano.yaw_matrix(pano.yaw_shift_angle(s, W), dtype=torch.float64)
    # rolling right by s columns moves what was seen along d(j) to column j + s: m d(j) = d(j + s)
    assert torch.allclose(pano.rotate_vectors(m, d, dim=0), torch.roll(d, -s, dims=-1), atol=1e-12)


def test_resize_area_preserves_constant_and_solid_angle_integral():
    g = torch.Generator().manual_seed(3)
    const = torch.full((3, 32, 64), 0.7, dtype=torch.float64)
    for H, W in ((8, 16), (16, 32), (12, 24), (48, 96)):
        assert torch.allclose(pano.resize_area(const, H, W), torch.full((3, H, W), 0.7, dtype=torch.float64))
    x = torch.rand(2, 3, 32, 64, generator=g, dtype=torch.float64)
    for H, W in ((16, 32), (8, 16), (4, 8)):  # integer factors: the radiance integral is kept
        y = pano.resize_area(x, H, W)
        def integral(t):
            return (t * pano.solid_angles(*t.shape[-2:], dtype=t.dtype)).sum((-2, -1))
        assert torch.allclose(integral(y), integral(x), rtol=1e-12)
    # non-integer factor: the integral is close
    y = pano.resize_area(x, 12, 24)
    w_in, w_out = pano.solid_angles(32, 64, dtype=x.dtype), pano.solid_angles(12, 24, dtype=x.dtype)
    assert torch.allclose((y * w_out).sum((-2, -1)), (x * w_in).sum((-2, -1)), rtol=0.02)


def test_perspective_crop_centre_looks_at_minus_z():
    d = pano.perspective_dirs(5, 7, 60.0)
    assert torch.allclose(d[:, 2, 3], torch.tensor([0.0, 0, -1]), atol=1e-6)
    assert torch.allclose(pano.perspective_dirs(5, 7, 60.0, yaw=math.pi / 2)[:, 2, 3],
                          torch.tensor([1.0, 0, 0]), atol=1e-6)
    assert torch.allclose(pano.perspective_dirs(5, 7, 60.0, pitch=math.pi / 2)[:, 2, 3],
                          torch.tensor([0.0, 1, 0]), atol=1e-6)
    # vertical field of view: the top edge is fov/2 above the axis
    d = pano.perspective_dirs(100, 100, 60.0, dtype=torch.float64)
    f = 50 / math.tan(math.radians(30))  # focal length in pixels
    want = torch.nn.functional.normalize(torch.tensor([0.5 / f, 49.5 / f, -1], dtype=torch.float64), dim=0)
    assert torch.allclose(d[:, 0, 50], want, atol=1e-9)  # top pixel centre: half a pixel below the edge
    # an equirect image whose pixels store their own direction: the crop reproduces the directions
    env = pano.directions(64, 128, dtype=torch.float64)
    crop = pano.perspective_crop(env, 9, 9, fov_y_deg=40.0)
    assert torch.allclose(crop[:, 4, 4], torch.tensor([0.0, 0, -1], dtype=torch.float64), atol=2e-3)
    want = pano.perspective_dirs(9, 9, 40.0, dtype=torch.float64)
    assert angle_deg(crop / crop.norm(dim=0), want).max() < 1.0
