"""phyir.lighting.clip_regions and its fit (phyir.learn.fit_clip_regions): the features measure what
they say on a drawn panorama, the ridge fit recovers a known linear law, and recover_clipped brings
each region to the model's luminance."""

from __future__ import annotations

import math

import torch

from phyir import pano
from phyir.color import luminance
from phyir.learn.fit_clip_regions import PanoramaSamples, fit, fit_samples, panorama_samples
from phyir.lighting.clip_regions import FEATURES, RADII, RegionModel, _grown, region_features
from phyir.lighting.hdr_recovery import CLIP_LEVEL, clipped_regions, recover_clipped

H, W = 128, 256


def degrees_from_front(h: int = H, w: int = W) -> torch.Tensor:
    """[h,w] angle in degrees between each pixel's direction and the panorama's centre (-z)."""
    d = pano.directions(h, w)
    return torch.rad2deg(torch.acos((d * torch.tensor([0.0, 0.0, -1.0])[:, None, None]).sum(0).clamp(-1, 1)))


def lamp_panorama(ring: float) -> torch.Tensor:
    """A grey room (0.18) with one clipped white disk of 8° radius on the horizon, its surroundings
    out to 20° lit at ``ring`` (linear)."""
    angle = degrees_from_front()
    img = torch.full((3, H, W), 0.18)
    img[:, angle < 20] = ring
    img[:, angle < 8] = 1.0
    return img


def test_features_measure_the_region():
    feats = {}
    for ring in (0.2, 0.8):
        ldr = lamp_panorama(ring)
        clipped, labels, n = clipped_regions(ldr)
        assert n == 1
        feats[ring] = dict(zip(FEATURES, region_features(ldr, clipped, labels, n, CLIP_LEVEL)[0].tolist()))
    f, lit = feats[0.2], feats[0.8]
    cap = 2 * math.pi * (1 - math.cos(math.radians(8)))  # the disk's solid angle
    assert abs(math.exp(f["log_area"]) / cap - 1) < 0.1
    assert abs(f["sin_lat"]) < 0.02 and f["white"] == 1.0 and f["clipped_around"] == 0.0
    assert f["edge_chroma"] < 1e-4  # a grey surround
    # rings out to 16 pixels (5.6 degrees; a square's corner 8) lie in the 12-degree surround: its
    # luminance over the median (0.18), all of it above half the clip when lit at 0.8, none at 0.2,
    # none near the clip
    for r in RADII[1:-2]:
        assert abs(math.exp(f[f"lum_{r}"]) - 0.2 / 0.18) < 0.02, r
        assert abs(math.exp(lit[f"lum_{r}"]) - 0.8 / 0.18) < 0.05, r
        assert (f[f"bright_{r}"], lit[f"bright_{r}"], lit[f"near_clip_{r}"]) == (0.0, 1.0, 0.0), r
    # the ring from 16 to 32 pixels straddles the surround's edge; the last one is the 0.18 room
    assert 1.1 < math.exp(lit["lum_32"]) < 0.8 / 0.18 - 0.1 and 0 < lit["bright_32"] < 1
    assert abs(math.exp(lit["lum_64"]) - 1) < 0.01 and lit["bright_64"] == 0.0


