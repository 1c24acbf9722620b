"""Lighting of inserted objects in torch: dominant lights, peak samples, irradiance maps, 3D probes."""

from __future__ import annotations

import math

import pytest
import torch
from support.scenes import box_room

from phyir import pano
from phyir.color import luminance
from phyir.lighting.extract import extract_lights
from phyir.lighting.object_lighting import (
    ProbeField,
    irradiance_map,
    object_lighting,
    peak_samples,
    place_lights,
)
from phyir.lighting.projection import DepthSurface


def disc_probe(h: int = 32, w: int = 64, spots=((0.3, 0.8, -0.5, 0.12, 80.0), (-0.7, 0.1, 0.7, 0.08, 30.0)),
               background: float = 0.2) -> torch.Tensor:
    """A constant background plus bright discs (direction, angular radius, radiance)."""
    d = pano.directions(h, w, dtype=torch.float64)
    env = torch.full((3, h, w), background, dtype=torch.float64)
    for x, y, z, radius, value in spots:
        c = torch.tensor([x, y, z], dtype=torch.float64)
        c = c / c.norm()
        inside = (d * c[:, None, None]).sum(0) > math.cos(radius)
        env = torch.where(inside, torch.tensor(value, dtype=torch.float64), env)
    return env.float()


def power_of(env: torch.Tensor) -> torch.Tensor:
    return (env * pano.solid_angles(*env.shape[-2:])).sum((1, 2))


def test_extract_finds_the_discs_and_conserves_energy():
    env = disc_probe()
    lights, residual = extract_lights(env)
    assert len(lights) == 2
    want = [torch.tensor(s[:3]) / torch.tensor(s[:3]).norm() for s in ((0.3, 0.8, -0.5), (-0.7, 0.1, 0.7))]
    for lt, w in zip(lights, want):  # strongest first
        assert math.degrees(math.acos(float((lt.direction * w).sum().clamp(max=1)))) < 4.0
    total = power_of(env)
    got = power_of(residual) + sum(lt.power for lt in lights)
    torch.testing.assert_close(got, total, rtol=1e-5, atol=1e-6)
    # the residual keeps the background and only the spot's base level
    assert float(residual.max()) < 4 * 0.2 * 4 + 1e-6
    # a disc's power: its radiance above the threshold level times its solid angle
    assert float(lights[0].power[0]) > float(lights[1].power[0]) > 0
    assert lights[0].spread == pytest.approx(0.12, rel=0.5)


def test_uniform_probe_has_no_lights_and_weak_ones_fade():
    lights, residual = extract_lights(torch.full((3, 16, 32), 0.7))
    assert lights == [] and torch.equal(residual, torch.full((3, 16, 32), 0.7))
    # a spot carrying ~3% of the power fades part-way; its lost share returns to the residual
    env = disc_probe(spots=((0.0, 1.0, 0.0, 0.12, 20.0),), background=1.0)
    lights, residual = extract_lights(env)
    assert len(lights) == 1 and 0.02 < lights[0].fraction < 0.08
    full, _ = extract_lights(env, min_fraction=0.0, full_fraction=1e-6)
    assert float(lights[0].power.sum()) < float(full[0].power.sum())
    torch.testing.assert_close(power_of(residual) + lights[0].power, power_of(env), rtol=1e-5, atol=1e-6)


def test_extraction_is_continuous_in_the_probe():
    env = disc_probe()
    a, _ = extract_lights(env)
    noise = torch.rand(env.shape, generator=torch.Generator().manual_seed(0))
    b, _ = extract_lights(env * (1 + 1e-3 * noise))
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert float((x.power - y.power).abs().max() / x.power.abs().max()) < 5e-3
        assert float((x.direction - y.direction).norm()) < 5e-3


def test_peak_samples_plus_residual_is_the_probe():
    env = disc_probe(16, 32, spots=((0.3, 0.8, -0.5, 0.35, 80.0), (-0.7, 0.1, 0.7, 0.2, 30.0)))
    dirs, power, residual = peak_samples(env, max_texels=8)
    assert dirs.shape == (32, 3) and power.shape == (32, 3)
    torch.testing.assert_close(dirs.norm(dim=1), torch.ones(32))
    # energy: residual texels x solid angle + samples = the probe's (the tent integrates to a texel)
    torch.testing.assert_close(power_of(residual) + power.sum(0), power_of(env), rtol=2e-3, atol=1e-4)
    # the samples sit around the brightest spot
    c = torch.tensor([0.3, 0.8, -0.5]) / torch.tensor([0.3, 0.8, -0.5]).norm()
    assert float((dirs @ c).max()) > 0.98


