"""A corpus of bad files, generated here; each gets the outcome documented in docs/file-formats.md."""

import struct
import warnings

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image
from support.corpus import corpus_outcomes

from phyir import PanoScene, io
from phyir.io import InputError, InputWarning
from phyir.pano import directions

H, W = 32, 64


def write_exr(path, channels: dict, header: dict | None = None) -> None:
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, **(header or {})}, channels).write(str(path))


def rgb_exr(path, img: np.ndarray) -> None:
    write_exr(path, {"R": img[0], "G": img[1], "B": img[2]})


def good_scene_bytes(tmp_path) -> bytes:
    g = torch.Generator().manual_seed(0)
    s = PanoScene(image=torch.rand(3, H, W, generator=g), depth=1 + torch.rand(1, H, W, generator=g),
                  probes=torch.rand(2, 4, 3, 4, 8, generator=g))
    io.save_scene(s, tmp_path / "good.exr")
    return (tmp_path / "good.exr").read_bytes()


def no_nan(t: torch.Tensor) -> bool:
    return bool(torch.isfinite(t).all())


def refused(path, match: str) -> InputError:
    with pytest.raises(InputError, match=match) as e:
        io.load_panorama(path)
    assert str(path) in str(e.value) and "\n" not in str(e.value)  # names the file, one line
    with pytest.raises(InputError, match=match):
        io.load_scene(path)
    return e.value


# ---------------------------------------------------------------------------------------------
# refused with InputError


def test_missing_empty_folder_and_random_bytes(tmp_path):
    refused(tmp_path / "nope.exr", "no such file")
    (tmp_path / "empty.exr").write_bytes(b"")
    refused(tmp_path / "empty.exr", r"empty file \(0 bytes\)")
    refused(tmp_path, "is a folder")
    rng = np.random.default_rng(1)
    (tmp_path / "random.exr").write_bytes(rng.bytes(5000))
    refused(tmp_path / "random.exr", r"not an OpenEXR file \(wrong magic number\)")
    (tmp_path / "random.png").write_bytes(rng.bytes(5000))
    refused(tmp_path / "random.png", "not a supported image")
    (tmp_path / "notes.hdr").write_text("hello\n")
    refused(tmp_path / "notes.hdr", "not a supported image")


def test_truncated_exr_header(tmp_path):
    data = good_scene_bytes(tmp_path)
    for n in (4, 7, 40, 200):
        (tmp_path / "t.exr").write_bytes(data[:n])
        refused(tmp_path / "t.exr", "corrupt or truncated OpenEXR header")


def test_exr_absurd_header_dims_refused_before_decoding(tmp_path, monkeypatch):
    rgb_exr(tmp_path / "ok.exr", np.ones((3, H, W), np.float32))
    data = bytearray((tmp_path / "ok.exr").read_bytes())
    box = struct.pack("<4i", 0, 0, W - 1, H - 1)
    assert data.count(box) == 2  # dataWindow and displayWindow
    data = data.replace(box, struct.pack("<4i", 0, 0, 2_000_000 - 1, 1_000_000 - 1))
    (tmp_path / "huge.exr").write_bytes(bytes(data))

    def must_not_decode(*a, **k):
        raise AssertionError("pixel data decoded despite an absurd header")

    monkeypatch.setattr(io.exr, "read_pixels", must_not_decode)
    refused(tmp_path / "huge.exr", r"absurd size: panorama is 1000000x2000000")


def test_exr_inverted_window_and_unsupported_channels(tmp_path):
    rgb_exr(tmp_path / "ok.exr", np.ones((3, H, W), np.float32))
    data = (tmp_path / "ok.exr").read_bytes()
    box = struct.pack("<4i", 0, 0, W - 1, H - 1)
    (tmp_path / "inv.exr").write_bytes(data.replace(box, struct.pack("<4i", 5, 5, 0, 0)))
    refused(tmp_path / "inv.exr", "empty image")
    write_exr(tmp_path / "uint.exr", {c: np.ones((H, W), np.uint32) for c in "RGB"})
    refused(tmp_path / "uint.exr", "unsupported bit depth: channel 'R' is 32-bit UINT")
    write_exr(tmp_path / "depthonly.exr", {"depth.Z": np.ones((H, W), np.float32)})
    refused(tmp_path / "depthonly.exr", r"no R,G,B or Y channels \(found: depth.Z\)")
    ones = np.ones((H, W), np.float32)
    write_exr(tmp_path / "partial.exr", {"R": ones, "G": ones, "B": ones, "normal.X": ones})
    refused(tmp_path / "partial.exr",
            "layer 'normal' of part 'scene' is incomplete: missing normal.Y, normal.Z")


