"""The ``synth``, ``model`` and ``shading`` benchmark targets: quick runs write complete, finite JSON
whose numbers behave as the physics says (more samples, less noise; exact mirrors), and the noise
estimators are right on Gaussian noise of known size."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
import torch


def _load_strict(path: Path) -> dict:
    """The JSON file, refusing NaN / Infinity (not JSON)."""
    def bad(c: str):
        raise AssertionError(f"{path.name}: non-finite constant {c}")

    return json.loads(path.read_text(), parse_constant=bad)


def _numbers(obj, path: str = ""):
    """(path, value) of every number in a JSON tree."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{path}/{i}")
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield path, obj


def _check_written(out: Path, target: str, result: dict) -> dict:
    doc = _load_strict(out / f"{target}.json")
    assert (out / f"{target}.png").stat().st_size > 1000
    assert doc.keys() == json.loads(json.dumps(result)).keys()
    assert all(math.isfinite(v) for _, v in _numbers(doc))
    return doc


def test_noise_estimators_on_gaussian_noise():
    from phyir.bench.synth import pair_noise, rel_l1

    g = torch.Generator().manual_seed(0)
    sigma, n = 0.1, 400_000
    truth = torch.full((n,), 2.0)
    a = truth + sigma * torch.randn(n, generator=g)
    b = truth + sigma * torch.randn(n, generator=g)
    expected = sigma * math.sqrt(2 / math.pi) / 2.0  # E|N(0, sigma)| / |truth|
    assert rel_l1(a, truth) == pytest.approx(expected, rel=0.01)
    assert pair_noise(a, b) == pytest.approx(expected, rel=0.01)
    mask = torch.zeros(n)
    mask[: n // 2] = 1
    assert rel_l1(a, truth, mask) == pytest.approx(expected, rel=0.02)
    assert rel_l1(truth, torch.zeros(n)) != rel_l1(truth, torch.zeros(n))  # NaN: no reference signal


@pytest.mark.slow
def test_synth_quick(tmp_path):
    from phyir.bench import synth as bench_synth

    res = bench_synth.run_bench(tmp_path, quick=True, threads=1, log=lambda s: None)
    doc = _check_written(tmp_path, "synth", res)
    cfg = bench_synth.QUICK
    sm = doc["summary"]
    assert [r["spp"] for r in sm["camera"]] == list(cfg["spp"])
    first, last = sm["camera"][0], sm["camera"][-1]
    # 4x the samples: camera noise ~halves (Monte Carlo); the seed-to-seed noise falls too
    assert last["noise_camera"] < 0.75 * first["noise_camera"]
    assert last["noise_total"] < first["noise_total"]
    # Monte Carlo: -0.5; two or three spp points of one room scatter it (-0.83 in a room of the
    # session-10 generator), beyond -1 would be faster than Monte Carlo can be
    assert -1.0 < sm["camera_noise_slope"] < -0.3
    assert [r["size"] for r in doc["growth"]["sizes"]] == [list(s) for s in cfg["sizes"]]
    assert [r["vis_rays"] for r in sm["probes"]] == list(cfg["vis_rays"])
    assert all(0 < r["noise"] < 1 for r in sm["probes"])
    assert bench_synth.key_numbers(res)
    assert "| spp |" in bench_synth.format_table(res)


@pytest.mark.slow
def test_model_quick(tmp_path, monkeypatch):
    from phyir.bench import model as bench_model
    from phyir.learn.weights import save_weights
    from phyir.nets.model import PhyIRModel

    torch.manual_seed(3)
    weights = save_weights(PhyIRModel("lite"), tmp_path / "w" / "lite.safetensors")
    monkeypatch.setenv("PHYIR_BENCH_WEIGHTS", str(weights))
    monkeypatch.delenv("PHYIR_BENCH_DATA", raising=False)
    monkeypatch.delenv("PHYIR_BENCH_MODELS", raising=False)
    out = tmp_path / "out"
    res = bench_model.run_bench(out, quick=True, threads=1, log=lambda s: None)
    doc = _check_written(out, "model", res)
    rows = {(r["model"], tuple(r["net_size"])): r for r in doc["rows"]}
    cfg = bench_model.QUICK
    assert rows.keys() == {(m, tuple(ns)) for m in cfg["sizes"] for ns in cfg["net_sizes"]}
    for (model, _), r in rows.items():
        assert r["predict_s"] > 0 and r["network_s"] > 0 and r["scenes"] == cfg["data"]["count"]
        if model == "lite":  # trained-format weights: every error computed and finite
            assert r["weights"] == "lite.safetensors"
            assert all(math.isfinite(r[k]) and r[k] >= 0 for k in bench_model.ERROR_KEYS)
            assert r["relight_mean"] == pytest.approx(
                (r["relight_diffuse"] + r["relight_matte_silver"] + r["relight_mirror_silver"]) / 3)
        else:  # no trained full weights: timed only
            assert r["weights"] is None and all(r[k] is None for k in bench_model.ERROR_KEYS)
    assert "n/a" in bench_model.format_table(res)
    assert set(bench_model.key_numbers(res)) >= {"lite.32x64.depth_abs_rel", "full.64x128.predict_ms"}


@pytest.mark.slow
def test_shading_quick(tmp_path, ctx):
    from phyir.evaluation.metrics import RELIGHT_MATERIALS
    from viewer import bench_shading

    res = bench_shading.run_bench(tmp_path, quick=True, threads=1, log=lambda s: None)
    doc = _check_written(tmp_path, "shading", res)
    cfg = bench_shading.QUICK
    names = [s["name"] for s in bench_shading.settings_list(cfg)]
    rows = {(r["material"], r["setting"]): r for r in doc["rows"]}
    assert rows.keys() == {(m, n) for m in RELIGHT_MATERIALS for n in names}
    # the mirror is one look-up in both: exact up to float32 and texture filtering
    assert rows[("mirror_silver", "ggx 128")]["err"] < 2e-3
    # more GGX samples: the matte silver sphere converges; the viewer's full quality is close
    assert rows[("matte_silver", "ggx 128")]["err"] < 0.5 * rows[("matte_silver", "ggx 4")]["err"]
    assert rows[("matte_silver", "ggx 128")]["err"] < 0.05
    assert rows[("diffuse", "ggx 128")]["err"] < 0.05
    assert all(r["call_ms"] > 0 and r["frame_ms"] >= 0 for r in doc["rows"])
    assert bench_shading.key_numbers(res)


@pytest.mark.skipif(not Path("/proc/self/clear_refs").exists(), reason="needs Linux peak-RSS reset")
def test_render_memory_is_measured_in_fresh_processes():
    """Each case runs in its own child, so a case measured after a bigger one is not hidden by the
    memory that one freed (in one process, prefiltered-forward after importance-backward read ~0 MB),
    and the peaks order as the algorithms do."""
    from phyir.bench.render import memory_use

    rows = {(r["method"], r["grad"]): r for r in memory_use(64, 128, 4, log=lambda s: None)}
    assert len(rows) == 4 and all(r["probes_mb"] == pytest.approx(12.0) for r in rows.values())
    for method in ("importance", "prefiltered"):
        fwd, both = rows[(method, False)]["extra_peak_mb"], rows[(method, True)]["extra_peak_mb"]
        assert 0 < fwd < both  # the backward pass keeps the forward's saved tensors and adds gradients
    assert rows[("prefiltered", False)]["extra_peak_mb"] < rows[("importance", False)]["extra_peak_mb"]
