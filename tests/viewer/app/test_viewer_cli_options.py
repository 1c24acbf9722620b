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


def test_object_options_belong_to_the_object_before_them(capsys):
    from viewer.app.cli_objects import ObjectSpec

    args = parser().parse_args(["s.exr", "--object", "sphere", "--at", "10,5", "--scale", "0.1",
                                "--object", "cube", "--position", "0,-1,-2", "--material", "mirror-silver",
                                "--object", "chair.glb"])
    assert args.objects == [ObjectSpec("sphere", at=(10.0, 5.0), scale=0.1),
                            ObjectSpec("cube", position=(0.0, -1.0, -2.0), material="mirror-silver"),
                            ObjectSpec("chair.glb")]
    for bad, says in ((["--at", "1,2"], "--at needs an --object before it"),
                      (["--object", "sphere", "--at", "1,2", "--position", "0,0,-1"],
                       "one of --at or --position"),
                      (["--object", "sphere", "--scale", "nan"], "--scale"),
                      (["--object", "sphere", "--scale", "1e30"], "--scale"),
                      (["--object", "sphere", "--position", "0,inf,1"], "--position: expected 3 finite")):
        with pytest.raises(SystemExit) as e:
            parser().parse_args(["s.exr", *bad])
        assert e.value.code == 2
        assert says in capsys.readouterr().err.strip().splitlines()[-1]


def test_object_on_the_command_line_is_inserted_in_the_screenshot(scene_file, tmp_path):
    import numpy as np
    from PIL import Image

    shots = {}
    for name, extra in (("plain", []), ("sphere", ["--object", "sphere", "--at", "32,26", "--scale", "0.4",
                                                    "--material", "0.9,0.1,0.1,0.5,0"])):
        out = tmp_path / f"{name}.png"
        assert main([str(scene_file), "--no-model", "--headless", "--no-ui", "--size", "512x256",
                     "--screenshot", str(out), *extra]) == 0
        shots[name] = np.asarray(Image.open(out)).astype(int)
    changed = np.abs(shots["sphere"] - shots["plain"]).sum(-1) > 30
    rows, cols = np.nonzero(changed)
    assert changed.sum() > 200  # the red ball (and its shadow) is there ...
    assert rows.min() > 256 * 0.45 and abs(np.median(cols) - 256) < 40  # ... below the horizon at column 32
    red = shots["sphere"][changed]
    assert (red[:, 0] > red[:, 1] + 20).mean() > 0.5


def test_object_that_cannot_be_loaded_is_a_one_line_error(scene_file, tmp_path, capsys):
    rc = main([str(scene_file), "--no-model", "--headless", "--screenshot", str(tmp_path / "s.png"),
               "--object", str(tmp_path / "nothere.obj")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "nothere.obj" in err[0]


def test_camera_inside_an_object_is_an_error_on_the_command_line(scene_file, tmp_path, capsys):
    rc = main([str(scene_file), "--no-model", "--headless", "--screenshot", str(tmp_path / "s.png"),
               "--object", "sphere", "--position", "0,0,0", "--scale", "0.3"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--object sphere: the camera is inside the object" in err[0]


@pytest.mark.parametrize("argv,typo,near", [
    (["s.exr", "--layr", "depth"], "--layr", "--layer"),
    (["s.exr", "--object", "sphere", "--att", "1,2"], "--att", "--at"),
    (["s.exr", "--yaw", "-30", "--pich", "3"], "--pich", "--pitch"),
])
def test_a_mistyped_option_suggests_the_nearest(argv, typo, near, capsys):
    """As phyir's subcommands: the nearest option and phyir-view's --help, in one line."""
    with pytest.raises(SystemExit) as e:
        parser().parse_args(argv)
    assert e.value.code == 2
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert err == (f"phyir-view: error: unrecognized option {typo} (did you mean {near}?) "
                   "(see phyir-view --help)")
