"""Scene files and panorama formats: exact round trips, the documented layout, atomic writes."""

import os
import struct
import zlib
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image

from phyir import PanoScene, color, io
from phyir.errors import PhyIRError
from phyir.io import ldr, rgbe
from phyir.pano import normals_from_depth

H, W = 32, 64


def make_scene(seed: int = 0, probes: bool = True) -> PanoScene:
    g = torch.Generator().manual_seed(seed)
    def r(*s):
        return torch.rand(*s, generator=g)
    depth = 1 + 3 * r(1, H, W)
    return PanoScene(
        image=10 * r(3, H, W), depth=depth, normal=normals_from_depth(depth), albedo=r(3, H, W),
        roughness=r(1, H, W), metallic=r(1, H, W), probes=5 * r(2, 4, 3, 8, 16) if probes else None,
        masks={"emission": (r(1, H, W) > 0.8).float(), "window": r(1, H, W)},
        meta={"source": "unit test", "exposure": "1.5", "note": "ünïcode"},
    ).validate()


def assert_scenes_equal(a: PanoScene, b: PanoScene) -> None:
    for name in ("image", "depth", "normal", "albedo", "roughness", "metallic", "probes"):
        x, y = getattr(a, name), getattr(b, name)
        assert (x is None) == (y is None), name
        if x is not None:
            assert x.dtype == y.dtype == torch.float32 and torch.equal(x, y), name
    assert a.masks.keys() == b.masks.keys()
    for k in a.masks:
        assert torch.equal(a.masks[k], b.masks[k]), k
    assert a.meta == b.meta


# ---------------------------------------------------------------------------------------------
# scene files


def test_scene_round_trip_exact(tmp_path):
    s = make_scene()
    io.save_scene(s, tmp_path / "s.exr")
    assert_scenes_equal(io.load_scene(tmp_path / "s.exr"), s)
    assert torch.equal(io.load_panorama(tmp_path / "s.exr"), s.image)


def test_scene_round_trip_partial_layers(tmp_path):
    s = make_scene(1, probes=False).replace(normal=None, albedo=None, masks={}, meta={})
    io.save_scene(s, tmp_path / "p.exr")
    back = io.load_scene(tmp_path / "p.exr")
    assert_scenes_equal(back, s)
    assert OpenEXR.File(str(tmp_path / "p.exr"), header_only=True).parts[0].name() == "scene"


def test_scene_half_precision(tmp_path):
    s = make_scene(2)
    io.save_scene(s, tmp_path / "h.exr", half=True)
    back = io.load_scene(tmp_path / "h.exr")
    assert torch.allclose(back.image, s.image, rtol=1e-3, atol=0)
    assert torch.allclose(back.depth, s.depth, rtol=1e-3, atol=0)
    assert torch.allclose(back.probes, s.probes, rtol=1e-3, atol=1e-7)
    assert os.path.getsize(tmp_path / "h.exr") < 0.7 * _size_full(s, tmp_path)
    types = {c.type() for c in OpenEXR.File(str(tmp_path / "h.exr")).parts[0].channels.values()}
    assert types == {OpenEXR.HALF}


def _size_full(s: PanoScene, tmp_path) -> int:
    io.save_scene(s, tmp_path / "f.exr")
    return os.path.getsize(tmp_path / "f.exr")