def test_exr_probe_attributes_must_match_atlas(tmp_path):
    ones = np.ones((H, W), np.float32)
    atlas = np.ones((8, 32), np.float32)
    for grid, size, match in (("2x4", "4x4", "does not match the atlas size 8x32"),
                              ("two", "4x8", "not strings of the form 'AxB'")):
        probe_header = {"probeGrid": grid, "probeSize": size, "displayWindow": ((0, 0), (W - 1, H - 1))}
        parts = [OpenEXR.Part({}, dict.fromkeys("RGB", ones), "scene"),
                 OpenEXR.Part(probe_header, dict.fromkeys("RGB", atlas), "probes")]
        OpenEXR.File(parts).write(str(tmp_path / "p.exr"))
        refused(tmp_path / "p.exr", match)


def test_tiny_wrong_aspect_and_huge_images(tmp_path):
    Image.new("RGB", (2, 1)).save(tmp_path / "1x2.png")
    refused(tmp_path / "1x2.png", r"absurd size: 1x2 \(HxW\) is smaller than the minimum 4x8")
    Image.new("RGB", (64, 64)).save(tmp_path / "square.png")
    refused(tmp_path / "square.png", "aspect ratio 64/64 = 1.000 is not that of an equirectangular")
    rgb_exr(tmp_path / "wide.exr", np.ones((3, 30, 64), np.float32))
    refused(tmp_path / "wide.exr", "aspect ratio 64/30")
    (tmp_path / "big.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 10000 +X 20000\n")
    refused(tmp_path / "big.hdr", "absurd size: panorama is 10000x20000")
    # the smallest accepted size and a slightly-off aspect ratio load
    Image.new("RGB", (8, 4)).save(tmp_path / "4x8.png")
    assert io.load_panorama(tmp_path / "4x8.png").shape == (3, 4, 8)
    Image.new("RGB", (1025, 512)).save(tmp_path / "off.png")
    assert io.load_panorama(tmp_path / "off.png").shape == (3, 512, 1025)


