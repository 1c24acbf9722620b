"""phyir.geometry.depth_normal: the normals' log-depth steps are exact on planes, and refinement flattens a
bent room back onto its planes (analytic box rooms)."""

from __future__ import annotations

import math

import pytest
import torch
import torch.nn.functional as F

from phyir import pano
from phyir.geometry.depth_normal import log_depth_steps, refine_depth
from phyir.geometry.plausible import REFINE_ANCHOR, REFINE_TAU
from phyir.learn.losses import depth_normal_loss


def box_room(H: int, W: int, lo=(-2.5, -1.5, -5.0), hi=(3.5, 1.2, 3.0)) -> tuple[torch.Tensor, torch.Tensor]:
    """Radial depth [1,H,W] and normals [3,H,W] of an axis-aligned box around the camera: each ray
    leaves through the face whose plane it reaches first (independent of phyir.pano's depth code)."""
    d = pano.directions(H, W, dtype=torch.float64)
    lo_t = torch.tensor(lo, dtype=torch.float64)[:, None, None]
    hi_t = torch.tensor(hi, dtype=torch.float64)[:, None, None]
    t = torch.where(d > 0, hi_t / d.clamp_min(1e-12), lo_t / d.clamp_max(-1e-12))
    r, axis = t.min(0)
    n = torch.zeros(3, H, W, dtype=torch.float64).scatter_(0, axis[None], 1.0) * -torch.sign(d)
    return r[None], n


