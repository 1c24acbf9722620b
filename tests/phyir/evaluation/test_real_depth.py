"""phyir.evaluation.scans / real_depth: the scan layouts the field uses, the depth protocol against
hand-computed values, normals of an analytic room, the rank correlation, and ``phyir eval --scans``
end to end on generated scans."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from support.scenes import room_with_table

from phyir import io
from phyir.errors import InputError
from phyir.evaluation import real_depth as RD
from phyir.evaluation import scans as S

H, W = 32, 64


def write_scan(folder, depth: np.ndarray, kind: str = "npy", scale: float | None = None,
               stem: str = "") -> None:
    """A scan: a grey-gradient rgb.png and its depth as .npy, .exr or a 16-bit .png (``scale`` m/unit)."""
    folder.mkdir(parents=True, exist_ok=True)
    h, w = depth.shape
    img = torch.linspace(0.05, 0.8, w).expand(3, h, w).contiguous()
    io.save_panorama(img, folder / f"{stem}rgb.png")
    if kind == "npy":
        np.save(folder / f"{stem}depth.npy", depth.astype(np.float32))
    elif kind == "exr":
        from phyir.io import exr

        exr.write_parts(folder / f"{stem}depth.exr", [("depth", {}, {"Y": depth.astype(np.float32)})])
    else:
        from PIL import Image

        raw = np.where(np.isfinite(depth), np.round(depth / (scale or S.PNG_SCALE)), 65535).astype(np.uint16)
        Image.fromarray(raw).save(folder / f"{stem}depth.png")
        if scale is not None:
            (folder / "scan.json").write_text(json.dumps({"depth_scale": scale}))


def room_depth() -> np.ndarray:
    return room_with_table(H, W)[0][0].numpy()


@pytest.mark.parametrize("kind", ["npy", "exr", "png"])
def test_each_depth_format_reads_back_in_metres(tmp_path, kind):
    d = room_depth()
    d[3, 5] = 0.0  # a hole
    d[4, 6] = np.inf if kind != "png" else d[4, 6]
    scale = 1 / 512 if kind == "png" else None  # Stanford2D3D's unit, from scan.json
    write_scan(tmp_path / "room", d, kind, scale)
    (scan,) = S.find_scans(tmp_path / "room")
    got = S.read_depth(scan)[0].numpy()
    assert got.shape == (H, W) and got[3, 5] == 0
    if kind != "png":
        assert got[4, 6] == 0
    ok = got > 0
    tol = 0.5 / 512 + 1e-6 if kind == "png" else 1e-6
    assert np.abs(got[ok] - d[ok]).max() <= tol


def test_png_holes_and_the_default_scale(tmp_path):
    d = room_depth()
    d[0, :] = np.inf  # written as 65535: a hole
    write_scan(tmp_path / "r", d, "png")
    got = S.read_depth(S.find_scans(tmp_path / "r")[0])[0].numpy()
    assert (got[0] == 0).all()
    assert np.abs(got[1:] - d[1:]).max() <= 0.5 * S.PNG_SCALE + 1e-6


def test_layouts_one_scan_subfolders_and_pairs(tmp_path):
    d = room_depth()
    write_scan(tmp_path / "rooms" / "b_room", d)
    write_scan(tmp_path / "rooms" / "a_room", d)
    (tmp_path / "rooms" / "empty").mkdir()
    assert [s.name for s in S.find_scans(tmp_path / "rooms")] == ["a_room", "b_room"]
    write_scan(tmp_path / "flat", d, stem="hall_")
    write_scan(tmp_path / "flat", d, stem="attic_")
    scans = S.find_scans(tmp_path / "flat")
    assert [s.name for s in scans] == ["attic", "hall"] and scans[1].depth.name == "hall_depth.npy"


def test_unusable_scans_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match="holds no scan"):
        S.find_scans(tmp_path)
    with pytest.raises(InputError, match="not a folder"):
        S.find_scans(tmp_path / "missing")
    write_scan(tmp_path / "r", np.ones((10, 30)))
    with pytest.raises(InputError, match="H x 2H"):
        S.read_depth(S.find_scans(tmp_path / "r")[0])
    write_scan(tmp_path / "p", room_depth(), "png", 0.001)
    (tmp_path / "p" / "scan.json").write_text("{}")
    with pytest.raises(InputError, match="depth_scale"):
        S.find_scans(tmp_path / "p")


def test_depth_rows_against_hand_computed_values():
    gt = torch.from_numpy(room_depth())[None]
    gt[0, :2] = 0  # invalid rows are left out
    rows = RD.depth_rows(gt * 2, gt)  # the right shape at twice the scale
    assert rows["scale"] == pytest.approx(0.5)
    assert rows["aligned.abs_rel"] == pytest.approx(0, abs=1e-12) and rows["aligned.delta1"] == 1
    assert rows["metric.abs_rel"] == pytest.approx(1.0) and rows["metric.delta1"] == 0
    valid = gt[gt > 0].double()
    med = valid.median()
    assert rows["constant.abs_rel"] == pytest.approx(float(((med - valid).abs() / valid).mean()), rel=1e-9)
    # a 10 % bump on a quarter of the columns, computed by hand in numpy (lower median, as torch's)
    bumped = gt.clone()
    bumped[:, :, : W // 4] *= 1.1
    g, b = gt.numpy().ravel(), bumped.numpy().ravel()
    ok = g > 0
    g, b = g[ok].astype(np.float64), b[ok].astype(np.float64)
    lower_median = lambda x: np.sort(x)[(len(x) - 1) // 2]  # noqa: E731
    s = lower_median(g) / lower_median(b)
    r = RD.depth_rows(bumped, gt)
    assert r["scale"] == pytest.approx(s, rel=1e-6)
    assert r["aligned.abs_rel"] == pytest.approx(np.mean(np.abs(b * s - g) / g), rel=1e-5)
    assert r["metric.rmse"] == pytest.approx(np.sqrt(np.mean((b - g) ** 2)), rel=1e-5)


def test_normal_rows_of_the_true_geometry_and_of_a_wrong_one():
    depth, normal, _ = room_with_table(64, 128)
    depth, normal = depth.float(), normal.float()
    exact = RD.normal_rows(normal, depth)
    assert exact["normal.median"] < 0.5 and exact["normal.mean"] < 3.0  # only crease pixels differ
    up = torch.zeros_like(normal)
    up[1] = 1
    floor = normal[1] > 0.9
    wrong = RD.normal_rows(up, depth)
    share_floor = float(floor.float().mean())
    assert wrong["normal.pct_11.25"] == pytest.approx(100 * share_floor, abs=3.0)


def test_the_mask_leaves_out_pixels_next_to_holes():
    gt = torch.ones(1, 8, 16)
    gt[0, 4, 7] = 0
    m = RD.valid_normals_mask(gt)[0]
    assert not m[4, 7] and not m[3, 7] and not m[5, 7] and not m[4, 6] and not m[4, 8]
    assert int(m.sum()) == 8 * 16 - 5
    gt[0, 2, 0] = 0  # wraps in longitude
    assert not RD.valid_normals_mask(gt)[0, 2, 15]


def test_spearman():
    assert RD.spearman([1, 2, 3, 4], [10, 20, 30, 40]) == pytest.approx(1.0)
    assert RD.spearman([1, 2, 3, 4], [4, 3, 2, 1]) == pytest.approx(-1.0)
    assert RD.spearman([1, 2, 2, 3], [1, 2, 3, 4]) == pytest.approx(0.9486833, rel=1e-6)  # ties: mean ranks
    assert np.isnan(RD.spearman([1, 2], [2, 1]))


def test_eval_scans_end_to_end(tmp_path, capsys):
    from phyir.cli import main

    d = room_depth()
    write_scan(tmp_path / "scans" / "box", d)
    write_scan(tmp_path / "scans" / "deep", d * 3, "png")
    out, sheet = tmp_path / "r.json", tmp_path / "sheet.png"
    assert main(["eval", "--scans", str(tmp_path / "scans"), "--json", str(out), "--sheet", str(sheet)]) == 0
    res = json.loads(out.read_text())
    assert set(res["rooms"]) == {"box", "deep"} and res["median"]["rooms"] == 2
    for r in res["rooms"].values():
        assert 0 <= r["aligned.abs_rel"] < 5 and 0 <= r["aligned.delta1"] <= 1 and r["scale"] > 0
        assert 0 <= r["confidence"] <= 1 and 0 <= r["normal.mean"] <= 180
    # the same image at three times the depth: the aligned errors are equal, the scale three times
    box, deep = res["rooms"]["box"], res["rooms"]["deep"]
    assert deep["aligned.abs_rel"] == pytest.approx(box["aligned.abs_rel"], abs=2e-3)
    assert deep["scale"] == pytest.approx(3 * box["scale"], rel=2e-3)
    from PIL import Image

    with Image.open(sheet) as im:
        assert im.size[0] > 4 * 256 and im.size[1] > 2 * 128
    assert "median" in capsys.readouterr().out


def test_a_written_scan_reads_back_and_is_written_as_one_set(tmp_path):
    """write_scan (benchmarks.synthetic_scans writes held-out rooms with it): the image and the depth
    come back exactly through the scan reader; an existing folder is refused and left as it is."""
    d = room_depth()
    rgb = np.arange(H * W * 3, dtype=np.int64).reshape(H, W, 3).astype(np.uint8)
    scan = S.write_scan(tmp_path / "scans" / "room", rgb, torch.from_numpy(d)[None])
    assert S.find_scans(tmp_path / "scans") == [scan]
    assert torch.equal(S.read_depth(scan)[0], torch.from_numpy(d.astype(np.float32)))
    from PIL import Image

    with Image.open(scan.image) as im:
        assert np.array_equal(np.array(im), rgb)
    with pytest.raises(InputError, match="already exists"):
        S.write_scan(tmp_path / "scans" / "room", rgb, d)
    assert sorted(p.name for p in (tmp_path / "scans").iterdir()) == ["room"]
