"""GMNet's geometry made plausible and consistent before predict upsamples it.

Real rooms unlike the training data can collapse the normal head (the whole panorama "up"), and a
network's depth comes out bowl-shaped or bumpy where its normals would say flat. What holds in any
panorama from an upright camera corrects both: a surface the camera sees faces the camera
(:func:`away_share`, :func:`plausible_gmnet`), floors are level and walls plumb
(:func:`phyir.geometry.gravity.snap_normals`), depth and normals agree
(:func:`phyir.geometry.depth_normal.refine_depth`) and straight below the camera is the floor it
stands on (:func:`phyir.geometry.gravity.floor_under_camera`).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import Tensor

from phyir import pano
from phyir.geometry.depth_normal import refine_depth
from phyir.geometry.gravity import LEVEL_DEG_FROM_DEPTH, floor_under_camera, snap_normals

# A surface the camera sees faces the camera.  A normal layer with more than this share of its pixels
# (solid-angle weighted) facing away has collapsed (the whole panorama "up": real rooms unlike the
# training data) and is replaced by the normals of the predicted depth.
MAX_AWAY_SHARE = 0.05
# depth-normal refinement (phyir.geometry.depth_normal.refine_depth), chosen on 10 synthetic rooms of
# seed 7000 (benchmarks/depth_normal_refine.py; checked on 20 others): reach ~ 1/sqrt(anchor) = 18 px, steps
# further than ~0.02 in log depth from the normals' are occlusions
REFINE_ANCHOR = 3e-3
REFINE_TAU = 0.02
FALLBACK_PASSES = 4  # refinement passes when the normals come from the depth (the fallback)


def away_share(normal: Tensor) -> float:
    """Solid-angle share of normals ``[3,H,W]`` that face away from the camera (impossible for the
    visible surfaces a panorama shows)."""
    H, W = normal.shape[-2:]
    d = pano.directions(H, W, normal.device, normal.dtype)
    omega = pano.solid_angles(H, W, normal.device, normal.dtype)
    away = ((normal * d).sum(0) > 0).to(omega.dtype)
    return float((away * omega).sum() / omega.sum())


def collapsed(away: float) -> bool:
    """Whether a normal layer with an :func:`away_share` of ``away`` has collapsed (more than
    :data:`MAX_AWAY_SHARE` faces away from the camera)."""
    return away > MAX_AWAY_SHARE


def depth_normals(depth: Tensor) -> Tensor:
    """Gravity-snapped normals of a predicted depth ``[...,1,H,W]`` (the wider tolerance: normals
    differentiated from a network's depth scatter far more than its own)."""
    return snap_normals(pano.normals_from_depth(depth), level_deg=LEVEL_DEG_FROM_DEPTH)


def facing_camera(normal: Tensor, depth: Tensor) -> Tensor:
    """Normals ``[...,3,H,W]`` whose pixels that face away from the camera (impossible for a surface it
    sees: a dome or a skylight the network took for a floor) take the normals of ``depth
    [...,1,H,W]`` instead; the others are kept."""
    H, W = normal.shape[-2:]
    away = (normal * pano.directions(H, W, normal.device, normal.dtype)).sum(-3, keepdim=True) > 0
    if not bool(away.any()):
        return normal
    return torch.where(away, depth_normals(depth).to(normal.dtype), normal)


def unflip(out: dict[str, Tensor]) -> dict[str, Tensor]:
    """GMNet's outputs for an upside-down input, back in the upright frame (y -> -y)."""
    out = {k: v.flip(-2) for k, v in out.items()}
    if "normal" in out:
        flip_y = torch.tensor([1.0, -1.0, 1.0], device=out["normal"].device)[:, None, None]
        out["normal"] = out["normal"] * flip_y
    return out


def plausible_gmnet(network: Callable[[Tensor], dict[str, Tensor]],
                    xn: Tensor) -> tuple[dict[str, Tensor], str]:
    """A geometry network's layers on the input ``xn [1,3,H,W]`` and which pass they are from
    ("upright" or "mirrored").  ``network`` is GMNet (``model.gmnet``) or another network of
    :func:`phyir.estimators.geometry_networks` (its ``load``'s result).  When the normals have
    :func:`collapsed`, the network also runs on the input mirrored through the horizon (a valid room,
    floor and ceiling swapped), and the pass whose normals face the camera more is kept — all five
    layers, since a collapsed normal head means the whole pass is out of its depth."""
    gm = {k: v.float() for k, v in network(xn).items()}
    away = away_share(gm["normal"][0]) if "normal" in gm else 0.0
    if not collapsed(away):
        return gm, "upright"
    flipped = unflip({k: v.float() for k, v in network(xn.flip(-2)).items()})
    if away_share(flipped["normal"][0]) < away:
        return flipped, "mirrored"
    return gm, "upright"


def consistent_depth(depth: Tensor, normal: Tensor) -> tuple[Tensor, Tensor | None, float | None]:
    """GMNet's ``depth [1,1,H,W]`` made to follow gravity-aligned normals: floors level, walls plumb,
    planes planar, and the two layers agree; then the cap below the camera continues the level floor
    around it. Returns the depth, the snapped ``normal [1,3,H,W]`` (None where the normal head had
    collapsed: then the depth follows its own normals, re-derived :data:`FALLBACK_PASSES` times,
    each pass levelling the floor a little more, and the normal layer is to come from it) and the
    camera height :func:`phyir.geometry.gravity.floor_under_camera` used (None: not applied)."""
    depth = depth.float()  # float32 is enough (1.8e-6 from float64 on a real room) at half the time
    if not collapsed(away_share(normal[0])):
        snapped = facing_camera(snap_normals(normal.float()), depth)
        depth = refine_depth(depth, snapped, anchor=REFINE_ANCHOR, tau=REFINE_TAU)
        return floor_under_camera(depth, snapped)
    for _ in range(FALLBACK_PASSES):
        depth = refine_depth(depth, depth_normals(depth), anchor=REFINE_ANCHOR, tau=REFINE_TAU)
    depth, _, height = floor_under_camera(depth, depth_normals(depth))
    return depth, None, height
