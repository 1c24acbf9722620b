"""``phyir insert`` end to end on a scene file, headless (EGL); errors exit 2 with one line."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from support.scenes import box_room

from phyir.cli import main
from phyir.io import exr, save_panorama, save_scene

moderngl = pytest.importorskip("moderngl")


@pytest.fixture(scope="module")
def scene_file(egl, tmp_path_factory):
    path = tmp_path_factory.mktemp("insert") / "room.exr"
    save_scene(box_room(64, 128), path)
    return path


def test_command_module_imports_no_gl():
    code = ("import sys, argparse, viewer.commands.insert as m; m.add_arguments(argparse.ArgumentParser());"
            "print(any(k in sys.modules for k in ('moderngl', 'viewer.insertion', 'trimesh')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_insert_writes_passes_and_png(scene_file, tmp_path, capsys):
    out = tmp_path / "ball.exr"
    rc = main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.25", "--at", "40,50",
               "--material", "matte-silver", "--quality", "draft", "-o", str(out)])
    assert rc == 0
    assert (tmp_path / "ball.png").stat().st_size > 1000
    headers = exr.read_headers(out)
    (h,) = headers
    assert set(h.channels) == {"R", "G", "B", "object.A", "shadow.Y", "object.R", "object.G", "object.B"}
    assert (h.height, h.width) == (64, 128)  # the panorama's resolution
    (chans,) = exr.read_pixels(out, headers)
    alpha, matte = chans["object.A"], chans["shadow.Y"]
    assert 10 < alpha.sum() < 200 and matte.max() > 0.2
    assert h.strings["phyir.material"] == "0.972,0.96,0.915,0.5,1"
    assert "wrote" in capsys.readouterr().out


def test_insert_perspective_and_position(scene_file, tmp_path):
    out = tmp_path / "cube.exr"
    rc = main(["insert", str(scene_file), "--object", "cube", "--scale", "0.2", "--position", "0.8,-1.0,-2.5",
               "--view", "perspective", "--size", "96x64", "--quality", "draft", "-o", str(out)])
    assert rc == 0
    headers = exr.read_headers(out)
    assert (headers[0].width, headers[0].height) == (96, 64)
    alpha = exr.read_pixels(out, headers)[0]["object.A"]
    # the view is aimed at the cube: its pixels are around the image centre
    ys, xs = np.nonzero(alpha > 0.5)
    assert len(xs) > 20
    assert abs(xs.mean() - 48) < 5 and abs(ys.mean() - 32) < 5


def test_dynamic_insertion_frames_gif_and_flicker(scene_file, tmp_path):
    out = tmp_path / "move.exr"
    rc = main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.2", "--path", "30,50:50,50",
               "--frames", "4", "--quality", "draft", "-o", str(out)])
    assert rc == 0
    for i in range(4):
        assert (tmp_path / f"move_{i:04d}.exr").exists() and (tmp_path / f"move_{i:04d}.png").exists()
    from PIL import Image

    gif = Image.open(tmp_path / "move.gif")
    assert gif.n_frames == 4
    stats = json.loads((tmp_path / "move_flicker.json").read_text())
    assert stats["static_background_change"] == 0.0  # untouched pixels are the panorama, bit for bit
    assert stats["object_step"] < 0.1


def test_user_errors_exit_2_with_one_line(scene_file, tmp_path, capsys):
    plain = tmp_path / "plain.hdr"
    import torch

    save_panorama(torch.rand(3, 16, 32), plain)
    cases = [
        (["--object", "sphere", "--at", "500,10"], "outside the 128x64 panorama"),
        (["--object", "sphere", "--at", "10,50", "--material", "gold"], "--material"),
        (["--object", "teapot", "--at", "10,50"], "--object"),
        (["--object", "sphere", "--at", "1,2", "-o", str(tmp_path / "a.jpg")], "must be .exr"),
    ]
    for extra, msg in cases:
        argv = ["insert", str(scene_file), *extra]
        if "-o" not in extra:
            argv += ["-o", str(tmp_path / "x.exr")]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and "\n" not in err, err
    assert main(["insert", str(plain), "--object", "sphere", "--at", "1,2",
                 "--weights", str(tmp_path / "none"), "-o", str(tmp_path / "x.exr")]) == 2
    cap = capsys.readouterr()
    assert "plain.hdr: no depth or probes: predicting" in cap.out  # a plain panorama goes through the model
    assert "weights" in cap.err and "\n" not in cap.err.strip()


def test_perspective_export_has_no_line_at_the_panorama_seam(scene_file, tmp_path):
    """A view across the seam (near +z, longitude ±180°, slanted so it crosses 2x2 pixel quads) of
    a background that is smooth and constant in longitude: every background pixel agrees with its row
    neighbours (a mip level picked from the coordinate's jump at the seam showed as a line of the
    image's mean: second difference 0.32 before the fix)."""
    from phyir.io import load_scene

    scene = load_scene(scene_file)
    H, W = scene.size
    v = (np.arange(H) + 0.5) / H
    bg = np.broadcast_to((1 + 4 * (v - 0.5) ** 2)[None, :, None], (3, H, W)).astype(np.float32)
    import torch

    path = tmp_path / "seam.exr"
    save_scene(scene.replace(image=torch.from_numpy(bg.copy())), path)
    out = tmp_path / "seam_view.exr"
    rc = main(["insert", str(path), "--object", "sphere", "--scale", "0.1", "--position", "0.3,-1.0,1.2",
               "--view", "perspective", "--size", "96x64", "--quality", "draft", "-o", str(out)])
    assert rc == 0
    (c,) = exr.read_pixels(out, exr.read_headers(out))
    g = c["G"]
    bg_px = (c["object.A"] == 0) & (c["shadow.Y"] < 1e-3)
    # second difference along each row, where three neighbours are background
    keep = bg_px[:, :-2] & bg_px[:, 1:-1] & bg_px[:, 2:]
    d2 = np.abs(g[:, :-2] - 2 * g[:, 1:-1] + g[:, 2:])[keep]
    assert keep.sum() > 1000
    assert d2.max() < 0.02, d2.max()


def test_a_ceiling_point_is_warned_about_in_one_line(scene_file, tmp_path, capsys):
    """--at on the ceiling hangs the object there upside down (a pendant lamp): allowed, but said,
    naming --at (a row counted in another image size lands near the zenith without a word)."""
    from phyir.io import load_scene

    H = load_scene(scene_file).size[0]
    rc = main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.2", "--at", "64,5",
               "--quality", "draft", "-o", str(tmp_path / "lamp.exr")])
    assert rc == 0
    (err,) = capsys.readouterr().err.strip().splitlines()
    assert err.startswith("phyir insert: warning: --at 64,5: the point is on the ceiling")
    assert f"a row over {H // 2} of {H}" in err
    h = exr.read_headers(tmp_path / "lamp.exr")[0]
    alpha = exr.read_pixels(tmp_path / "lamp.exr", [h])[0]["object.A"]
    assert np.nonzero(alpha > 0.5)[0].mean() < H / 4  # drawn where it was put, hanging near the top
    # on the floor: nothing to say; a path that touches the ceiling: how many of its points do
    assert main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.2", "--at", "40,50",
                 "--quality", "draft", "-o", str(tmp_path / "floor.exr")]) == 0
    assert capsys.readouterr().err == ""
    assert main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.2", "--path", "40,50:64,5",
                 "--frames", "3", "--quality", "draft", "-o", str(tmp_path / "up.png")]) == 0
    err = capsys.readouterr().err
    assert "phyir insert: warning: --path: 1 of 3 points are on the ceiling" in err or \
        "phyir insert: warning: --path: 2 of 3 points are on the ceiling" in err, err