def test_irradiance_map_is_exact_for_constants_and_a_cosine_lobe():
    torch.testing.assert_close(irradiance_map(torch.full((3, 16, 32), 2.0)), torch.full((3, 32, 64), 2.0))
    # radiance = max(0, y): irradiance / pi facing up is 2/3, facing sideways 2 / (3 pi) (analytic)
    d = pano.directions(16, 32)
    env = d[1].clamp(min=0).expand(3, 16, 32)
    irr = irradiance_map(env)
    up = pano.sample_dir(irr, torch.tensor([0.0, 1.0, 0.0]))
    side = pano.sample_dir(irr, torch.tensor([1.0, 0.0, 0.0]))
    assert float(up[0]) == pytest.approx(2 / 3, rel=0.01)
    assert float(side[0]) == pytest.approx(2 / (3 * math.pi), rel=0.02)


def test_probe_field_interpolates_continuously_and_places_lights():
    room = box_room(32, 64, grid=(4, 8), probe_size=(8, 16))
    field = ProbeField(room)
    p0 = torch.tensor([0.3, -1.2, -1.5])
    idx, w = field.weights(p0)
    assert w.sum() == pytest.approx(1.0) and (w >= 0).all() and len(idx) == 8
    a = field.probe_at(p0)
    b = field.probe_at(p0 + torch.tensor([1e-3, 0.0, 0.0]))
    assert float((a - b).abs().max() / a.abs().max()) < 5e-3
    # at a probe's own position the nearest probe dominates
    q = field.positions[5].float()
    idx, w = field.weights(q)
    assert int(idx[torch.argmax(w)]) == 5
    # the lamp is on the ceiling: its light sits on the depth surface above the object
    lights, _ = extract_lights(a)
    placed, reach = place_lights(lights, p0, DepthSurface.from_scene(room), radius=0.2)
    top = max(placed, key=lambda pl: float(luminance(pl.light.power, dim=0)))
    assert float(top.position[1]) == pytest.approx(1.5, abs=0.15)


def test_support_shadowed_darkens_the_floor_under_a_sphere():
    """Uniform light, a sphere of radius r resting on a plane: the floor point seen at angle t from
    straight down keeps 1 - cos^3 t of its light (form factor of the sphere there), so the cosine-
    weighted mean straight down is 1 - 2/5; upward the cube is unchanged."""
    from phyir.lighting.object_lighting import AXES, irradiance_at, support_shadowed

    probe = torch.ones(3, 64, 128)
    ambient = irradiance_at(probe, AXES)
    centre = torch.tensor([0.3, 0.5, -1.0])
    plane = (torch.tensor([0.0, 0.0, 0.0]), torch.tensor([0.0, 1.0, 0.0]))
    cube = support_shadowed(probe, probe, centre, 0.5, plane, ambient, [])
    assert cube[3].mean() == pytest.approx(0.6, abs=0.02)  # -y
    assert cube[2].mean() == pytest.approx(1.0, abs=1e-4)  # +y
    assert 0.6 < float(cube[0].mean()) < 1.0  # sideways: part of the floor
    assert torch.equal(support_shadowed(probe, probe, centre, 0.5, None, ambient, []), ambient)


def test_dragged_object_keeps_its_lights_where_they_are(monkeypatch):
    """While dragging (``previous`` given) the lights keep their room positions, seen from the new
    centre, and are not marched again; past one radius from where they were marched they are."""
    import phyir.lighting.object_lighting as ol

    room = box_room(32, 64, grid=(4, 8), probe_size=(8, 16))
    field, surface = ProbeField(room), DepthSurface.from_scene(room)
    p0 = torch.tensor([0.3, -1.2, -1.5])
    first = object_lighting(field, p0, surface, radius=0.2)
    assert first.lights
    marched = []
    monkeypatch.setattr(ol, "place_lights", lambda *a, **k: marched.append(1) or place_lights(*a, **k))
    p1 = p0 + torch.tensor([0.05, 0.0, 0.0])
    moved = object_lighting(field, p1, surface, radius=0.2, previous=first)
    assert not marched
    for pl in moved.lights:
        assert any(torch.equal(pl.position, q.position) for q in first.lights)
        assert pl.distance == pytest.approx(float((pl.position - p1).norm()), rel=1e-5)
    shift = (moved.reach[-1] - first.reach[-1]).double()
    assert torch.allclose(shift, (p1 - p0).double(), atol=1e-5)  # shadow reach points follow
    assert torch.equal(moved.marched_from, first.marched_from)
    far = object_lighting(field, p0 + torch.tensor([0.25, 0.0, 0.0]), surface, radius=0.2, previous=moved)
    assert marched and torch.allclose(far.marched_from, p0 + torch.tensor([0.25, 0.0, 0.0]))
