"""GMNet / LNet / GSNet / PhyIRModel: shapes, ranges, seamless longitude, rotation equivariance,
the guided filter, extreme inputs."""

from __future__ import annotations

import pytest
import torch
from support.tiny_scenes import tiny_scene

from phyir.filters import box_sum, guided_filter
from phyir.nets import PhyIRModel
from phyir.nets import layers as nets_layers
from phyir.nets.lnet import probes_to_world
from phyir.transforms import rotate_yaw

GRID = (4, 8)
LAYERS = ("depth", "normal", "albedo", "roughness", "metallic")


pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def lite() -> PhyIRModel:
    torch.manual_seed(0)
    m = PhyIRModel("lite").eval()
    with torch.no_grad():  # livelier random probes than the near-constant initial head
        m.lnet.head[-1].weight.mul_(20)
    return m


@pytest.fixture(scope="module")
def image() -> torch.Tensor:
    return tiny_scene(3, 64, 128).image[None]


def _check_ranges(scene, B, H, W, grid, probe_size):
    assert scene.image.shape == (B, 3, H, W)
    scene.validate()  # shapes, finiteness, ranges, unit normals
    assert scene.depth.min() > 0
    for k in ("albedo", "roughness", "metallic"):
        t = getattr(scene, k)
        assert 0 < t.min() and t.max() < 1, k
    n = torch.linalg.vector_norm(scene.normal, dim=1)
    assert torch.allclose(n, torch.ones_like(n), atol=1e-5)
    assert scene.probes.shape == (B, *grid, 3, *probe_size)
    assert scene.probes.min() > 0


def test_lite_shapes_and_ranges(lite, image):
    x = torch.cat((image, 0.5 * image))
    with torch.no_grad():
        out = lite(x, GRID)
    _check_ranges(out, 2, 64, 128, GRID, (16, 32))
    # default grid: one probe per probe_block x probe_block pixels
    with torch.no_grad():
        out = lite(image)
    assert out.probe_grid == (64 // 16, 128 // 16)


def test_full_shapes_and_ranges(image):
    torch.manual_seed(0)
    m = PhyIRModel("full").eval()
    # the paper's widths: ResNet-18 trunk 11.2 M (no fc), decoders 3.1 M each, LNet head 512->1536
    assert 26e6 < sum(p.numel() for p in m.gmnet.parameters()) < 28e6
    assert m.lnet.head[-1].out_channels == 16 * 32 * 3
    with torch.no_grad():
        out = m(image, GRID)
    _check_ranges(out, 1, 64, 128, GRID, (16, 32))


def _seam_ratio(t: torch.Tensor) -> float:
    """Mean |jump| across the seam (last -> first column) over the median interior column jump."""
    seam = (t[..., 0] - t[..., -1]).abs().mean()
    interior = (t[..., 1:] - t[..., :-1]).abs().mean(dim=tuple(range(t.dim() - 1)))
    return float(seam / interior.median())


def _outputs(model, image):
    with torch.no_grad():
        out = model(image, GRID)
    res = {k: getattr(out, k) for k in LAYERS}
    res["probe grid"] = out.probes.movedim(2, -1).flatten(-3)  # [B, Hp, 3*h*w, Wp]: across the grid
    return res


def test_seam_is_continuous_for_every_output(lite, image):
    """The input is a real (seamless) panorama: the outputs jump across the seam no more than
    between typical neighbouring columns (measured: 0.5-1.7 x the median jump)."""
    for name, t in _outputs(lite, image).items():
        assert _seam_ratio(t) < 3.0, name


def test_seam_check_fails_with_zero_padding(image, monkeypatch):
    """Negative control: the same networks with zero padding have a seam (measured: 7-28 x)."""
    monkeypatch.setattr(nets_layers.CircConv2d, "forward", lambda self, x: torch.nn.functional.conv2d(
        torch.nn.functional.pad(x, self.circ), self.weight, self.bias, self.stride))
    torch.manual_seed(0)
    m = PhyIRModel("lite").eval()
    out = _outputs(m, image)
    assert min(_seam_ratio(out[k]) for k in LAYERS) > 5.0


@pytest.mark.parametrize("shift", [32, 64])
def test_rotating_input_rotates_outputs(lite, image, shift):
    """Rolling the input by whole multiples of the total stride (32 columns) rotates every output as
    phyir.transforms.rotate_yaw does: layers rolled, normals and probes rotated about +y."""
    with torch.no_grad():
        a = lite(image, GRID)
        b = lite(torch.roll(image, shift, dims=-1), GRID)
    ra = rotate_yaw(a, shift)
    for k in (*LAYERS, "probes"):
        want, got = getattr(ra, k), getattr(b, k)
        assert (want - got).abs().max() < 1e-4 * (1 + want.abs().max()), k
    # and the rotation is not trivial: the outputs really moved
    assert (a.albedo - b.albedo).abs().max() > 1e-2
    assert (a.normal - b.normal).abs().max() > 1e-2


def test_probes_to_world_rolls_each_grid_column():
    local = torch.arange(2 * 4 * 3 * 2 * 8, dtype=torch.float32).reshape(1, 2, 4, 3, 2, 8)
    world = probes_to_world(local)
    for b in range(4):  # offset (b + 0.5) * 8 / 4 - 4 = 2b - 3 texels
        assert torch.equal(world[..., b, :, :, :], torch.roll(local[..., b, :, :, :], 2 * b - 3, dims=-1))


def test_box_sum_matches_brute_force():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 7, 12, generator=g, dtype=torch.float64)
    r = 2
    ref = torch.zeros_like(x)
    for i in range(7):
        for j in range(12):
            for di in range(-r, r + 1):
                for dj in range(-r, r + 1):
                    if 0 <= i + di < 7:
                        ref[:, i, j] += x[:, i + di, (j + dj) % 12]
    assert torch.allclose(box_sum(x, r), ref, atol=1e-12)