def test_scene_file_layout_as_documented(tmp_path):
    s = make_scene(3)
    io.save_scene(s, tmp_path / "s.exr")
    f = OpenEXR.File(str(tmp_path / "s.exr"), separate_channels=True)
    assert [p.name() for p in f.parts] == ["scene", "probes"]
    scene, probes = f.parts
    assert set(scene.channels) == {"R", "G", "B", "depth.Z", "normal.X", "normal.Y", "normal.Z",
                                   "albedo.R", "albedo.G", "albedo.B", "roughness.Y", "metallic.Y",
                                   "mask.emission", "mask.window"}
    assert {c.pixels.dtype for c in scene.channels.values()} == {np.dtype(np.float32)}
    assert scene.header["compression"] == OpenEXR.PIZ_COMPRESSION
    assert scene.header["phyir.source"] == "unit test" and scene.header["phyir.note"] == "ünïcode"
    assert np.array_equal(scene.channels["normal.Y"].pixels, s.normal[1].numpy())
    assert np.array_equal(scene.channels["mask.window"].pixels, s.masks["window"][0].numpy())
    # probes: atlas Hp*h x Wp*w, probe (a, b) at rows a*h.., columns b*w..
    assert set(probes.channels) == {"R", "G", "B"}
    assert probes.header["probeGrid"] == "2x4" and probes.header["probeSize"] == "8x16"
    atlas = probes.channels["G"].pixels
    assert atlas.shape == (2 * 8, 4 * 16)
    assert np.array_equal(atlas[8:16, 32:48], s.probes[1, 2, 1].numpy())
    # shared display window, own data window
    for p in (scene, probes):
        assert [list(v) for v in p.header["displayWindow"]] == [[0, 0], [W - 1, H - 1]]
    assert [list(v) for v in probes.header["dataWindow"]] == [[0, 0], [4 * 16 - 1, 2 * 8 - 1]]


def test_file_written_with_plain_openexr_loads(tmp_path):
    """A scene written by hand with the documented part/channel names, without phyir's writer."""
    rng = np.random.default_rng(4)
    def f32(*s):
        return rng.random(s, dtype=np.float32)
    Hp, Wp, h, w = 2, 4, 4, 8
    img, depth, alb = 3 * f32(3, H, W), 1 + f32(H, W), f32(3, H, W)
    nrm = rng.normal(size=(3, H, W)).astype(np.float32)
    nrm /= np.linalg.norm(nrm, axis=0)
    rough, mask = f32(H, W), f32(H, W)
    probes = f32(Hp, Wp, 3, h, w)
    atlas = np.zeros((3, Hp * h, Wp * w), np.float32)
    for a in range(Hp):
        for b in range(Wp):
            atlas[:, a * h : a * h + h, b * w : b * w + w] = probes[a, b]
    zip_ = OpenEXR.ZIP_COMPRESSION
    scene_part = OpenEXR.Part(
        {"compression": zip_, "type": OpenEXR.scanlineimage, "phyir.origin": "hand-written"},
        {"R": img[0], "G": img[1], "B": img[2], "depth.Z": depth, "normal.X": nrm[0],
         "normal.Y": nrm[1], "normal.Z": nrm[2], "albedo.R": alb[0], "albedo.G": alb[1],
         "albedo.B": alb[2], "roughness.Y": rough, "mask.lamp": mask}, "scene")
    probe_part = OpenEXR.Part(
        {"compression": zip_, "type": OpenEXR.scanlineimage, "displayWindow": ((0, 0), (W - 1, H - 1)),
         "probeGrid": f"{Hp}x{Wp}", "probeSize": f"{h}x{w}"},
        {"R": atlas[0], "G": atlas[1], "B": atlas[2]}, "probes")
    OpenEXR.File([scene_part, probe_part]).write(str(tmp_path / "hand.exr"))

    s = io.load_scene(tmp_path / "hand.exr")
    assert np.array_equal(s.image.numpy(), img) and np.array_equal(s.depth[0].numpy(), depth)
    assert np.array_equal(s.normal.numpy(), nrm) and np.array_equal(s.albedo.numpy(), alb)
    assert np.array_equal(s.roughness[0].numpy(), rough) and s.metallic is None
    assert np.array_equal(s.probes.numpy(), probes)
    assert list(s.masks) == ["lamp"] and np.array_equal(s.masks["lamp"][0].numpy(), mask)
    assert s.meta == {"origin": "hand-written"}


def test_plain_exr_rgb_and_gray(tmp_path):
    rng = np.random.default_rng(5)
    rgb = rng.random((3, H, W), dtype=np.float32)
    OpenEXR.File({"compression": OpenEXR.PIZ_COMPRESSION},
                 {"R": rgb[0], "G": rgb[1], "B": rgb[2], "A": rgb[0]}).write(str(tmp_path / "rgb.exr"))
    s = io.load_scene(tmp_path / "rgb.exr")  # alpha is dropped without a warning
    assert np.array_equal(s.image.numpy(), rgb) and s.depth is None and s.probes is None
    half = rgb[1].astype(np.float16)
    OpenEXR.File({}, {"Y": half}).write(str(tmp_path / "y.exr"))
    t = io.load_panorama(tmp_path / "y.exr")
    assert np.array_equal(t.numpy(), np.stack([half.astype(np.float32)] * 3))