def _angle_deg(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(torch.rad2deg(torch.acos((a * b).sum(0).clamp(-1, 1))).mean())


def test_steps_are_exact_on_planes_and_off_at_creases():
    depth, normal = box_room(64, 128)
    s = log_depth_steps(normal)
    z = torch.log(depth)
    zx = torch.roll(z, -1, dims=-1) - z
    zy = torch.cat((z[..., 1:, :], z[..., -1:, :]), -2) - z
    assert float(((zx - s.gx).abs() * s.wx).max()) < 1e-9
    assert float(((zy - s.gy).abs() * s.wy).max()) < 1e-9
    # steps across the box's edges (normals 90 degrees apart) are not used; nearly all others are
    assert 0.95 < float(s.wx.mean()) < 1.0 and 0.95 < float(s.wy.mean()) < 1.0
    assert float(s.wy[..., -1, :].abs().max()) == 0.0


def test_refinement_flattens_a_bowl_back_onto_the_planes():
    depth, normal = box_room(64, 128)
    lat = pano.pixel_lonlat(64, 128, dtype=torch.float64)[1]
    g = torch.Generator().manual_seed(0)
    bowl = depth * (1 + 0.3 * torch.cos(lat) ** 2) * (1 + 0.03 * torch.randn(depth.shape, generator=g,
                                                                                dtype=torch.float64))
    fixed = refine_depth(bowl, normal, anchor=1e-4, iters=1000)
    # the shape comes back up to the one global scale the normals can't tell
    scale = torch.exp((torch.log(depth) - torch.log(fixed)).median())
    rel = float(((fixed * scale - depth).abs() / depth).mean())
    rel_bowl = float(((bowl * torch.exp((torch.log(depth) - torch.log(bowl)).median()) - depth).abs()
                      / depth).mean())
    assert rel < 0.5 * rel_bowl  # what is left is mostly the 3 % noise
    assert _angle_deg(pano.normals_from_depth(fixed), normal) < 2.0
    assert _angle_deg(pano.normals_from_depth(bowl), normal) > 30.0


def test_refinement_keeps_consistent_depth_and_occlusion_edges():
    depth, normal = box_room(32, 64)
    assert torch.allclose(refine_depth(depth, normal), depth, rtol=1e-6)
    # a box in front of the wall: the jump to it is not smoothed away by the wall's normals
    step = depth.clone()
    step[..., 12:20, 20:30] *= 0.5
    fixed = refine_depth(step, normal, anchor=REFINE_ANCHOR, tau=REFINE_TAU)  # predict's settings
    assert float((fixed[..., 12:20, 20:30] / step[..., 12:20, 20:30]).sub(1).abs().max()) < 0.01


def test_depth_normal_loss_is_zero_when_consistent_and_grows_with_the_bend():
    depth, normal = box_room(32, 64)
    d, n = depth[None].float(), normal[None].float()
    assert float(depth_normal_loss(d, n, d, n)) < 1e-5
    lat = pano.pixel_lonlat(32, 64)[1]
    losses = [float(depth_normal_loss(d * (1 + a * torch.cos(lat) ** 2), n, d, n)) for a in (0.1, 0.3)]
    assert 0 < losses[0] < losses[1]
    # gradients reach both heads
    d2, n2 = d.clone().requires_grad_(), n.clone().requires_grad_()
    depth_normal_loss(d2 * (1 + 0.1 * torch.cos(lat) ** 2), n2, d, n).backward()
    assert float(d2.grad.abs().sum()) > 0 and float(n2.grad.abs().sum()) > 0


@pytest.mark.parametrize("grazing", [True, False])
def test_steps_ignore_grazing_views(grazing):
    """A floor seen at the horizon has -n.d -> 0: its steps are ill-conditioned and get no weight."""
    H, W = 32, 64
    n = torch.zeros(3, H, W, dtype=torch.float64)
    n[1] = 1.0
    s = log_depth_steps(n)
    lat = pano.pixel_lonlat(H, W, dtype=torch.float64)[1]
    rows = (lat < -math.radians(20)) if not grazing else (lat.abs() < math.radians(3))
    w = float(s.wx[0][rows].mean())
    assert (w == 1.0) if not grazing else (w == 0.0)


def test_the_anchor_weighs_a_pixel_by_its_solid_angle():
    """The depth's pull is per unit solid angle: the same smooth bump is flattened further near the
    nadir, where each pixel covers cos(latitude) of an equator pixel's view, than at the horizon."""
    H, W = 64, 128
    depth, normal = box_room(H, W)
    rows = torch.arange(H, dtype=torch.float64)[:, None]
    cols = torch.arange(W, dtype=torch.float64)[None, :]

    def bump(row: int) -> torch.Tensor:  # +4 % at its centre, 3 px wide: 1-2 % steps, not an occlusion
        return 1 + 0.04 * torch.exp(-((rows - row) ** 2 + (cols - 40) ** 2) / (2 * 3.0 ** 2))

    left = {}
    for name, row in (("horizon", H // 2 + 4), ("nadir", H - 5)):
        fixed = refine_depth(depth * bump(row), normal, anchor=REFINE_ANCHOR, tau=REFINE_TAU)
        left[name] = float((fixed / depth - 1).abs()[0, row - 2:row + 3, 37:44].max())
    assert left["nadir"] < 0.5 * left["horizon"], left


def _room_with_a_crate(H: int, W: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A box room with a crate in front of the camera: depth [1,H,W], normals [3,H,W] and where the
    crate is [H,W] (phyir.synth.analytic, an independent ray-box test)."""
    from phyir.synth.analytic import box_hits

    d = pano.directions(H, W, dtype=torch.float64)
    room_t, room_n, _ = box_hits(d, (-2.5, -1.5, -5.0), (3.5, 1.2, 3.0), inside=True)
    crate_t, crate_n, hit = box_hits(d, (-0.6, -1.5, -2.4), (0.6, -0.3, -1.6), inside=False)
    crate = hit & (crate_t < room_t)
    return torch.where(crate, crate_t, room_t)[None], torch.where(crate, crate_n, room_n), crate


def _outline(mask: torch.Tensor) -> torch.Tensor:
    """Pixels with a 4-neighbour on the other side of ``mask``'s boundary."""
    rows = torch.zeros_like(mask)
    rows[1:] |= mask[1:] != mask[:-1]
    rows[:-1] |= mask[:-1] != mask[1:]
    return rows | (torch.roll(mask, 1, -1) != mask) | (torch.roll(mask, -1, -1) != mask)


def test_occlusion_edges_mark_the_crate_outline_and_nothing_inside_surfaces():
    from phyir.geometry.depth_normal import occlusion_edges

    depth, normal, crate = _room_with_a_crate(64, 128)
    edges = occlusion_edges(torch.log(depth), normal, tau=0.02)[0]
    # the outline: crate pixels beside a wall pixel (the depth jumps there)
    beside = _outline(crate)
    # where the depth jumps: the crate's outline but its foot, which stands on the floor
    z = torch.log(depth[0])
    jump = torch.zeros_like(crate)
    jump[:-1] |= (z[1:] - z[:-1]).abs() > 0.1
    jump[1:] |= (z[1:] - z[:-1]).abs() > 0.1
    jump |= ((torch.roll(z, 1, -1) - z).abs() > 0.1) | ((torch.roll(z, -1, -1) - z).abs() > 0.1)
    outline = beside & crate & jump
    assert int(outline.sum()) > 20
    assert float(edges[outline].min()) > 0.99
    # away from the outline and the room's creases (two pixels), nothing is an edge
    wide = F.max_pool2d(beside[None, None].double(), 5, 1, 2)[0, 0] > 0
    steps = log_depth_steps(normal)
    creases = F.max_pool2d(((steps.wx < 1) | (steps.wy < 1))[None].double(), 5, 1, 2)[0, 0] > 0
    inside = ~wide & ~creases
    assert float(inside.double().mean()) > 0.6
    assert float(edges[inside].max()) < 1e-3


def test_depth_upsampled_with_its_normals_ignores_texture_and_keeps_occlusions():
    from phyir.geometry.depth_normal import upsample_depth

    depth_lo, normal_lo, crate_lo = _room_with_a_crate(32, 64)
    depth_hi, _, crate_hi = _room_with_a_crate(128, 256)
    # the image: the room's shading plus a high-contrast stripe texture on every surface
    texture = (torch.arange(256) // 3 % 2).double()[None, None].expand(1, 128, 256)
    image_hi = torch.log1p(0.5 + 0.4 * texture + 2.0 * crate_hi.double())
    image_lo = pano.resize_area(image_hi, 32, 64)
    kw = dict(r=2, eps=1e-3, tau=0.02, surface_eps=1e3)
    plain = upsample_depth(depth_lo, image_lo, image_hi, normal=None, **kw)
    aware = upsample_depth(depth_lo, image_lo, image_hi, normal=normal_lo, **kw)
    near_edges = F.max_pool2d(_outline(crate_hi)[None, None].double(), 17, 1, 8)[0, 0] > 0
    band = ~near_edges & (pano.pixel_lonlat(128, 256, dtype=torch.float64)[1].abs() < 1.0)

    def ripple(x):  # the texture's 3-pixel period in the depth: second differences along a row
        z = torch.log(x[0])
        return float((torch.roll(z, 1, -1) - 2 * z + torch.roll(z, -1, -1)).abs()[band].median())
    assert ripple(plain) > 10 * ripple(aware)
    # at the crate's outline the depth still jumps with the image, as sharply as the plain upsampling's
    smooth = upsample_depth(depth_lo, image_lo, image_hi, normal=None, **(kw | {"eps": 1e3}))
    outline = F.max_pool2d(_outline(crate_hi)[None, None].double(), 3, 1, 1)[0, 0] > 0
    def error(x):
        return float(((x - depth_hi).abs() / depth_hi)[0][outline].mean())
    assert error(aware) < 1.2 * error(plain)
    assert error(aware) < 0.7 * error(smooth)
