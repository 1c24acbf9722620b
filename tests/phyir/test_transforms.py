"""Yaw rotation and mirroring keep every layer of a scene consistent with the others."""

import pytest
import torch

from phyir import PanoScene
from phyir.pano import directions, normals_from_depth, rotate_vectors, sample_dir, yaw_matrix, yaw_shift_angle
from phyir.synth.analytic import box_room
from phyir.transforms import mirror_lr, rotate_yaw

H, W = 32, 64
Hp, Wp, h, w = 4, 8, 8, 16  # probe blocks are 8 x 8 pixels; a probe column is 4 panorama columns


def box_depth(H: int, W: int) -> torch.Tensor:
    """Radial depth of an off-centre box room (phyir.synth.analytic)."""
    return box_room(H, W, (-2.0, -1.5, -2.5), (3.0, 1.2, 1.7))[0].float()


def ellipsoid_depth(H: int, W: int) -> torch.Tensor:
    """Radial depth of a smooth off-centre ellipsoidal room: |(o + t d) / axes| = 1, t > 0."""
    d = directions(H, W, dtype=torch.float64)
    axes = torch.tensor([3.0, 1.5, 2.2], dtype=torch.float64)[:, None, None]
    o = torch.tensor([0.8, -0.3, 0.5], dtype=torch.float64)[:, None, None]
    qa, qb, qc = ((d / axes) ** 2).sum(0), 2 * (o * d / axes**2).sum(0), ((o / axes) ** 2).sum(0) - 1
    return ((-qb + torch.sqrt(qb * qb - 4 * qa * qc)) / (2 * qa))[None].float()


@pytest.fixture(scope="module")
def scene() -> PanoScene:
    g = torch.Generator().manual_seed(0)
    def r(*s):
        return torch.rand(*s, generator=g)
    depth = ellipsoid_depth(H, W)
    return PanoScene(image=r(3, H, W), depth=depth, normal=normals_from_depth(depth), albedo=r(3, H, W),
                     roughness=r(1, H, W), metallic=r(1, H, W), probes=r(Hp, Wp, 3, h, w),
                     masks={"emission": r(1, H, W)}, meta={"k": "v"}).validate()


def rotated_probe(p: torch.Tensor, shift: int) -> torch.Tensor:
    """Independent reference: the probe's radiance looked up in the direction the rotation undoes."""
    m = yaw_matrix(yaw_shift_angle(shift, W), dtype=torch.float64)
    d = rotate_vectors(m.T, directions(h, w, dtype=torch.float64), dim=0)  # R^-1 d
    return sample_dir(p.double(), d).float()


def test_whole_column_shift_exact_for_pixel_layers(scene):
    for shift in (0, 1, 5, -3, W + 2):
        out = rotate_yaw(scene, shift).validate()
        for name in ("image", "depth", "albedo", "roughness", "metallic"):
            assert torch.equal(getattr(out, name), torch.roll(getattr(scene, name), shift, -1)), name
        assert torch.equal(out.masks["emission"], torch.roll(scene.masks["emission"], shift, -1))
        assert out.meta == scene.meta
    assert torch.equal(rotate_yaw(scene, 0).normal, scene.normal)


@pytest.mark.parametrize("shift", [1, 7, 16, -21])
def test_rotated_normals_match_normals_of_rotated_depth(scene, shift):
    out = rotate_yaw(scene, shift)
    assert torch.allclose(out.normal, normals_from_depth(out.depth), atol=2e-5)
    # and they really turned: the box is off-centre, so rolled but unrotated normals differ
    assert not torch.allclose(out.normal, torch.roll(scene.normal, shift, -1), atol=1e-2)


def test_rotated_box_room_normals(scene):
    """Creases: only pixels where the two sides tie (a few in a thousand) may flip to the other face."""
    box = scene.replace(depth=box_depth(H, W), normal=normals_from_depth(box_depth(H, W)))
    for shift in (1, 7, -21):
        out = rotate_yaw(box, shift)
        off = (out.normal - normals_from_depth(out.depth)).norm(dim=0) > 2e-5
        assert off.float().mean() < 0.005


@pytest.mark.parametrize("shift", [8, 16, -24])
def test_probes_rotate_with_whole_blocks(scene, shift):
    out = rotate_yaw(scene, shift).probes
    k = shift // (W // Wp)
    for a in range(Hp):
        for b in range(Wp):
            want = rotated_probe(scene.probes[a, b], shift)  # the probe moved k blocks along the grid
            assert torch.allclose(out[a, (b + k) % Wp], want, atol=1e-5), (a, b)


def test_probes_fractional_shift_is_linear_in_longitude(scene):
    shift = 3  # 3/8 of a block, 3/4 of a probe column: both interpolated
    out = rotate_yaw(scene, shift).probes
    f = shift * Wp / W
    for a in range(Hp):
        for b in range(Wp):
            want = (1 - f) * rotated_probe(scene.probes[a, b], shift) \
                + f * rotated_probe(scene.probes[a, b - 1], shift)
            assert torch.allclose(out[a, b], want, atol=1e-5), (a, b)


def test_rotation_composes_and_inverts(scene):
    ab = rotate_yaw(rotate_yaw(scene, 8), 24)
    direct = rotate_yaw(scene, 32)
    assert torch.equal(ab.image, direct.image)
    assert torch.allclose(ab.normal, direct.normal, atol=1e-6)
    assert torch.allclose(ab.probes, direct.probes, atol=1e-6)
    back = rotate_yaw(rotate_yaw(scene, 16), -16)
    assert torch.allclose(back.normal, scene.normal, atol=1e-6)
    assert torch.allclose(back.probes, scene.probes, atol=1e-6)
    full = rotate_yaw(scene, W)  # a full turn changes nothing
    assert torch.equal(full.image, scene.image) and torch.allclose(full.normal, scene.normal, atol=1e-6)


def test_batched_rotation_equals_per_scene(scene):
    other = scene.map(lambda t: t.flip(-2))
    batch = rotate_yaw(PanoScene.stack([scene, other]), 8)
    for i, s in enumerate((scene, other)):
        single = rotate_yaw(s, 8)
        assert torch.equal(batch[i].image, single.image)
        assert torch.allclose(batch[i].normal, single.normal)
        assert torch.allclose(batch[i].probes, single.probes)


def test_mirror(scene):
    out = mirror_lr(scene).validate()
    for name in ("image", "depth", "albedo", "roughness", "metallic"):
        assert torch.equal(getattr(out, name), getattr(scene, name).flip(-1)), name
    assert torch.allclose(out.normal, normals_from_depth(out.depth), atol=2e-5)
    twice = mirror_lr(out)
    assert torch.equal(twice.normal, scene.normal) and torch.equal(twice.probes, scene.probes)
    # a mirrored probe sees the original radiance in the mirrored direction (x -> -x)
    d = directions(h, w, dtype=torch.float64) * torch.tensor([-1.0, 1, 1], dtype=torch.float64)[:, None, None]
    for b in range(Wp):
        want = sample_dir(scene.probes[1, b].double(), d).float()
        assert torch.allclose(out.probes[1, Wp - 1 - b], want, atol=1e-5), b
