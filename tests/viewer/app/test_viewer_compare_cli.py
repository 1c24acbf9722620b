"""phyir-view's comparison options: several files, --reference, --compare MODE, --split; bad ones are
refused in one line naming the option or the file."""

from __future__ import annotations

import numpy as np
import pytest
from support.scenes import box_room

from phyir.io import save_scene
from phyir.scene import PanoScene
from viewer.app.cli import main, parser

pytestmark = pytest.mark.gl

H, W = 64, 128  # shown 1:1 in a 128x64 window without the interface


@pytest.fixture(scope="module")
def files(tmp_path_factory, egl):
    folder = tmp_path_factory.mktemp("compare")
    room = box_room(H, W, variant="viewer")
    a, b = folder / "a.exr", folder / "b.exr"
    save_scene(PanoScene(image=room.image), a)
    save_scene(PanoScene(image=room.image * 0.6 + 0.05), b)
    return a, b


def read_png(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(np.float64)


def test_reference_and_sqerr_screenshot_headless_match_numpy(files, tmp_path):
    from phyir import io
    from viewer import compare
    from viewer.layers import scene_arrays
    from viewer.renderer import colormap_lut

    a, b = files
    out = tmp_path / "s.png"
    rc = main([str(a), "--reference", str(b), "--compare", "sqerr", "--no-model", "--headless", "--no-ui",
               "--size", f"{W}x{H}", "--screenshot", str(out)])
    assert rc == 0
    got = read_png(out)
    values = compare.compare_values(scene_arrays(io.load_scene(a))["image"],
                                    scene_arrays(io.load_scene(b))["image"], "sqerr")
    t = values / compare.auto_extent(values)
    lut = colormap_lut(compare.COLORMAP["sqerr"])
    x = np.clip(t, 0, 1) * 255
    want = np.stack([np.interp(x, np.arange(256), lut[:, k]) for k in range(3)], -1) * 255
    assert got.shape == want.shape and np.abs(got - want).max() <= 1.5
    assert values.std() > 0.01  # the two files differ: the test could fail


def test_two_files_split_at_a_third(files, tmp_path):
    a, b = files
    shots = {}
    for name, args in (("a", [str(a)]), ("b", [str(b)]), ("split", [str(a), str(b), "--split", "0.33"])):
        out = tmp_path / f"{name}.png"
        assert main([*args, "--no-model", "--headless", "--no-ui", "--size", f"{W}x{H}",
                     "--screenshot", str(out)]) == 0
        shots[name] = read_png(out)
    col = int(0.33 * W)
    assert np.array_equal(shots["split"][:, :col], shots["a"][:, :col])
    assert np.array_equal(shots["split"][:, col + 1 :], shots["b"][:, col + 1 :])
    assert np.abs(shots["a"] - shots["b"]).mean() > 5


@pytest.mark.parametrize("args,says", [(["--compare", "ratio"], "--compare: invalid choice"),
                                       (["--split", "1.5"], "--split must be a finite number in [0, 1]"),
                                       (["--split", "nan"], "--split must be a finite number")])
def test_bad_comparison_options_are_refused_in_one_line(args, says, capsys):
    with pytest.raises(SystemExit) as e:
        parser().parse_args(["a.exr", *args])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0]


def test_a_comparison_without_a_reference_or_with_a_missing_one_is_one_line(files, tmp_path, capsys):
    a, _ = files
    out = str(tmp_path / "s.png")
    assert main([str(a), "--compare", "diff", "--headless", "--screenshot", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["phyir-view: --compare diff needs a reference: --reference FILE or a second image"]
    missing = tmp_path / "missing.exr"
    assert main([str(a), "--reference", str(missing), "--compare", "diff", "--no-model", "--headless",
                 "--screenshot", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"phyir-view: --reference {missing}: ")
    assert "missing.exr" in err[0].partition(": ")[2].partition(": ")[2]  # the reason names the file too


def test_compare_alone_still_means_ground_truth(files):
    args = parser().parse_args([str(files[0]), "--compare"])
    assert args.compare == "truth"
    args = parser().parse_args([str(files[0]), str(files[1]), "--compare", "reldiff"])
    assert args.compare == "reldiff" and args.path == [str(files[0]), str(files[1])]