def test_save_panorama_exr(tmp_path):
    t = make_scene(6).image
    io.save_panorama(t, tmp_path / "p.exr")
    assert torch.equal(io.load_panorama(tmp_path / "p.exr"), t)
    io.save_panorama(t, tmp_path / "ph.exr", half=True)
    assert torch.allclose(io.load_panorama(tmp_path / "ph.exr"), t, rtol=1e-3, atol=0)


def test_save_errors(tmp_path):
    t = make_scene(7).image
    with pytest.raises(PhyIRError, match="unsupported output format .tif"):
        io.save_panorama(t, tmp_path / "p.tif")
    with pytest.raises(PhyIRError, match="does not exist"):
        io.save_panorama(t, tmp_path / "missing" / "p.exr")
    with pytest.raises(ValueError, match="1 NaN/Inf"):
        io.save_panorama(t.clone().index_put_((torch.tensor(0), torch.tensor(0), torch.tensor(0)),
                                              torch.tensor(float("nan"))), tmp_path / "n.exr")
    with pytest.raises(PhyIRError, match="use a .exr"):
        io.save_scene(make_scene(7), tmp_path / "s.png")
    with pytest.raises(ValueError, match="meta entries"):
        io.save_scene(make_scene(7).replace(meta={"k": 3}), tmp_path / "s.exr")
    assert not any(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------------
# Radiance .hdr


def test_hdr_round_trip_within_quantisation(tmp_path):
    g = torch.Generator().manual_seed(8)
    t = torch.exp(4 * torch.randn(3, H, W, generator=g))  # radiance over many orders of magnitude
    t[:, :4] = 0.25  # long runs: exercises RLE runs
    io.save_panorama(t, tmp_path / "p.hdr")
    back = io.load_panorama(tmp_path / "p.hdr")
    # RGBE keeps 8 mantissa bits relative to the brightest channel of each pixel
    bound = t.max(0, keepdim=True).values * 2.0**-8
    assert ((back - t).abs() <= bound * 1.0001).all()
    assert torch.equal(back[:, :4], t[:, :4])
    assert os.path.getsize(tmp_path / "p.hdr") < H * W * 4  # RLE actually compresses


def _flat_hdr(rgbe_px: np.ndarray, resolution: str, extra: str = "") -> bytes:
    return f"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n{extra}\n{resolution}\n".encode() + rgbe_px.tobytes()


def test_hdr_flat_orientations_and_exposure(tmp_path):
    rng = np.random.default_rng(9)
    px = rng.integers(2, 255, (4, 8, 4), dtype=np.uint8)  # r,g,b >= 2: no old-style run markers
    want = np.where(px[..., 3:] > 0, px[..., :3] * 2.0 ** (px[..., 3:].astype(float) - 136), 0)
    cases = {
        "-Y 4 +X 8": (px, want),
        "+Y 4 +X 8": (px[::-1], want),
        "-Y 4 -X 8": (px[:, ::-1], want),
        "+X 8 -Y 4": (px.transpose(1, 0, 2), want),  # column-major: scanlines are columns
        "-X 8 +Y 4": (px[::-1, ::-1].transpose(1, 0, 2), want),
    }
    for res, (stored, expected) in cases.items():
        (tmp_path / "o.hdr").write_bytes(_flat_hdr(np.ascontiguousarray(stored), res))
        got = io.read_raw(tmp_path / "o.hdr").parts[0].layers["image"].transpose(1, 2, 0)
        assert np.allclose(got, expected, rtol=1e-6), res
    (tmp_path / "e.hdr").write_bytes(_flat_hdr(px, "-Y 4 +X 8", "EXPOSURE=2\nEXPOSURE=2\n"))
    got = io.load_panorama(tmp_path / "e.hdr").permute(1, 2, 0).numpy()
    assert np.allclose(got, want / 4, rtol=1e-6)


def test_hdr_old_style_runs_and_rle_equal_flat(tmp_path):
    px = np.full((4, 8, 4), (10, 200, 30, 130), np.uint8)
    px[:, 0] = (200, 100, 50, 129)
    # old-style RLE: pixel (1,1,1,n) repeats the previous pixel n times
    rows = [bytes(px[i, 0]) + bytes((10, 200, 30, 130)) + bytes((1, 1, 1, 6)) for i in range(4)]
    (tmp_path / "old.hdr").write_bytes(b"#?RADIANCE\n\n-Y 4 +X 8\n" + b"".join(rows))
    (tmp_path / "flat.hdr").write_bytes(_flat_hdr(px, "-Y 4 +X 8"))
    (tmp_path / "rle.hdr").write_bytes(rgbe.encode(rgbe.rgbe_to_float(px)))
    flat = io.load_panorama(tmp_path / "flat.hdr")
    assert torch.equal(io.load_panorama(tmp_path / "old.hdr"), flat)
    assert torch.equal(io.load_panorama(tmp_path / "rle.hdr"), flat)


def test_real_panoramas_load(panos_dir):
    peaks = {"artist_workshop_1k.hdr": 50, "comfy_cafe_1k.hdr": 2768, "fireplace_1k.hdr": 1400,
             "sepulchral_chapel_rotunda_1k.hdr": 80, "studio_small_08_1k.hdr": 105}  # README
    for name, peak in peaks.items():
        t = io.load_panorama(panos_dir / name)
        assert t.shape == (3, 512, 1024) and t.dtype == torch.float32
        assert torch.isfinite(t).all() and t.min() >= 0
        assert float(t.max()) == pytest.approx(peak, rel=0.015), name


# ---------------------------------------------------------------------------------------------
# PNG / JPEG


def test_srgb_transfer():
    x = np.linspace(0, 1, 1001, dtype=np.float32)
    assert np.allclose(color.linear_to_srgb(color.srgb_to_linear(x)), x, atol=1e-6)
    assert color.srgb_to_linear(np.float32(0.5)) == pytest.approx(0.21404, abs=1e-5)
    assert color.srgb_to_linear(np.float32(0.04)) == pytest.approx(0.04 / 12.92)


@pytest.mark.parametrize("bits", [8, 16])
def test_png_round_trip_within_quantisation(tmp_path, bits):
    g = torch.Generator().manual_seed(10)
    t = torch.rand(3, H, W, generator=g) * 1.2  # values above 1 are clipped
    io.save_panorama(t, tmp_path / "p.png", bits=bits)
    back = io.load_panorama(tmp_path / "p.png")
    q = 2**bits - 1
    def enc(x):
        return torch.from_numpy(color.linear_to_srgb(x.numpy()))
    assert (enc(back) - enc(t.clamp(max=1))).abs().max() <= 0.5 / q + 1e-6
    if bits == 8:
        assert np.array_equal(np.asarray(Image.open(tmp_path / "p.png")),
                              np.round(enc(t).numpy().transpose(1, 2, 0) * 255).astype(np.uint8))


def _png16(samples: np.ndarray, ctype: int, filters: list[int]) -> bytes:
    """Independent PNG writer: 16-bit samples [H, W, C], the given filter type per row."""
    h, w, c = samples.shape
    raw = samples.astype(">u2").view(np.uint8).reshape(h, w * c * 2).astype(np.int32)
    bpp, out = c * 2, b""
    for i in range(h):
        x = raw[i]
        up = raw[i - 1] if i else np.zeros_like(x)
        left = np.r_[np.zeros(bpp, np.int32), x[:-bpp]]
        ul = np.r_[np.zeros(bpp, np.int32), up[:-bpp]]
        ft = filters[i % len(filters)]
        if ft == 0:
            pred = 0
        elif ft == 1:
            pred = left
        elif ft == 2:
            pred = up
        elif ft == 3:
            pred = (left + up) // 2
        else:
            p = left + up - ul
            pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
            pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
        out += bytes([ft]) + ((x - pred) % 256).astype(np.uint8).tobytes()

    def chunk(t: bytes, b: bytes) -> bytes:
        return struct.pack(">I", len(b)) + t + b + struct.pack(">I", zlib.crc32(t + b))

    return (ldr.PNG_MAGIC + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 16, ctype, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(out)) + chunk(b"IEND", b""))


