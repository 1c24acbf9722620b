"""``phyir --help`` and ``phyir info``, run as a user would (the installed console script)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image

from phyir import io

PHYIR = Path(sys.executable).with_name("phyir")
pytestmark = pytest.mark.skipif(not PHYIR.exists(), reason="phyir console script not installed")
H, W = 32, 64


def phyir(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([str(PHYIR), *args], capture_output=True, text=True, timeout=120)


def test_help_lists_info():
    r = phyir("--help")
    assert r.returncode == 0 and "info" in r.stdout and r.stderr == ""


@pytest.fixture(scope="module")
def info_run(tmp_path_factory):
    """One ``phyir info`` run over good and bad files (each CLI start pays for importing torch)."""
    d = tmp_path_factory.mktemp("info")
    rng = np.random.default_rng(0)
    img = rng.random((3, H, W), dtype=np.float32)
    img[0, 0, :3] = np.nan  # written with plain OpenEXR: phyir's writer refuses NaN
    depth = np.full((H, W), 2.5, np.float32)
    atlas = np.full((2 * 8, 4 * 16), 0.75, np.float32)
    OpenEXR.File([
        OpenEXR.Part({"phyir.source": "test"}, {"R": img[0], "G": img[1], "B": img[2], "depth.Z": depth,
                                                "mask.emission": depth / 5}, "scene"),
        OpenEXR.Part({"probeGrid": "2x4", "probeSize": "8x16", "displayWindow": ((0, 0), (W - 1, H - 1))},
                     dict.fromkeys("RGB", atlas), "probes"),
    ]).write(str(d / "scene.exr"))
    io.save_panorama(torch.ones(3, H, W), d / "plain.hdr")
    Image.new("RGB", (40, 40)).save(d / "square.png")
    (d / "broken.exr").write_bytes(b"\x00" * 100)
    files = [d / "scene.exr", d / "broken.exr", d / "plain.hdr", d / "missing.png", d / "square.png"]
    return d, phyir("info", *map(str, files))


def test_info_reports_layers_probes_and_nans(info_run):
    d, r = info_run
    out = r.stdout
    assert f"{d / 'scene.exr'}: OpenEXR (2 parts)" in out
    assert "part 'scene': 32x64 (HxW), FLOAT" in out
    assert "part 'probes': 16x64 (HxW), FLOAT, probe grid 2x4, probe size 8x16" in out
    scene_report = out.split("\n\n")[0]  # one block per file
    rows = {line.split()[0]: line.split() for line in scene_report.splitlines() if line.startswith("    ")}
    assert rows["image"][1] == "R,G,B" and rows["image"][5:] == ["3", "0"]  # 3 NaN, 0 Inf
    assert rows["depth"][1:] == ["depth.Z", "2.5", "2.5", "2.5", "0", "0"]
    assert rows["mask.emission"][1:4] == ["mask.emission", "0.5", "0.5"]
    assert rows["probes"][1:] == ["R,G,B", "0.75", "0.75", "0.75", "0", "0"]
    assert "attribute phyir.source = 'test'" in out
    assert "Radiance HDR (-Y 32 +X 64)" in out and "usable as a panorama: yes (32x64)" in out
    assert "PNG (8-bit RGB)" in out and "usable as a panorama: no (aspect ratio 40/40" in out


def test_info_bad_file_one_line_error_nonzero_exit(info_run):
    d, r = info_run
    assert r.returncode == 2
    assert r.stderr.splitlines() == [
        f"phyir info: error: {d / 'broken.exr'}: not an OpenEXR file (wrong magic number)",
        f"phyir info: error: {d / 'missing.png'}: no such file",
    ]
    assert "Traceback" not in r.stderr