def test_region_windows_wrap_in_longitude():
    """A region across the seam has the features of the same region away from it (the windows wrap)."""
    ldr = lamp_panorama(0.6)
    seam = torch.roll(ldr, W // 2, dims=-1)  # the disk moves from the centre to the seam
    rows = []
    for img in (ldr, seam):
        clipped, labels, n = clipped_regions(img)
        assert n == 1
        rows.append(region_features(img, clipped, labels, n, CLIP_LEVEL)[0])
    assert torch.allclose(rows[0], rows[1], atol=1e-6)


def test_grown_masks_are_square_dilations():
    """The summed-area table's growth against max pooling (an independent reference)."""
    import torch.nn.functional as F

    mask = torch.rand(40, 90, generator=torch.Generator().manual_seed(1)) > 0.97
    for r, grown in zip((1, 3, 8), _grown(mask, (1, 3, 8))):
        want = F.max_pool2d(mask[None, None].float(), 2 * r + 1, 1, padding=r)[0, 0] > 0
        assert torch.equal(grown, want), r


def test_the_ridge_fit_recovers_a_linear_law():
    g = torch.Generator().manual_seed(0)
    X = torch.randn(400, len(FEATURES), generator=g, dtype=torch.float64)
    beta = torch.linspace(-1.0, 1.2, len(FEATURES), dtype=torch.float64)
    y = 2.0 + X @ beta + 0.01 * torch.randn(400, generator=g, dtype=torch.float64)
    intercept, coef = fit(X, y, torch.rand(400, generator=g, dtype=torch.float64) + 0.5, ridge=1e-6)
    assert abs(intercept - 2.0) < 0.01 and max(abs(a - b) for a, b in zip(coef, beta.tolist())) < 0.01


def test_the_fit_pools_the_panoramas_samples():
    """Panoramas' samples fitted together give the law they share, and the partly clipped pixels'
    gain is their true energy over the filled one summed over the panoramas."""
    g = torch.Generator().manual_seed(1)
    beta = torch.linspace(0.5, -0.5, len(FEATURES), dtype=torch.float64)
    def samples(name: str, partial: tuple[float, float]) -> PanoramaSamples:
        X = torch.randn(200, len(FEATURES), generator=g, dtype=torch.float64)
        X[:, FEATURES.index("log_area")] = math.log(0.05)  # one law: every region big
        core_sr = torch.rand(200, generator=g, dtype=torch.float64) + 0.1
        return PanoramaSamples(name, X, 3.0 + X @ beta, core_sr, partial)
    model = fit_samples([samples("a.hdr", (2.0, 1.0)), samples("b.hdr", (1.0, 1.0))], ridge=1e-6)
    new = samples("c.hdr", (0.0, 0.0))
    assert torch.allclose(model.log_gain(new.features), new.log_luminance, atol=1e-5)
    assert model.partial_gain == 1.5 and model.fitted_on == ("a.hdr", "b.hdr") and model.regions == 400
    assert model.small_coef == ()  # no small regions: no second law


def test_a_panoramas_samples_are_its_lamps_true_luminance(tmp_path):
    """A white lamp disk 300x the room's median, photographed by the evaluation camera: one region,
    its core's true luminance over the copy's median is the lamp's over the room's."""
    from phyir.io import save_panorama

    angle = degrees_from_front()
    hdr = torch.full((3, H, W), 0.5)
    hdr[:, angle < 6] = 150.0
    save_panorama(hdr, tmp_path / "lamp.exr")
    s = panorama_samples(tmp_path / "lamp.exr", exposures=(1.0,))
    assert s.name == "lamp.exr" and s.features.shape == (1, len(FEATURES))
    assert abs(float(s.log_luminance[0]) - math.log(300.0)) < 0.01  # (the copy's median is 8-bit: 0.6 %)
    disk = float(pano.solid_angles(H, W)[angle < 6].sum())
    assert abs(float(s.core_sr[0]) / disk - 1) < 1e-6 and s.partial == (0.0, 0.0)


def test_recovery_brings_the_region_to_the_models_luminance(tmp_path):
    ldr = lamp_panorama(0.5)
    model = RegionModel(math.log(40.0), (0.0,) * len(FEATURES))  # every region: 40x the median
    out, rec = recover_clipped(ldr, model=model)
    clipped, labels, _ = clipped_regions(ldr)
    med = float(luminance(ldr).median())
    omega = pano.solid_angles(H, W)
    lum = luminance(out)
    mean = float((lum[clipped] * omega[clipped]).sum() / omega[clipped].sum())
    assert abs(mean / (40 * med) - 1) < 1e-3 and rec.method == "regions" and rec.regions == 1
    assert torch.equal(out[:, ~clipped], ldr[:, ~clipped])
    model.save(tmp_path / "m.json")
    assert RegionModel.load(tmp_path / "m.json") == model
    assert recover_clipped(ldr, model=None)[1].method == "gain"


def test_small_regions_take_their_own_law(tmp_path):
    """Regions under ``small_below_sr`` take the small-region law, the rest the main one; the laws
    travel through the JSON file."""
    log_area = FEATURES.index("log_area")
    feats = torch.zeros(2, len(FEATURES), dtype=torch.float64)
    feats[:, log_area] = torch.tensor([math.log(0.002), math.log(0.05)])
    model = RegionModel(math.log(40.0), (0.0,) * len(FEATURES), small_below_sr=0.01,
                        small_intercept=math.log(2.0), small_coef=(0.0,) * len(FEATURES))
    want = torch.tensor([math.log(2.0), math.log(40.0)], dtype=torch.float64)
    assert torch.allclose(model.log_gain(feats), want)
    model.save(tmp_path / "m.json")
    assert RegionModel.load(tmp_path / "m.json") == model
    one_law = RegionModel(math.log(40.0), (0.0,) * len(FEATURES))
    assert torch.allclose(one_law.log_gain(feats), torch.full((2,), math.log(40.0), dtype=torch.float64))


def test_the_shipped_model_has_both_laws():
    model = RegionModel.load()
    assert model is not None and model.small_below_sr > 0 and len(model.small_coef) == len(FEATURES)
    assert len(model.fitted_on) == 15 and not any("colorful_studio" in f for f in model.fitted_on)


def halo_panorama() -> torch.Tensor:
    """``lamp_panorama``'s white disk inside a warm halo whose red channel clipped (8-12°: red 1.0,
    green 0.6, blue 0.3), in an unclipped band of hue (2, 1, 0.5) out to 20°."""
    angle = degrees_from_front()
    img = torch.full((3, H, W), 0.18)
    img[:, angle < 20] = torch.tensor([0.8, 0.4, 0.2])[:, None]
    img[:, angle < 12] = torch.tensor([1.0, 0.6, 0.3])[:, None]
    img[:, angle < 8] = 1.0
    return img


def test_partly_clipped_pixels_keep_their_measured_channels():
    """fill_partial: the halo's green and blue are measurements and stay; its clipped red takes the
    band's hue at the measured level (2 x green = 1.2); then everything times the gain. The white
    disk and the unclipped pixels are not touched."""
    from phyir.lighting.clip_regions import fill_partial

    ldr = halo_panorama()
    out = fill_partial(ldr, CLIP_LEVEL, gain=1.5)
    over = ldr >= CLIP_LEVEL
    halo = over.any(0) & ~over.all(0)
    want = torch.tensor([1.2, 0.6, 0.3])[:, None] * 1.5
    assert torch.allclose(out[:, halo], want.expand(3, int(halo.sum())), atol=1e-4)
    assert torch.equal(out[:, ~halo], ldr[:, ~halo])


def test_the_law_lifts_the_white_core_and_not_the_halo():
    """recover_clipped with a model: the white core reaches the law's luminance; the partly clipped
    halo gets fill_partial's values, however bright the law says the region is."""
    from phyir.lighting.clip_regions import fill_partial

    ldr = halo_panorama()
    model = RegionModel(math.log(40.0), (0.0,) * len(FEATURES), partial_gain=1.2)
    out, rec = recover_clipped(ldr, model=model)
    over = ldr >= CLIP_LEVEL
    core, halo = over.all(0), over.any(0) & ~over.all(0)
    med = float(luminance(ldr).median())
    omega = pano.solid_angles(H, W)
    lum = luminance(out)
    mean = float((lum[core] * omega[core]).sum() / omega[core].sum())
    assert abs(mean / (40 * med) - 1) < 1e-3 and rec.regions == 1
    assert torch.allclose(out[:, halo], fill_partial(ldr, CLIP_LEVEL, 1.2)[:, halo])


def test_recovery_never_writes_into_its_input():
    """Without partly clipped pixels too (fill_partial has nothing to fill)."""
    for ldr in (lamp_panorama(0.5), halo_panorama()):
        before = ldr.clone()
        recover_clipped(ldr, model=RegionModel(math.log(40.0), (0.0,) * len(FEATURES)))
        assert torch.equal(ldr, before)


def test_a_jpegs_white_core_is_white():
    """Through a JPEG encoder (quality 95, chroma subsampled) most of a clipped white disk inside an
    orange halo comes back a few codes under 255 in green or blue: white_pixels still takes it as the
    white core, where requiring every channel at the clip keeps under a third of it; the halo, whose
    measured channels are well under the clip, is not white."""
    from phyir.learn.camera import jpeg_linear
    from phyir.lighting.clip_regions import white_pixels

    h, w = 256, 512  # the disk 11 pixels across its radius (a JPEG's chroma blocks are 16)
    angle = degrees_from_front(h, w)
    img = torch.full((3, h, w), 0.18)
    img[:, angle < 20] = torch.tensor([0.8, 0.4, 0.2])[:, None]
    img[:, angle < 12] = torch.tensor([1.0, 0.6, 0.3])[:, None]
    img[:, angle < 8] = 1.0
    ldr = jpeg_linear(img, 95)
    disk, halo = angle < 7, (angle > 9) & (angle < 11)
    white = white_pixels(ldr, CLIP_LEVEL)
    every_channel = (ldr >= CLIP_LEVEL).all(0)
    assert float(white[disk].float().mean()) > 0.8 and float(every_channel[disk].float().mean()) < 0.35
    assert not bool(white[halo].any())
    assert torch.equal(white_pixels(img, CLIP_LEVEL), angle < 8)  # as it is: exactly the disk


def test_the_shipped_laws():
    """Both shipped laws, the JPEG one fitted on JPEG copies too; recover_clipped names the one used."""
    from phyir.lighting.clip_regions import JPEG_MODEL_PATH

    jpeg = RegionModel.load(JPEG_MODEL_PATH)
    assert jpeg is not None and jpeg.jpeg == 90 and jpeg.fitted_on == RegionModel.load().fitted_on
    ldr = lamp_panorama(0.5)
    assert recover_clipped(ldr, model="shipped")[1].method == "regions"
    assert recover_clipped(ldr, model="shipped-jpeg")[1].method == "regions-jpeg"


def test_the_panoramas_added_to_a_fit(tmp_path):
    """--add: files as they are, a folder's .hdr/.exr; a missing path, an empty folder or a file of
    hdri-indoor's validation split (never fitted on) is an error naming it."""
    import pytest

    from phyir.errors import InputError
    from phyir.learn.fit_clip_regions import panorama_files

    rooms = tmp_path / "rooms"
    rooms.mkdir()
    for name in ("b.exr", "a.hdr", "notes.txt"):
        (rooms / name).write_bytes(b"")
    one = tmp_path / "c.exr"
    one.write_bytes(b"")
    assert panorama_files([one, rooms]) == [one, rooms / "a.hdr", rooms / "b.exr"]
    (tmp_path / "empty").mkdir()
    (tmp_path / "lythwood_room_1k.hdr").write_bytes(b"")
    for bad, why in ((tmp_path / "nothing.exr", "no such file"), (tmp_path / "empty", "no .hdr or .exr"),
                     (tmp_path / "lythwood_room_1k.hdr", "validation split")):
        with pytest.raises(InputError, match=why) as e:
            panorama_files([bad])
        assert e.value.path == str(bad)