def test_png16_all_filters_and_colour_types(tmp_path):
    rng = np.random.default_rng(11)
    for ctype, c in ((2, 3), (6, 4), (0, 1), (4, 2)):
        s = rng.integers(0, 65536, (8, 16, c), dtype=np.uint16)
        s[2:4] = s[1]  # repeated rows and smooth gradients: filters matter
        (tmp_path / "f.png").write_bytes(_png16(s, ctype, [0, 1, 2, 3, 4]))
        got = io.load_panorama(tmp_path / "f.png").permute(1, 2, 0).numpy()
        rgb = s[..., :3] if c >= 3 else np.repeat(s[..., :1], 3, axis=2)  # alpha dropped, gray copied
        assert np.allclose(got, color.srgb_to_linear(rgb / 65535.0), atol=1e-6), ctype


def test_png16_gray_matches_pillow(tmp_path):
    rng = np.random.default_rng(12)
    g = np.cumsum(rng.integers(0, 900, (16, 32)), axis=1).astype(np.uint16)
    Image.fromarray(g).save(tmp_path / "g.png")  # Pillow's own encoder (adaptive filters)
    got = io.load_panorama(tmp_path / "g.png")[0].numpy()
    assert np.allclose(got, color.srgb_to_linear(np.asarray(Image.open(tmp_path / "g.png")) / 65535.0))


