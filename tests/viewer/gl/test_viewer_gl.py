"""The viewer's shaders on a headless EGL context, against phyir.pano and numpy references."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from phyir import pano
from phyir.color import linear_to_srgb

moderngl = pytest.importorskip("moderngl")

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def renderer(ctx):
    from viewer.renderer import Renderer

    return Renderer(ctx)


def run_mapping(ctx, mode: int, size: tuple[int, int], dirs: np.ndarray | None = None,
                persp=(1.0, 0.0, 0.0)) -> np.ndarray:
    """Evaluate shaders/mapping_check.frag; returns H x W x 4 float32 (rows from the top for modes
    0/2, rows in upload order for mode 1)."""
    from viewer.gl import glsl

    W, H = size
    prog = glsl.program(ctx, "fullscreen.vert", "mapping_check.frag", {"MODE": mode})
    out = ctx.texture((W, H), 4, dtype="f4")
    fbo = ctx.framebuffer([out])
    if "size" in prog:
        prog["size"] = (float(W), float(H))
    if "persp" in prog:
        prog["persp"] = persp
    tex = None
    if dirs is not None:
        tex = ctx.texture((W, H), 3, np.ascontiguousarray(dirs, np.float32), dtype="f4")
        tex.use(0)
        prog["dirs"] = 0
    fbo.use()
    ctx.vertex_array(prog, []).render(vertices=3)
    a = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
    for r in (fbo, out, prog) + ((tex,) if tex else ()):
        r.release()
    return a if mode == 1 else a[::-1]


def test_glsl_uv_to_dir_matches_pano(ctx):
    H, W = 64, 128
    got = run_mapping(ctx, 0, (W, H))[..., :3]
    want = pano.directions(H, W).permute(1, 2, 0).numpy()
    assert np.abs(got - want).max() < 2e-6


def test_glsl_dir_to_uv_matches_pano(ctx):
    H, W = 48, 96
    g = torch.Generator().manual_seed(7)
    d = torch.nn.functional.normalize(torch.randn(H, W, 3, generator=g, dtype=torch.float64), dim=-1)
    d = d[torch.abs(d[..., 1]) < 0.999].reshape(-1, 3)[: H * W]
    d = torch.cat([d, d[: H * W - len(d)]]).reshape(H, W, 3)
    got = run_mapping(ctx, 1, (W, H), d.numpy())
    u, v = pano.dir_to_uv(d, H, W, dim=-1)
    du = np.abs(got[..., 0] - u.numpy())
    du = np.minimum(du, W - du)  # the seam: u = 0 and u = W are the same column
    assert du.max() < 1e-3 and np.abs(got[..., 1] - v.numpy()).max() < 1e-3


@pytest.mark.parametrize("fov,yaw,pitch", [(60.0, 0.0, 0.0), (90.0, 1.1, -0.4), (30.0, -2.5, 0.8)])
def test_glsl_perspective_dirs_match_pano(ctx, fov, yaw, pitch):
    H, W = 36, 64
    got = run_mapping(ctx, 2, (W, H), persp=(math.radians(fov), yaw, pitch))[..., :3]
    want = pano.perspective_dirs(H, W, fov, yaw, pitch, dtype=torch.float64).permute(1, 2, 0).numpy()
    assert np.abs(got - want).max() < 2e-6


def test_view_math_mirrors_pano(ctx):
    """phyir/insert/views.py (hover, clicks, markers) uses the same cameras as the shaders."""
    from phyir.insert.views import EquirectView, PerspectiveView

    v = PerspectiveView(fov=70.0, yaw=0.7, pitch=-0.3)
    H, W = 30, 50
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    d = v.screen_to_dir(xs, ys, (W, H))
    want = pano.perspective_dirs(H, W, 70.0, 0.7, -0.3, dtype=torch.float64).permute(1, 2, 0).numpy()
    assert np.abs(d - want).max() < 1e-12
    u, vv = v.screen_to_uv(xs, ys, (W, H), (256, 512))
    x, y, front = v.uv_to_screen(u, vv, (W, H), (256, 512))
    assert front.all() and np.abs(x - xs).max() < 1e-6 and np.abs(y - ys).max() < 1e-6
    e = EquirectView(center=(100.0, 40.0), zoom=3.0)
    u, vv = e.screen_to_uv(xs, ys, (W, H))
    x, y, _ = e.uv_to_screen(u, vv, (W, H))
    assert np.allclose(x, xs) and np.allclose(y, ys)
    e.zoom_about(2.0, (W, H), (10.0, 20.0))
    assert np.allclose(e.screen_to_uv(10.0, 20.0, (W, H)), (100 + (10 - 25) / 3, 40 + (20 - 15) / 3))


def test_perspective_matrices_project_onto_the_pixels():
    """For meshes (object insertion): projection @ view maps a point seen through a pixel to it."""
    from phyir.insert.views import PerspectiveView

    v = PerspectiveView(fov=65.0, yaw=-0.8, pitch=0.35)
    W, H = 64, 40
    ys, xs = np.mgrid[0:H, 0:W] + 0.5
    pts = 2.5 * v.screen_to_dir(xs, ys, (W, H))
    clip = np.einsum("ij,hwj->hwi", v.projection_matrix((W, H)) @ v.view_matrix(),
                     np.concatenate([pts, np.ones((H, W, 1))], -1))
    ndc = clip[..., :3] / clip[..., 3:]
    assert np.allclose((ndc[..., 0] + 1) * W / 2, xs) and np.allclose((1 - ndc[..., 1]) * H / 2, ys)
    assert (np.abs(ndc[..., 2]) < 1).all()


def layer_values(renderer, layer: np.ndarray, view, size, view_wh, nearest=False) -> np.ndarray:
    """Linear values of the layer pass (two-pass path, so they can be read back as floats)."""
    from viewer.renderer import Display, Frame

    ctx = renderer.ctx
    tex = renderer.texture(layer)
    target = ctx.simple_framebuffer(view_wh)
    renderer.linear_passes.append(lambda r, f: None)
    try:
        renderer.render(target, (0, 0, *view_wh), Frame(texture=tex, pano_size=size, view=view,
                                                        display=Display(), nearest=nearest))
        return renderer.read_linear()
    finally:
        renderer.linear_passes.pop()
        tex.release()
        target.release()


def smooth_pano(H: int, W: int) -> np.ndarray:
    d = pano.directions(H, W, dtype=torch.float64).numpy()
    return np.stack([1 + d[0], 1 + 0.5 * d[1], 1 + np.sin(3 * d[2]) * 0.5], -1).astype(np.float32)


def test_equirect_view_at_one_to_one_shows_every_texel(renderer):
    from phyir.insert.views import EquirectView

    H, W = 32, 64
    rng = np.random.default_rng(3)
    img = rng.random((H, W, 3), dtype=np.float32)
    v = EquirectView()
    v.fit((W, H), (H, W))
    assert v.zoom == 1.0
    for nearest in (False, True):
        got = layer_values(renderer, img, v, (H, W), (W, H), nearest)
        assert np.array_equal(got[..., :3], img) and (got[..., 3] == 1).all()


def test_equirect_view_zoomed_nearest_repeats_texels(renderer):
    from phyir.insert.views import EquirectView

    H, W = 16, 32
    img = np.random.default_rng(4).random((H, W, 1), dtype=np.float32)
    v = EquirectView(center=(W / 2, H / 2), zoom=4.0)
    got = layer_values(renderer, img, v, (H, W), (W * 4, H * 4), nearest=True)[..., 0]
    assert np.array_equal(got, np.kron(img[..., 0], np.ones((4, 4), np.float32)))
    # outside the panorama: coverage 0
    v = EquirectView(center=(W / 2, H / 2), zoom=0.5)
    got = layer_values(renderer, img, v, (H, W), (W, H * 2))
    assert (got[: H // 2 - 2, :, 3] == 0).all()
    assert (got[H - 2 : H + 2, W // 4 + 2 : 3 * W // 4 - 2, 3] == 1).all()


@pytest.mark.parametrize("fov,yaw,pitch", [(75.0, 0.0, 0.0), (100.0, 2.0, 0.5)])
def test_perspective_view_matches_pano_perspective_crop(renderer, fov, yaw, pitch):
    from phyir.insert.views import PerspectiveView

    H, W = 128, 256
    img = smooth_pano(H, W)
    h, w = 60, 80
    got = layer_values(renderer, img, PerspectiveView(fov=fov, yaw=yaw, pitch=pitch), (H, W), (w, h))
    want = pano.perspective_crop(torch.from_numpy(img).permute(2, 0, 1).double(), h, w, fov, yaw, pitch)
    err = np.abs(got[..., :3] - want.permute(1, 2, 0).numpy())
    assert err.max() < 2e-3, err.max()


# ---------------------------------------------------------------------------------------------
# display transforms vs numpy


def aces(x):
    x = np.maximum(x, 0)
    return np.clip((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0, 1)


def lut_lookup(lut: np.ndarray, t: np.ndarray) -> np.ndarray:
    x = np.clip(t, 0, 1) * (len(lut) - 1)
    return np.stack([np.interp(x, np.arange(len(lut)), lut[:, c]) for c in range(3)], -1)


def displayed(renderer, values: np.ndarray, display) -> np.ndarray:
    """uint8 colours of an H x W x C value image shown 1:1 (one-pass path)."""
    from phyir.insert.views import EquirectView
    from viewer.renderer import Frame

    H, W = values.shape[:2]
    tex = renderer.texture(values)
    target = renderer.ctx.simple_framebuffer((W, H))
    v = EquirectView(center=(W / 2, H / 2), zoom=1.0)
    renderer.render(target, (0, 0, W, H), Frame(texture=tex, pano_size=(H, W), view=v, display=display,
                                                nearest=True))
    out = renderer.read(target)
    tex.release()
    target.release()
    return out.astype(np.float64)


HDR_VALUES = np.concatenate([np.zeros(1), np.geomspace(1e-4, 40.0, 127)]).astype(np.float32)


@pytest.mark.parametrize("tonemap,exposure,offset", [("srgb", 0.0, 0.0), ("srgb", 1.5, 0.02),
                                                     ("aces", -1.0, 0.0), ("aces", 2.0, -0.01)])
def test_tone_maps_match_numpy(renderer, tonemap, exposure, offset):
    from viewer.renderer import Display

    vals = np.stack([HDR_VALUES, HDR_VALUES[::-1], np.full_like(HDR_VALUES, 0.18)], -1)
    img = np.broadcast_to(vals[None], (2, len(vals), 3)).copy()
    got = displayed(renderer, img, Display(kind="hdr", tonemap=tonemap, exposure=exposure, offset=offset))
    x = img * 2.0**exposure + offset
    want = 255 * (linear_to_srgb(aces(x)) if tonemap == "aces" else linear_to_srgb(x))
    assert np.abs(got - want).max() <= 1.0


def test_false_colour_maps_log_luminance(renderer):
    from viewer.renderer import Display, colormap_lut

    lum = np.geomspace(2.0**-9, 2.0**9, 64).astype(np.float32)
    img = np.repeat(np.repeat(lum[None, :, None], 3, -1), 2, 0)
    got = displayed(renderer, img, Display(kind="hdr", tonemap="false", false_range=(-8.0, 8.0)))
    want = 255 * lut_lookup(colormap_lut("turbo"), (np.log2(img[..., 0]) + 8) / 16)
    assert np.abs(got - want).max() <= 1.5


@pytest.mark.parametrize("name", ["viridis", "magma", "gray", "turbo"])
def test_colour_maps_and_range(renderer, name):
    from viewer.renderer import Display, colormap_lut

    vals = np.linspace(-1.0, 5.0, 97, dtype=np.float32)  # beyond the range on both sides
    img = np.repeat(vals[None, :, None], 2, 0)
    got = displayed(renderer, img, Display(kind="scalar", colormap=name, range=(0.5, 3.5)))
    lut = colormap_lut(name)
    t = (vals - 0.5) / 3.0
    assert np.abs(got - 255 * lut_lookup(lut, t)[None]).max() <= 1.5
    if name in ("viridis", "magma", "gray"):  # perceptually ordered maps: brightness follows value
        lum = got[0] @ [0.2126, 0.7152, 0.0722]
        inside = (t > 0.02) & (t < 0.98)
        assert np.all(np.diff(lum[inside]) >= -0.5)
        assert lum[t <= 0].std() < 0.5 and lum[t >= 1].std() < 0.5  # clamped outside the range


def test_normals_and_colours_display(renderer):
    from viewer.renderer import Display

    n = np.array([[[1, 0, 0], [0, -1, 0], [0.6, 0, 0.8]]], np.float32)
    got = displayed(renderer, n, Display(kind="normal"))
    assert np.abs(got - 255 * (0.5 * n + 0.5)).max() <= 1.0
    c = np.array([[[0.0, 0.5, 1.0], [0.2, 0.002, 0.7]]], np.float32)
    got = displayed(renderer, c, Display(kind="colour", exposure=3.0))  # exposure ignored
    assert np.abs(got - 255 * linear_to_srgb(c)).max() <= 1.0


def test_markers_are_rings_at_their_positions(renderer):
    from phyir.insert.views import EquirectView
    from viewer.renderer import Display, Frame, Marker

    H, W = 64, 128
    tex = renderer.texture(np.zeros((H, W, 3), np.float32))
    target = renderer.ctx.simple_framebuffer((W, H))
    frame = Frame(texture=tex, pano_size=(H, W), view=EquirectView(center=(W / 2, H / 2), zoom=1.0),
                  display=Display(), markers=[Marker(40.5, 20.5, (1.0, 0.0, 0.0))],
                  extras={"marker_radius": 8.0})
    renderer.render(target, (0, 0, W, H), frame)
    img = renderer.read(target).astype(int)
    assert img[20, 40].sum() == 0                       # centre untouched
    assert img[20, 48, 0] > 200 and img[20, 48, 1] < 50  # on the ring: red
    assert img[12, 40, 0] > 200 and img[28, 40, 0] > 200
    assert img[20, 60].sum() == 0 and img[50, 100].sum() == 0
    tex.release()
    target.release()
