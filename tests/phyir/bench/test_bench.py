"""``phyir bench``: the quick run of every available target writes a complete, finite report; the
measuring helpers measure what they claim; user errors are one line."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from phyir.bench import measure as bench_measure
from phyir.bench import report as bench_report
from phyir.cli import main
from phyir.commands import bench


def _strict_json(path: Path) -> dict:
    def no_constants(name: str):
        raise AssertionError(f"{path}: non-finite value {name} in strict JSON")

    return json.loads(path.read_text(), parse_constant=no_constants)


def _numbers(obj, path=""):
    """(path, value) of every number in a JSON tree."""
    if isinstance(obj, bool):
        return
    if isinstance(obj, (int, float)):
        yield path, obj
    elif isinstance(obj, dict):
        for k, v in obj.items():
            yield from _numbers(v, f"{path}/{k}")
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _numbers(v, f"{path}/{i}")


# ---------------------------------------------------------------------------------------------
# the quick run (CI): every available target, report complete and finite


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    t0, c0 = time.perf_counter(), time.process_time()
    rc = main(["bench", "--quick", "--threads", "1", "-o", str(out)])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    assert rc == 0
    print(f"phyir bench --quick: {wall:.0f} s wall, {cpu:.0f} s CPU")
    return out, _strict_json(out / "report.json")


@pytest.mark.slow
def test_quick_report_complete_and_finite(quick_run):
    out, rep = quick_run
    assert set(bench_report.REPORT_KEYS) <= set(rep)
    assert set(rep["targets"]) == set(bench.available())  # the other helpers' targets once they exist
    assert {"modules", "skips", "render"} <= set(rep["targets"])
    assert rep["not_available"] == [t for t in bench.TARGETS if t not in bench.available()]
    for key in ("cpu", "cpu_cores", "torch", "device", "device_name"):
        assert rep["machine"][key] not in (None, "")
    for name, e in rep["targets"].items():
        assert set(bench_report.TARGET_KEYS) <= set(e), name
        assert e["seconds"] > 0 and e["table"].strip(), name
        assert (out / f"{name}.json").stat().st_size > 0, name
        assert e["plots"] and all((out / p).stat().st_size > 1000 for p in e["plots"]), name
        assert e["key_numbers"], name
        assert bench_report.unexpected_undefined(name, e) == [], name
        # every number anywhere in the entry is finite (strict JSON: NaN/Inf can't even be parsed)
        for path, v in _numbers(e):
            assert math.isfinite(v), f"{name}{path}"
    md = (out / "report.md").read_text()
    assert all(f"## {name} (" in md for name in rep["targets"])


@pytest.mark.slow
def test_quick_modules_numbers(quick_run):
    from phyir.bench.modules import PARTS

    _, rep = quick_run
    e = rep["targets"]["modules"]
    k = e["key_numbers"]
    for part in PARTS:
        assert k[f"lite.{part}.ms"] > 0
        if bench_measure.cpu_peak_supported():
            assert f"lite.{part}.peak_mb" in k
    if bench_measure.cpu_peak_supported():
        cal = e["result"]["memory_calibration"]  # a 64 MB tensor must measure as 64 MB (+ small change)
        assert cal["allocated_mb"] <= cal["extra_peak_mb"] < 1.15 * cal["allocated_mb"]
        mem = e["result"]["models"]["lite"]["memory"]
        assert mem["predict"]["total_peak_mb"] > mem["predict"]["extra_peak_mb"] > 0


@pytest.mark.slow
def test_quick_skips_numbers(quick_run):
    from phyir.bench.skips import VARIANTS

    _, rep = quick_run
    rows = rep["targets"]["skips"]["result"]["predict"]["rows"]
    assert set(rows) == set(VARIANTS)
    # skips that leave the compared layers alone change nothing
    assert rows["geometry_only"]["diff"]["depth"] == 0 and rows["geometry_only"]["diff"]["normal"] == 0
    assert rows["no_probes"]["max_diff"] == 0
    assert rows["reuse_all"]["computed"] == "" and rows["reuse_all"]["max_diff"] == 0
    assert rows["reuse_layers"]["computed"] == "probes"
    assert rows["reuse_layers"]["diff"]["albedo"] < 1e-6  # read back from a float32 scene file
    assert rows["points"]["diff"]["probes"] > 0  # a probe at the point is not the grid's interpolation
    # reusing everything skips all the work: far cheaper than the full run, in CPU time too
    assert rows["reuse_all"]["cpu_s"] < 0.2 * rows["full"]["cpu_s"]
    render = rep["targets"]["skips"]["result"]["render"]
    assert {e["skip"] for e in render} == {"emissive", "mirror", "rough", "rough_all_cosine"}


# ---------------------------------------------------------------------------------------------
# user errors: one line, exit 2


@pytest.mark.parametrize("argv, words", [
    (["bench", "nosuch"], "unknown benchmark"),
    (["bench", "modules", "--repeats", "0"], "--repeats"),
    (["bench", "modules", "--device", "tpu"], "expected cpu or cuda"),
])
def test_user_errors_one_line(argv, words, capsys, tmp_path):
    assert main([*argv, "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err


def test_cuda_missing_is_a_user_error(capsys, tmp_path):
    if torch.cuda.is_available():
        pytest.skip("CUDA is available here")
    assert main(["bench", "modules", "--device", "cuda", "-o", str(tmp_path)]) == 2
    assert "CUDA is not available" in capsys.readouterr().err


def test_output_that_is_a_file(capsys, tmp_path):
    f = tmp_path / "x"
    f.write_text("")
    assert main(["bench", "modules", "-o", str(f)]) == 2
    assert "not a folder" in capsys.readouterr().err


def test_every_registered_target_module_is_named_consistently():
    assert set(bench.available()) <= set(bench.TARGETS)
    assert {"modules", "skips", "render"} <= set(bench.available())


# ---------------------------------------------------------------------------------------------
# measuring helpers


def test_time_calls_counts_and_orders():
    n = {"a": 0, "b": 0}

    def sleeper(key, s):
        def call():
            n[key] += 1
            time.sleep(s)
        return call

    r = bench_measure.time_calls({"a": sleeper("a", 0.02), "b": sleeper("b", 0.0)}, "cpu", repeats=3)
    assert n == {"a": 4, "b": 4}  # one warm-up + 3 timed runs each
    a = r["a"]
    assert a["repeats"] == 3 and a["time_s"] == a["median_s"]
    assert 0.02 <= a["min_s"] <= a["q1_s"] <= a["median_s"] <= a["q3_s"] <= a["max_s"]
    assert a["cpu_s"] < 0.015  # sleeping costs no CPU
    assert r["b"]["median_s"] < a["median_s"]


def test_spread_quartiles():
    s = bench_measure.spread([4.0, 1.0, 3.0, 2.0, 5.0])
    assert (s["min_s"], s["q1_s"], s["median_s"], s["q3_s"], s["max_s"]) == (1.0, 2.0, 3.0, 4.0, 5.0)
    assert bench_measure.spread([7.0])["q3_s"] == 7.0


def test_peak_memory_cpu_sees_a_known_allocation():
    if not bench_measure.cpu_peak_supported():
        pytest.skip("no /proc/self/clear_refs")
    # in a fresh process with MALLOC_ENV, as the benchmarks measure: in this process, after the quick
    # run's render target, a 96 MB tensor measured +0.04 MB (its pages were resident already)
    mb = 96
    code = ("import json, torch; from phyir.bench import measure as b; "
            f"print(json.dumps(b.peak_memory(lambda: torch.ones({mb} * 2**18).sum(), 'cpu')))")
    env = {**os.environ, **bench_measure.MALLOC_ENV}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, check=True)
    r = json.loads(out.stdout.strip().splitlines()[-1])
    assert mb * 0.98 <= r["extra_peak_mb"] < mb * 1.3
    assert r["total_peak_mb"] > r["extra_peak_mb"]


def test_sanitize_marks_non_finite_values():
    und: list[str] = []
    obj = {"a": [1.0, float("nan")], "b": {"c": float("inf")}, "t": (1, "x")}
    clean = bench_report.sanitize(obj, "", und)
    assert clean == {"a": [1.0, None], "b": {"c": None}, "t": [1, "x"]}
    assert und == ["a/1", "b/c"]
    entry = {"undefined": ["scenes/metal/rows/3/err_diffuse", "scenes/glossy/rows/0/err_image"],
             "key_numbers_undefined": []}
    assert bench_report.unexpected_undefined("render", entry) == ["scenes/glossy/rows/0/err_image"]
    with pytest.raises(TypeError):
        bench_report.sanitize({"x": object()})


def test_machine_info_describes_this_machine():
    m = bench_measure.machine_info("cpu")
    assert m["cpu_cores"] >= 1 and m["torch"] == torch.__version__ and m["device_name"] == "cpu"


def _entry(cmd: str) -> dict:
    return {"date": "2026-01-01 00:00 UTC", "command": cmd, "seconds": 1.0, "table": "t",
            "key_numbers": {"x": 1.0}, "plots": [], "undefined": [], "result": {}}


def test_report_keeps_earlier_targets_of_the_same_kind(tmp_path):
    machine = bench_measure.machine_info("cpu")

    def write(name, quick=False):
        (tmp_path / f"{name}.json").write_text("{}")
        bench_report.write_report(tmp_path, bench_report.build_report(
            {name: _entry(f"phyir bench {name}")}, command="c", quick=quick, device="cpu", threads=1,
            repeats=None, machine=machine, not_available=[], total_seconds=1.0))
        return _strict_json(tmp_path / "report.json")

    write("a")
    got = write("b")
    assert set(got["targets"]) == {"a", "b"} and got["merged_from_earlier"] == ["a"]
    assert got["targets"]["a"]["command"] == "phyir bench a" and "machine" in got["targets"]["a"]
    md = (tmp_path / "report.md").read_text()
    assert "(from an earlier run: 2026-01-01 00:00 UTC, `phyir bench a`" in md
    # a quick report never mixes with a full one
    assert set(write("c", quick=True)["targets"]) == {"c"}
    write("a")
    write("b")
    # a target whose JSON is gone is dropped
    (tmp_path / "a.json").unlink()
    assert set(write("d")["targets"]) == {"b", "d"}