def test_jpeg_round_trip_approximate(tmp_path):
    v, u = torch.meshgrid(torch.linspace(0, 1, H), torch.linspace(0, 1, W), indexing="ij")
    t = torch.stack((u, v, 0.5 * (u + v))) ** 2  # smooth: JPEG is nearly lossless on it
    io.save_panorama(t, tmp_path / "p.jpg")
    back = io.load_panorama(tmp_path / "p.jpg")
    assert back.shape == t.shape and (back - t).abs().mean() < 0.01


# ---------------------------------------------------------------------------------------------
# atomic writes


def test_atomic_write_success_and_failure(tmp_path):
    target = tmp_path / "out.bin"
    target.write_bytes(b"old")
    with io.atomic_write(target) as tmp:
        assert Path(tmp).parent == tmp_path and Path(tmp).exists() and tmp != str(target)
        Path(tmp).write_bytes(b"new")
        assert target.read_bytes() == b"old"  # nothing visible before the block ends
    assert target.read_bytes() == b"new"
    for exc in (RuntimeError, KeyboardInterrupt):
        with pytest.raises(exc), io.atomic_write(target) as tmp:
            Path(tmp).write_bytes(b"half-writ")
            raise exc("interrupted")
        assert target.read_bytes() == b"new"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.bin"]  # no temporary left behind


def test_save_scene_failing_mid_write_leaves_target(tmp_path, monkeypatch):
    target = tmp_path / "s.exr"
    io.save_scene(make_scene(13), target)
    before = target.read_bytes()

    def broken_writer(path, parts, compression="ZIP"):
        Path(path).write_bytes(b"\x76\x2f\x31\x01 partial")  # a half-written file, then a failure
        raise OSError("disk full")

    monkeypatch.setattr(io.exr, "write_parts", broken_writer)
    with pytest.raises(OSError, match="disk full"):
        io.save_scene(make_scene(14), target)
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["s.exr"]
    assert_scenes_equal(io.load_scene(target), make_scene(13))


def test_save_panorama_is_atomic_for_every_format(tmp_path, monkeypatch):
    """Every writer goes through atomic_write: its temporary is what gets written."""
    seen = []
    real = io.atomic_write

    def spy(path):
        seen.append(os.fspath(path))
        return real(path)

    monkeypatch.setattr(io.writers, "atomic_write", spy)  # where the writers look it up
    t = make_scene(15).image.clamp(max=1)
    for name in ("a.exr", "a.hdr", "a.png", "a.jpg"):
        io.save_panorama(t, tmp_path / name)
    io.save_panorama(t, tmp_path / "b.png", bits=16)
    io.save_scene(make_scene(15), tmp_path / "s.exr")
    assert [Path(p).name for p in seen] == ["a.exr", "a.hdr", "a.png", "a.jpg", "b.png", "s.exr"]
