"""phyir-view's command line: bad numbers are refused in one line, --gt opens a ground truth."""

from __future__ import annotations

import pytest
from support.scenes import box_room

from phyir.io import save_scene
from viewer.app.cli import main, parser


@pytest.mark.parametrize("args", [["--zoom", "nan"], ["--zoom", "0"], ["--fov", "0"], ["--fov", "inf"],
                                  ["--center", "nan,nan"], ["--probe", "1,inf"], ["--pitch", "91"],
                                  ["--exposure", "nan"]])
def test_non_finite_or_out_of_range_view_options_are_refused(args, capsys):
    with pytest.raises(SystemExit) as e:
        parser().parse_args(["scene.exr", *args])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert args[0] in err and ("finite" in err or "expected" in err)


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory, egl):
    path = tmp_path_factory.mktemp("cli") / "room.exr"
    save_scene(box_room(32, 64, variant="viewer"), path)
    return path


def test_probe_outside_the_panorama_is_an_error_not_a_clamp(scene_file, tmp_path, capsys):
    rc = main([str(scene_file), "--no-model", "--headless", "--probe", "5000,5000",
               "--screenshot", str(tmp_path / "s.png")])
    assert rc == 2
    err = capsys.readouterr().err
    assert "--probe 5000,5000: outside the 64x32 panorama" in err and len(err.strip().splitlines()) == 1


def test_gt_opens_a_ground_truth_scene(scene_file, tmp_path):
    out = tmp_path / "gt.png"
    rc = main([str(scene_file), "--gt", str(scene_file), "--no-model", "--headless",
               "--screenshot", str(out)])
    assert rc == 0 and out.stat().st_size > 1000
