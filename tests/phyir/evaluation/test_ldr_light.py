"""phyir.evaluation.ldr_light: clipped-region rows on a hand-made lamp, the perfect recovery scoring
zero, and ``phyir eval --ldr-light`` end to end on generated HDR panoramas."""

from __future__ import annotations

import json
import math

import pytest
import torch

from phyir import io, pano
from phyir.evaluation import ldr_light as LL

H, W = 64, 128


def lamp_room(lamp: float = 50.0) -> torch.Tensor:
    """Grey walls (0.2 .. 0.4 by row) and one 6x6 lamp of ``lamp`` near the zenith."""
    x = torch.linspace(0.2, 0.4, H)[None, :, None].expand(3, H, W).clone()
    x[:, 8:14, 30:36] = lamp
    return x


def test_region_rows_of_a_clipped_lamp():
    truth = lamp_room(50.0)
    ldr = truth.clamp(0, 1)
    naive = LL.region_rows(ldr, ldr, truth)
    assert naive["regions"] == 1 and naive["region_ratio_median"] == pytest.approx(1 / 50, rel=1e-4)
    assert naive["regions_within_2x"] == 0
    assert naive["clipped_sr"] == pytest.approx(float(pano.solid_angles(H, W)[8:14, 30:36].sum()), rel=1e-5)
    exact = LL.region_rows(ldr, truth, truth)
    assert exact["region_ratio_median"] == pytest.approx(1.0) and exact["clipped_log_err"] < 1e-6
    assert LL.region_rows(torch.full((3, H, W), 0.3), truth, truth) == {"clipped_sr": 0.0}


def test_eval_ldr_light_end_to_end(tmp_path):
    from phyir.cli import main

    for name, lamp in (("dim", 3.0), ("bright", 80.0)):
        io.save_panorama(lamp_room(lamp), tmp_path / f"{name}.exr")
    out = tmp_path / "r.json"
    assert main(["eval", "--ldr-light", str(tmp_path), "--json", str(out)]) == 0
    res = json.loads(out.read_text())
    assert {"dim/naive", "dim/gain", "bright/naive", "median/naive"} <= set(res)
    # the naive LDR loses most of the bright lamp's light: its diffuse sphere is darker there
    assert res["bright/naive"]["diffuse.ratio"] < res["dim/naive"]["diffuse.ratio"] <= 1.0 + 1e-6
    assert res["median/naive"]["diffuse.ratio_min"] == pytest.approx(res["bright/naive"]["diffuse.ratio"])
    # the calibrated gain brings light back: brighter than the naive copy
    assert res["bright/gain"]["diffuse.ratio"] > res["bright/naive"]["diffuse.ratio"]


def test_the_results_table_of_an_ldr_light_run(tmp_path):
    """room_table (printed by benchmarks.real_tables) on `phyir eval --ldr-light`'s JSON: a row per
    room, validation rooms first and named so, every method's figures in order, the medians' ratio
    as a range."""
    def row(d, r, m, w):
        return {"diffuse.rel_l1": d, "diffuse.ratio": r, "matte_silver.rel_l1": m, "regions_within_2x": w}
    doc = {"studio/naive": row(0.5, 0.4, 0.6, 0.0), "studio/gain": row(0.3, 0.7, 0.4, 0.25),
           "lythwood_room_1k/naive": row(0.1, 0.9, 0.2, 0.0),
           "lythwood_room_1k/gain": row(0.05, 1.0, 0.1, 0.5)}
    for m in ("naive", "gain"):
        doc[f"median/{m}"] = {**row(0.2, 0.8, 0.3, 0.4), "diffuse.ratio_min": 0.4, "diffuse.ratio_max": 1.0}
    lines = LL.room_table(doc)
    assert lines[0].startswith("| room | diffuse rel L1: naive / gain |")
    assert lines[2] == ("| lythwood_room (validation split) | 0.100 / 0.050 | 0.90 / 1.00 | 0.200 / 0.100 "
                        "| 50 % |")
    assert lines[3] == "| studio | 0.500 / 0.300 | 0.40 / 0.70 | 0.600 / 0.400 | 25 % |"
    assert lines[4].startswith("| **median** (ratio: range) | 0.200 / 0.200 | 0.40–1.00 / 0.40–1.00 |")


def test_eval_ldr_light_measures_a_given_region_model(tmp_path, capsys):
    """``--region-model FILE``: the law in the file is the one measured (a law that knows the lamp's
    luminance gives the region back within the 8-bit median's rounding); a file that is not a law
    is a one-line error naming it."""
    from phyir.cli import main
    from phyir.color import luminance
    from phyir.lighting.clip_regions import FEATURES, RegionModel

    room = lamp_room(80.0)
    io.save_panorama(room, tmp_path / "bright.exr")
    exact = RegionModel(math.log(80.0 / float(luminance(room).median())), (0.0,) * len(FEATURES))
    exact.save(tmp_path / "law.json")
    out, pano_file = tmp_path / "r.json", str(tmp_path / "bright.exr")
    assert main(["eval", "--ldr-light", pano_file, "--region-model", str(tmp_path / "law.json"),
                 "--json", str(out)]) == 0
    row = json.loads(out.read_text())["bright/regions"]
    assert row["region_ratio_median"] == pytest.approx(1.0, abs=0.02)
    (tmp_path / "other.json").write_text('{"weights": [1, 2]}')
    capsys.readouterr()
    assert main(["eval", "--ldr-light", pano_file, "--region-model", str(tmp_path / "other.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "other.json: not a clipped-region model" in err