def test_guided_filter_properties():
    g = torch.Generator().manual_seed(1)
    src = torch.rand(1, 2, 16, 32, generator=g, dtype=torch.float64)
    guide = torch.rand(1, 1, 16, 32, generator=g, dtype=torch.float64)
    # a guide equal to the (one-channel) source with tiny eps reproduces the source
    one = src[:, :1]
    assert torch.allclose(guided_filter(one, one, 1e-10), one, atol=1e-5)
    # a constant guide reduces to a box filter applied twice (mean of the window means)
    flat = torch.full_like(guide, 0.5)
    from phyir.filters import box_mean
    assert torch.allclose(guided_filter(flat, src, 1e-3), box_mean(box_mean(src, 2), 2), atol=1e-12)
    # circular in longitude: filtering commutes with rolling the columns
    a = torch.roll(guided_filter(guide, src, 1e-2), 5, dims=-1)
    b = guided_filter(torch.roll(guide, 5, dims=-1), torch.roll(src, 5, dims=-1), 1e-2)
    assert torch.allclose(a, b, atol=1e-12)
    # differentiable with respect to guide, source and a per-pixel eps
    eps = torch.full_like(guide, 1e-2).requires_grad_()
    gg, ss = guide.clone().requires_grad_(), src.clone().requires_grad_()
    guided_filter(gg, ss, eps).sum().backward()
    assert all(t.grad is not None and t.grad.abs().sum() > 0 for t in (gg, ss, eps))


@pytest.mark.parametrize("kind", ["black", "bright", "ldr_saturated", "nonfinite"])
def test_extreme_inputs_give_finite_outputs(lite, kind):
    H, W = 64, 128
    g = torch.Generator().manual_seed(0)
    x = {"black": torch.zeros(3, H, W), "bright": torch.full((3, H, W), 1e5),
         "ldr_saturated": torch.where(torch.rand(3, H, W, generator=g) < 0.7, 1.0, 0.95),
         "nonfinite": torch.rand(3, H, W, generator=g)}[kind]
    if kind == "nonfinite":
        x[0, :4] = float("inf")
    out = lite.predict(x, grid=GRID)
    for name, t in out.layers():
        assert torch.isfinite(t).all(), name
    assert torch.isfinite(out.probes).all() and (out.probes >= 0).all()
    out.validate()


def test_predict_returns_probes_in_input_units(lite, image):
    a = lite.predict(image[0], grid=GRID)
    b = lite.predict(8.0 * image[0], grid=GRID)
    assert torch.allclose(b.probes, 8.0 * a.probes, rtol=1e-4)
    assert torch.allclose(b.depth, a.depth, rtol=1e-5) and torch.allclose(b.albedo, a.albedo, atol=1e-6)


def test_sizes_that_dont_fit_the_stride(lite):
    with pytest.raises(ValueError, match="multiples of 32"):
        lite(torch.rand(1, 3, 48, 96))
    out = lite.predict(torch.rand(3, 50, 100), grid=GRID)  # run at 64x128, resampled back
    assert out.size == (50, 100) and out.depth.shape == (1, 50, 100)
    out.validate()