def test_at_takes_pixels_or_fractions_of_the_size(scene_file, tmp_path, capsys):
    """``--at 0.3125,0.78125`` on the 128x64 room is the point at 40, 50 (pixel 39.5, 49.5 as --at
    counts them, centres at +0.5): the same picture; ``--help`` says which is which."""
    from phyir.commands import options

    point = options.image_point(1e6)
    assert point("0.5,0.78").fraction and point(" 0.0, 1.0").fraction
    for pixels in ("0,1", "1,0", "0.5,2", "1.5,0.5", "40,50", "1e-1,0.5"):
        assert not point(pixels).fraction, pixels
    assert options.to_pixels(point("0.5,0.78"), 1024, 512) == (511.5, pytest.approx(398.86))
    assert options.to_pixels(point("0.0,0.0"), 128, 64) == (127.5, 0.0)  # the seam: column 0's left edge
    assert options.to_pixels((40.0, 50.0), 128, 64) == (40.0, 50.0)
    outs = {}
    for at in ("0.3125,0.78125", "39.5,49.5"):
        out = tmp_path / f"{at}.exr"
        assert main(["insert", str(scene_file), "--object", "sphere", "--scale", "0.25", "--at", at,
                     "--quality", "draft", "-o", str(out)]) == 0
        (outs[at],) = exr.read_pixels(out, exr.read_headers(out))
    assert outs["0.3125,0.78125"]["object.A"].sum() > 10
    for name in ("R", "G", "B", "object.A"):
        assert np.array_equal(outs["0.3125,0.78125"][name], outs["39.5,49.5"][name]), name
    capsys.readouterr()
    assert main(["insert", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "pixel column U, row V" in text and "fractions of the width and height" in text
