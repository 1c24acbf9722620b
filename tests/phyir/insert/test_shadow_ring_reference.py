"""The pieces of the floor-ring shadow reference (phyir.insert.reference, used by
benchmarks.shadow_ring_reference) against closed forms: a sphere's form factor seen from a floor point,
and the irradiance of uniform light."""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.insert import reference as ref


def test_sphere_occlusion_gives_the_form_factor_of_a_sphere_above_a_floor_point():
    # a sphere of radius r whose centre is at height r and distance D from the point: F = (r / D)^3
    h, w = 64, 128
    dirs = pano.directions(h, w, dtype=torch.float64)
    omega = pano.solid_angles(h, w, dtype=torch.float64)
    r = 0.15
    for d in (0.15, 0.2, 0.3):
        cover, normal = ref.sphere_occlusion(torch.zeros(1, 3, dtype=torch.float64), dirs,
                                             torch.tensor([d, r, 0.0], dtype=torch.float64), r)
        ff = float((cover[0] * dirs[1].clamp_min(0) * omega).sum() / math.pi)
        assert abs(ff / (r / math.hypot(d, r)) ** 3 - 1) < 0.01
        hit = cover[0] > 0.99  # the hit normals face the point: their mean points back along -x, -y
        assert (normal[0, 0][hit] < 0.2).all() and float(normal[0, 1][hit].mean()) < 0


def test_irradiance_of_uniform_light_is_pi_whatever_the_normal():
    normals = torch.nn.functional.normalize(torch.randn(2, 3, 4, 5, dtype=torch.float64), dim=1)
    e = ref.irradiance_towards(torch.ones(3, 16, 32), normals)
    assert torch.allclose(e, torch.full_like(e, math.pi), rtol=0.01)