def test_unsupported_png_bit_depth_and_corrupt_png_jpeg(tmp_path):
    Image.new("1", (64, 32)).save(tmp_path / "bw.png")
    refused(tmp_path / "bw.png", "unsupported bit depth: 1-bit PNG")
    Image.new("RGB", (64, 32), (10, 20, 30)).save(tmp_path / "ok.png")
    data = (tmp_path / "ok.png").read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) - 30])
    refused(tmp_path / "trunc.png", "corrupt or truncated image")
    (tmp_path / "hdr_only.png").write_bytes(data[:20])
    refused(tmp_path / "hdr_only.png", r"corrupt or truncated PNG \(no IHDR chunk\)")
    rng = np.random.default_rng(2)
    Image.fromarray(rng.integers(0, 255, (32, 64, 3), dtype=np.uint8)).save(tmp_path / "ok.jpg", quality=90)
    data = (tmp_path / "ok.jpg").read_bytes()
    (tmp_path / "trunc.jpg").write_bytes(data[: len(data) // 2])
    refused(tmp_path / "trunc.jpg", "corrupt or truncated image")
    s = rng.integers(0, 65535, (H, W, 3)).astype(np.uint16)
    io.save_panorama(torch.from_numpy(s.transpose(2, 0, 1) / 65535.0).float(), tmp_path / "ok16.png", bits=16)
    data = (tmp_path / "ok16.png").read_bytes()
    (tmp_path / "trunc16.png").write_bytes(data[: len(data) // 2])
    refused(tmp_path / "trunc16.png", "truncated PNG")


def test_truncated_hdr(tmp_path):
    g = torch.Generator().manual_seed(3)
    io.save_panorama(torch.rand(3, H, W, generator=g) * 10, tmp_path / "ok.hdr")
    data = (tmp_path / "ok.hdr").read_bytes()
    (tmp_path / "t.hdr").write_bytes(data[: len(data) // 2])
    refused(tmp_path / "t.hdr", r"truncated Radiance HDR pixel data \(ends in scanline 1\d\)")
    (tmp_path / "h.hdr").write_bytes(data[:20])
    refused(tmp_path / "h.hdr", "corrupt or truncated Radiance HDR header")
    (tmp_path / "x.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 4 +X 8\n" + bytes(128))
    refused(tmp_path / "x.hdr", "unsupported Radiance HDR FORMAT=32-bit_rle_xyze")


# ---------------------------------------------------------------------------------------------
# repaired, with a warning


def test_nan_inf_replaced_and_reported(tmp_path):
    img = np.full((3, H, W), 0.5, np.float32)
    img[0, 0, 0] = img[1, 5, 7] = np.nan
    img[2, 3, 3] = np.inf
    img[0, 4, 4] = 7.0  # the largest finite value: +Inf becomes this
    img[1, 6, 6] = -np.inf  # becomes the smallest finite value, 0.25
    img[2, 7, 7] = 0.25
    rgb_exr(tmp_path / "nan.exr", img)
    with pytest.warns(InputWarning, match=r"nan.exr: image: replaced 2 NaN \(by 0\) and 2 Inf values"):
        t = io.load_panorama(tmp_path / "nan.exr")
    assert no_nan(t) and t[0, 0, 0] == 0 and t[1, 5, 7] == 0 and t[2, 3, 3] == 7.0 and t[1, 6, 6] == 0.25


def test_negative_radiance_clamped_with_warning(tmp_path):
    img = np.full((3, H, W), 0.5, np.float32)
    img[:, 2, :3] = -1.0
    rgb_exr(tmp_path / "neg.exr", img)
    with pytest.warns(InputWarning, match="image: clamped 9 negative radiance to 0"):
        t = io.load_panorama(tmp_path / "neg.exr")
    assert t.min() == 0 and t[:, 2, :3].abs().sum() == 0 and t[:, 3].eq(0.5).all()


def test_scene_layers_repaired(tmp_path):
    ones = np.ones((H, W), np.float32)
    nrm = np.stack([0 * ones, 0 * ones, 2 * ones])  # length 2: renormalised
    nrm[:, 0, 0] = np.nan  # broken: faces the camera
    nrm[:, 1, 1] = 0
    alb = np.full((H, W), 0.5, np.float32)
    alb[0, :5] = 1.5
    write_exr(tmp_path / "s.exr", {"R": ones, "G": ones, "B": ones, "normal.X": nrm[0], "normal.Y": nrm[1],
                                   "normal.Z": nrm[2], "albedo.R": alb, "albedo.G": alb, "albedo.B": alb,
                                   "depth.Z": ones, "mask.m": 2 * ones, "junk": ones})
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        s = io.load_scene(tmp_path / "s.exr")
    text = "\n".join(str(w.message) for w in rec)
    assert all(issubclass(w.category, InputWarning) for w in rec)
    assert "normal: 2 NaN/Inf/zero normals set to face the camera; renormalised 2046 normals" in text
    assert "albedo: clamped 15 values above 1" in text and "mask.m: clamped 2048 values above 1" in text
    assert "ignored junk" in text
    assert torch.equal(s.normal[:, 0, 0], -directions(H, W)[:, 0, 0])
    assert torch.equal(s.normal[:, 1, 1], -directions(H, W)[:, 1, 1])
    assert torch.equal(s.normal[:, 5, 5], torch.tensor([0.0, 0, 1]))
    assert s.albedo.max() == 1 and s.masks["m"].max() == 1
    s.validate()


def test_rgba_and_gray_and_16bit(tmp_path):
    rng = np.random.default_rng(4)
    rgb = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    alpha = rng.integers(0, 255, (H, W, 1), dtype=np.uint8)
    Image.fromarray(rgb).save(tmp_path / "rgb.png")
    Image.fromarray(np.concatenate([rgb, alpha], 2)).save(tmp_path / "rgba.png")
    assert torch.equal(io.load_panorama(tmp_path / "rgba.png"), io.load_panorama(tmp_path / "rgb.png"))
    Image.fromarray(rgb[..., 0]).save(tmp_path / "gray.png")
    g = io.load_panorama(tmp_path / "gray.png")
    assert torch.equal(g[0], g[1]) and torch.equal(g[1], g[2])
    assert torch.equal(g[0], io.load_panorama(tmp_path / "rgb.png")[0])
    # 16 bits are kept: a step of 1/65535 survives
    s = np.full((H, W, 3), 30000, np.uint16)
    s[0, 0] = 30001
    io.save_panorama(torch.from_numpy(s.transpose(2, 0, 1).astype(np.float32) / 65535), tmp_path / "a.png",
                     bits=16)  # linear in, sRGB out: compare in sRGB through the loader's inverse
    t = io.load_panorama(tmp_path / "a.png")
    assert t[0, 0, 0] > t[0, 0, 1] and t.dtype == torch.float32


# ---------------------------------------------------------------------------------------------
# corrupt data into the C++ library: in a child interpreter, which must not crash

CHILD = r"""
import json, sys, warnings
warnings.simplefilter("ignore")
import torch
from phyir import io
for path in sys.argv[1:]:
    try:
        s = io.load_scene(path)
        tensors = [t for _, t in s.layers()] + ([s.probes] if s.probes is not None else [])
        out = "ok" if all(bool(torch.isfinite(t).all()) for t in tensors) else "NaN"
    except io.InputError as e:
        out = "InputError" if path in str(e) and "\n" not in str(e) else "bad message: " + str(e)
    print(json.dumps([path, out]), flush=True)
print("done", flush=True)
"""


def test_corrupt_exr_corpus_never_crashes(tmp_path):
    data = good_scene_bytes(tmp_path)
    rng = np.random.default_rng(5)
    paths = []
    for n in sorted({len(data) // 3, len(data) // 2, len(data) - 100, len(data) - 1, 400, 700}):
        paths.append(tmp_path / f"trunc{n}.exr")
        paths[-1].write_bytes(data[:n])
    for k in range(30):  # flipped bytes, in the header (small k) and in pixel data
        b = bytearray(data)
        lo = 8 if k < 10 else 400
        for i in rng.integers(lo, len(b), 1 + k % 4):
            b[i] ^= int(rng.integers(1, 256))
        paths.append(tmp_path / f"flip{k}.exr")
        paths[-1].write_bytes(bytes(b))
    results = corpus_outcomes(CHILD, paths)
    assert all(results[str(p)] == "InputError" for p in paths if p.name.startswith("trunc"))
