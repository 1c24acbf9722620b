"""shaders/compare.glsl against its numpy mirror viewer.compare: the difference, relative difference
and squared error read back as floats through the identity ("gray") colour map, and the split view."""

from __future__ import annotations

import numpy as np
import pytest

moderngl = pytest.importorskip("moderngl")

pytestmark = pytest.mark.gl

H, W = 32, 64


@pytest.fixture(scope="module")
def renderer(ctx):
    from viewer.renderer import Renderer

    r = Renderer(ctx)
    yield r
    r.release()


def draw(renderer, a: np.ndarray, b: np.ndarray, display, compare, float_target: bool = True) -> np.ndarray:
    """The view of ``a`` (1:1, nearest) against reference ``b``: H x W x 3 (float32 or uint8)."""
    from phyir.insert.views import EquirectView
    from viewer.renderer import Frame

    ctx = renderer.ctx
    ta, tb = renderer.texture(a), renderer.texture(b)
    colour = ctx.texture((W, H), 4, dtype="f4" if float_target else "f1")
    target = ctx.framebuffer([colour])
    compare.texture = tb
    view = EquirectView(center=(W / 2, H / 2), zoom=1.0)
    try:
        renderer.render(target, (0, 0, W, H), Frame(texture=ta, pano_size=(H, W), view=view,
                                                    display=display, nearest=True, compare=compare))
        if float_target:
            out = np.frombuffer(target.read(components=4, dtype="f4"), np.float32).reshape(H, W, 4)
            return out[::-1, :, :3].copy()
        return renderer.read(target).astype(np.float64)
    finally:
        for obj in (ta, tb, target, colour):
            obj.release()


def layers(c: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.uniform(0.0, 3.0, (H, W, c)).astype(np.float32)
    b = rng.uniform(0.0, 3.0, (H, W, c)).astype(np.float32)
    b[:4] = 0.0  # reldiff's denominator at its smallest: |b| + 0.01
    return a, b


@pytest.mark.parametrize("mode", ["diff", "reldiff", "sqerr"])
@pytest.mark.parametrize("kind,channel", [("hdr", "rgb"), ("hdr", "g"), ("hdr", "luminance"),
                                          ("colour", "b"), ("scalar", "rgb"), ("normal", "rgb")])
def test_metrics_match_numpy(renderer, mode, kind, channel):
    from viewer.compare import compare_values
    from viewer.renderer import Compare, Display

    a, b = layers(1 if kind == "scalar" else 3, seed=len(mode) + len(kind))
    want = compare_values(a, b, mode, kind, channel)
    lo, hi = float(want.min()) - 0.5, float(want.max()) + 0.5  # nothing clamped
    got = draw(renderer, a, b, Display(kind=kind, channel=channel),
               Compare(mode, None, range=(lo, hi), colormap="gray"))
    assert np.abs(got[..., 0] - got[..., 2]).max() < 1e-6  # grey: one value
    value = lo + got[..., 0] * (hi - lo)
    err = np.abs(value - want) / (hi - lo)
    assert err.max() < 1e-3, (err.max(), np.unravel_index(err.argmax(), err.shape))
    assert want.std() > 0.1 * (hi - lo)  # the values vary: the test could fail


def test_reference_of_another_size_lines_up_over_the_panorama(renderer):
    from viewer.compare import compare_values
    from viewer.renderer import Compare, Display

    a, _ = layers(3, 7)
    small = np.random.default_rng(8).uniform(0, 2, (H // 2, W // 2, 3)).astype(np.float32)
    got = draw(renderer, a, small, Display(), Compare("diff", None, range=(-4.0, 4.0), colormap="gray"))
    want = compare_values(a, np.kron(small, np.ones((2, 2, 1), np.float32)), "diff")
    assert np.abs(-4.0 + 8.0 * got[..., 0] - want).max() < 8e-3


def test_metrics_use_their_colour_maps(renderer):
    """The default maps, as uint8 colours: the numbers of the LUT look-up
    (tests/viewer/gl/test_viewer_gl.py)."""
    from viewer.compare import COLORMAP, compare_values
    from viewer.renderer import Compare, Display, colormap_lut

    a, b = layers(3, 9)
    for mode, r in (("diff", (-2.0, 2.0)), ("sqerr", (0.0, 4.0))):
        got = draw(renderer, a, b, Display(), Compare(mode, None, range=r, colormap=COLORMAP[mode]),
                   float_target=False)
        t = np.clip((compare_values(a, b, mode) - r[0]) / (r[1] - r[0]), 0, 1)
        lut = colormap_lut(COLORMAP[mode])
        want = np.stack([np.interp(t * 255, np.arange(256), lut[:, c]) for c in range(3)], -1) * 255
        assert np.abs(got - want).max() <= 1.5, mode


def test_split_shows_the_image_left_and_the_reference_right(renderer):
    from viewer.renderer import Compare, Display

    a, b = layers(3, 11)
    a, b = a / 3, b / 3  # within [0, 1]: the sRGB display shows them unclamped
    display = Display(kind="colour")
    alone_a = draw(renderer, a, a, display, Compare("split", None, split=1.0), float_target=False)
    alone_b = draw(renderer, b, b, display, Compare("split", None, split=1.0), float_target=False)
    for split in (0.25, 0.5):
        got = draw(renderer, a, b, display, Compare("split", None, split=split), float_target=False)
        col = int(split * W)  # the line: the column split * W falls in
        assert np.array_equal(got[:, :col], alone_a[:, :col])
        assert np.array_equal(got[:, col + 1 :], alone_b[:, col + 1 :])
        assert np.abs(got[:, col] - 0.9 * 255).max() <= 1
    assert np.abs(alone_a - alone_b).mean() > 20  # a and b look different: the test could fail
