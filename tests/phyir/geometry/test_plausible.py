"""predict never ships a collapsed normal layer: visible surfaces face the camera.

A stub GMNet stands in for the network so each case is exact: in a box room it predicts "up"
everywhere (the collapse seen on real rooms) unless told otherwise.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from phyir import inference, pano
from phyir.geometry import plausible
from phyir.geometry.gravity import LEVEL_DEG_FROM_DEPTH, snap_normals
from phyir.scene import PanoScene
from phyir.synth.analytic import box_room

H, W = 32, 64
LO, HI = (-2.0, -1.4, -3.0), (2.5, 1.3, 2.0)


def angle_deg(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.rad2deg(torch.acos((a * b).sum(0).clamp(-1, 1)))


class StubGM(nn.Module):
    """GMNet stand-in: exact box-room geometry for inputs brighter below the horizon, collapsed
    ("up") normals for inputs brighter above (``collapse_both``: always collapsed)."""

    def __init__(self, collapse_both: bool = False):
        super().__init__()
        self.scale = nn.Parameter(torch.ones(1))
        self.collapse_both = collapse_both
        self.calls = 0
        depth, normal = box_room(H, W, LO, HI)
        self.depth, self.normal = depth.float(), normal.float()

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        self.calls += 1
        bright_top = bool(x[0, :, : H // 2].mean() > x[0, :, H // 2:].mean())
        depth, normal = self.depth, self.normal
        if not bright_top:  # what a mirrored room looks like, in its own (mirrored) frame
            depth = depth.flip(-2)
            normal = normal.flip(-2) * torch.tensor([1.0, -1.0, 1.0])[:, None, None]
        if bright_top or self.collapse_both:
            normal = torch.tensor([0.0, 1.0, 0.0])[:, None, None].expand(3, H, W)
        out = {"depth": depth, "normal": normal, "albedo": torch.full((3, H, W), 0.5),
               "roughness": torch.full((1, H, W), 0.5), "metallic": torch.zeros(1, H, W)}
        return {k: v[None] * self.scale for k, v in out.items()}


class StubModel(nn.Module):
    def __init__(self, gm: StubGM):
        super().__init__()
        self.gmnet = gm
        self.gsnet = nn.Module()
        self.gsnet.targets = ()


def lamp_panorama() -> torch.Tensor:
    """A panorama lit from above: the upper half brighter (ceiling lights)."""
    lat = math.pi / 2 - math.pi * (torch.arange(H) + 0.5) / H
    return (0.2 + torch.sin(lat).clamp(min=0))[None, :, None].expand(3, H, W).contiguous()


def test_away_share_of_exact_normals_is_zero_and_of_collapsed_ones_half():
    _, normal = box_room(H, W, LO, HI)
    assert plausible.away_share(normal.float()) == 0.0
    up = torch.tensor([0.0, 1.0, 0.0])[:, None, None].expand(3, H, W)
    assert abs(plausible.away_share(up) - 0.5) < 0.02


def test_collapsed_pass_is_replaced_by_the_mirrored_pass():
    gm = StubGM()
    out, report = inference.predict_with_report(lamp_panorama(), model=StubModel(gm),
                                                outputs=("depth", "normal"), probes=None)
    assert gm.calls == 2 and report.gm_pass == "mirrored" and report.normals_from == "network"
    _, truth = box_room(H, W, LO, HI)
    assert float(angle_deg(out.normal, truth.float()).max()) < 1e-3
    assert out.meta["predict.gm_pass"] == "mirrored"


def test_normals_fall_back_to_the_depth_when_no_pass_is_plausible():
    gm = StubGM(collapse_both=True)
    out, report = inference.predict_with_report(lamp_panorama(), model=StubModel(gm),
                                                outputs=("depth", "normal"), probes=None)
    assert report.normals_from == "depth" and report.normals_away > 0.4
    depth, truth = box_room(H, W, LO, HI)
    from_depth = snap_normals(pano.normals_from_depth(out.depth), level_deg=LEVEL_DEG_FROM_DEPTH)
    assert torch.allclose(out.normal, from_depth, atol=1e-6)
    assert plausible.away_share(out.normal) == 0.0
    # the box's faces are planar: their depth normals are exact away from the edges
    assert float(angle_deg(out.normal, truth.float()).median()) < 1.0


def test_plausible_normals_run_one_pass_and_stay_as_predicted():
    gm = StubGM()
    dark_top = lamp_panorama().flip(-2)  # brighter below: the stub predicts exact (mirrored) normals
    out, report = inference.predict_with_report(dark_top, model=StubModel(gm), outputs=("normal",),
                                                probes=None)
    assert gm.calls == 1 and report.gm_pass == "upright" and report.normals_from == "network"
    assert torch.equal(out.normal, gm(dark_top[None])["normal"][0])


class BentGM(StubGM):
    """Exact box-room normals, depth bent into a bowl (+25 % at the horizon): what large real rooms
    got from the network."""

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        out = super().forward(x)
        lat = pano.pixel_lonlat(H, W)[1]
        out["depth"] = out["depth"] * (1 + 0.25 * torch.cos(lat) ** 2)
        return out


def _planarity_error(depth: torch.Tensor, truth: torch.Tensor) -> float:
    """Mean relative depth error after the one global scale (which normals cannot tell)."""
    s = torch.exp((torch.log(truth) - torch.log(depth)).median())
    return float(((depth * s - truth).abs() / truth).mean())


def test_predicted_depth_is_refined_to_follow_plausible_normals():
    gm = BentGM()
    dark_top = lamp_panorama().flip(-2)
    out, report = inference.predict_with_report(dark_top, model=StubModel(gm), outputs=("depth", "normal"),
                                                probes=None)
    with torch.no_grad():
        raw = gm(dark_top[None])["depth"][0]
    truth = box_room(H, W, LO, HI)[0].float().flip(-2)
    assert report.depth_refined and out.meta["predict.depth"] == "refined by the normals"
    # (at predict's anchor the depth keeps part of a bend this global: 0.046 vs 0.070)
    assert _planarity_error(out.depth, truth) < 0.75 * _planarity_error(raw, truth)
    # the normal layer is the network's (exact box normals: level and plumb already), and the depth
    # now agrees with it
    assert torch.allclose(out.normal, gm(dark_top[None])["normal"][0], atol=1e-6)
    after = float(angle_deg(pano.normals_from_depth(out.depth), out.normal).mean())
    before = float(angle_deg(pano.normals_from_depth(raw), out.normal).mean())
    assert after < 0.5 * before, (after, before)
    # refine_depth=False: GMNet's depth as it came
    plain, report = inference.predict_with_report(dark_top, model=StubModel(gm), outputs=("depth",),
                                                  probes=None, refine_depth=False)
    assert not report.depth_refined and torch.allclose(plain.depth, raw)


def test_collapsed_normals_leave_a_levelled_depth_and_its_normals():
    """The fallback: the depth's own normals, gravity-snapped, refine a bowl-shaped depth a few times
    (floors level out), and the normal layer comes from that depth; a given depth is never touched."""
    gm = BentGM(collapse_both=True)
    out, report = inference.predict_with_report(lamp_panorama(), model=StubModel(gm),
                                                outputs=("depth", "normal"), probes=None)
    with torch.no_grad():
        raw = gm(lamp_panorama()[None])["depth"][0]
    assert report.normals_from == "depth" and report.depth_refined
    truth, truth_n = (x.float() for x in box_room(H, W, LO, HI))
    lat = torch.rad2deg(pano.pixel_lonlat(H, W)[1])
    band = (lat < -20) & (lat > -65)  # the floor, where the bowl tilts the depth's normals
    tilt = lambda n: angle_deg(n, truth_n)[band].mean()  # noqa: E731
    plain = pano.normals_from_depth(raw)
    assert float(tilt(out.normal)) < 0.5 * float(tilt(plain)), (tilt(out.normal), tilt(plain))
    assert _planarity_error(out.depth, truth) < _planarity_error(raw, truth)
    given = PanoScene(image=lamp_panorama().flip(-2), depth=torch.full((1, H, W), 2.0))
    out, report = inference.predict_with_report(given, model=StubModel(BentGM()), outputs=("normal",),
                                                probes=None)
    assert not report.depth_refined and torch.equal(out.depth, given.depth)


class BumpyNadirGM(StubGM):
    """Exact box-room geometry but for the floor straight below the camera, its depth bumped by ±7 %
    around the nadir (what the network gave a patterned rug there)."""

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        out = super().forward(x)
        lon, lat = pano.pixel_lonlat(H, W)
        out["depth"] = out["depth"] * (1 + 0.07 * torch.sin(5 * lon) * (lat < math.radians(-84)))
        return out


def test_predict_puts_the_floor_under_the_camera_on_the_floor_around_it():
    gm = BumpyNadirGM()
    dark_top = lamp_panorama().flip(-2)
    out, report = inference.predict_with_report(dark_top, model=StubModel(gm), outputs=("depth", "normal"),
                                                probes=None)
    truth = box_room(H, W, LO, HI)[0].float().flip(-2)  # the stub's mirrored room: floor 1.3 m down
    with torch.no_grad():
        raw = gm(dark_top[None])["depth"][0]
    cap = pano.pixel_lonlat(H, W)[1] < math.radians(-84)

    def cap_error(d: torch.Tensor) -> float:
        return float(((d - truth).abs() / truth)[0][cap].max())

    assert report.floor_height is not None and abs(report.floor_height - HI[1]) < 0.01 * HI[1]
    assert out.meta["predict.floor_height"] == f"{report.floor_height:.4g}"
    assert cap_error(raw) > 0.06 and cap_error(out.depth) < 0.01


def test_normals_facing_away_from_the_camera_take_the_depths():
    """A patch of the ceiling predicted as floor ("up" above the camera: a dome read as a floor)
    faces away from the camera: those pixels take the depth's normals, the rest is untouched."""
    depth, normal = box_room(H, W, LO, HI)
    depth, normal = depth.float()[None], normal.float()[None]
    bad = normal.clone()
    bad[:, :, 2:6, 10:30] = torch.tensor([0.0, 1.0, 0.0])[:, None, None]  # ceiling rows, "up"
    fixed = plausible.facing_camera(bad, depth)
    d = pano.directions(H, W)
    assert bool(((fixed[0] * d).sum(0) <= 0).all()), "every pixel faces the camera"
    assert torch.equal(fixed[..., 6:, :], bad[..., 6:, :]) and torch.equal(fixed[..., :2, :], bad[..., :2, :])
    patch = angle_deg(fixed[0, :, 2:6, 10:30], normal[0, :, 2:6, 10:30])
    assert float(patch.median()) < 5  # the depth's normals: the ceiling's -y
    assert torch.equal(plausible.facing_camera(normal, depth), normal)
