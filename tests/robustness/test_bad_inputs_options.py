"""Bad-input corpus, issue 22 classes 5-8 (generated here, nothing committed): silent nonsense
(absurd EXPOSURE, the camera inside an object, nothing visible, depth not in metres), weights
metadata beyond its bounds, NaN/Inf/int8 tensors, numeric options of every command (non-finite,
out of range, sizes beyond the documented limits), ``--path`` across the seam, streamed animation
frames, and ``phyir train`` (worker errors, bad numbers, resuming with other options).
Outcomes: docs/robustness.md, "Silent nonsense, weights metadata, numeric options, train"."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import weakref
from pathlib import Path

import numpy as np
import pytest
import torch
from support.memory import PEAK_MB
from support.scenes import box_room
from support.tiny_scenes import write_dataset

import phyir
from phyir import io
from phyir.cli import main
from phyir.errors import InputError
from phyir.insert import placement, views
from phyir.insert.objects import SceneObject, primitive
from phyir.learn.weights import load_model

pytestmark = pytest.mark.usefixtures("one_thread")
REPO = Path(__file__).resolve().parents[2]
# every spelling of "not a finite number" float() accepts, and words it refuses
NON_FINITE = ("nan", " nan", "-nan", "NaN", "inf", "-inf", "Infinity", "1e309", "-1e400")
NOT_NUMBERS = ("0x1p5", "abc", "", "1,5", "1e")


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # argparse refusals
        rc = e.code
    return rc, capsys.readouterr().err.strip()


def refused(argv, capsys, name: str, outputs=(), progress: bool = False) -> str:
    """Exit 2, one line on stderr naming ``name`` (after the command's progress lines when
    ``progress``), no traceback, none of ``outputs`` written; returns the error line."""
    rc, err = run_cli(argv, capsys)
    assert rc == 2, (argv, err)
    assert "Traceback" not in err, (argv, err)
    line = err.splitlines()[-1] if progress else err
    assert "\n" not in line and name in line and " error: " in line, (argv, err)
    for p in outputs:
        assert not Path(p).exists(), (argv, p)
    return line


# ---------------------------------------------------------------------------------------------
# class 5: a .hdr's EXPOSURE


def hdr_with_exposure(path: Path, *values: str) -> Path:
    io.save_panorama(torch.full((3, 8, 16), 0.5), path)
    data = path.read_bytes()
    head, rest = data.split(b"\n", 1)
    lines = b"".join(b"EXPOSURE=" + v.encode() + b"\n" for v in values)
    path.write_bytes(head + b"\n" + lines + rest)
    return path


@pytest.mark.parametrize("values", [("1e300",), ("1e-300",), ("1e-40",), ("1e20",), ("nan",), ("inf",),
                                    ("0",), ("-2",), ("1e10", "1e10"), ("1e-12", "1e-12")])
def test_absurd_hdr_exposure_is_refused(tmp_path, capsys, values):
    p = hdr_with_exposure(tmp_path / "e.hdr", *values)
    with pytest.raises(InputError, match="EXPOSURE") as e:
        io.load_scene(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)
    refused(["info", p], capsys, str(p))


def test_plausible_hdr_exposure_is_divided_out(tmp_path):
    s = io.load_scene(hdr_with_exposure(tmp_path / "e.hdr", "4", "0.5"))
    assert torch.allclose(s.image, torch.full_like(s.image, 0.25), rtol=1e-2)


# ---------------------------------------------------------------------------------------------
# class 5: renders that show nothing, or the object's inside


def test_camera_inside_objects():
    """Within 1.02 x the bounding sphere: the renderer can't draw the object (it is drawn as an
    impostor from outside that sphere)."""
    sphere = SceneObject(primitive("sphere"), scale=0.25)
    assert placement.camera_inside([sphere]) is not None  # centred on the camera
    sphere.position = np.array([0.0, 0.0, -0.2])
    assert "inside the object 'sphere'" in placement.camera_inside([sphere])
    sphere.position = np.array([0.0, 0.0, -0.26])
    assert placement.camera_inside([sphere]) is None
    cube = SceneObject(primitive("cube"), scale=0.5, position=np.array([0.0, 0.0, -0.8]))
    assert placement.camera_inside([cube]) is not None  # outside the box, inside its sphere (0.87 m)
    cube.position = np.array([0.0, 0.0, -0.9])
    assert placement.camera_inside([cube]) is None
    cube.visible = False
    cube.position = np.zeros(3)
    assert placement.camera_inside([cube]) is None  # hidden objects don't count
    assert placement.camera_inside([sphere], camera=(0.0, 0.0, -0.3)) is not None


def test_coverage_problems():
    a = np.zeros((8, 16), np.float32)
    assert "no object is visible" in placement.coverage_problem(a)
    a[2:4, 3:5] = 1
    assert placement.coverage_problem(a) is None
    assert "covers the whole view" in placement.coverage_problem(np.ones((8, 16), np.float32))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    folder = tmp_path_factory.mktemp("room")
    path = folder / "room.exr"
    scene = box_room(64, 128)
    io.save_scene(scene, path)
    far = folder / "far.exr"
    io.save_scene(scene.replace(depth=torch.full_like(scene.depth, 1e30)), far)
    return path, far


def cube_obj(path: Path, size: float, offset: float = 0.0) -> Path:
    """An OBJ cube of edge ``size`` whose centre is at (offset, 0, offset)."""
    h = size / 2
    v = [(x * h + offset, y * h, z * h + offset) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    f = [(1, 3, 4), (1, 4, 2), (5, 6, 8), (5, 8, 7), (1, 2, 6), (1, 6, 5), (3, 7, 8), (3, 8, 4),
         (1, 5, 7), (1, 7, 3), (2, 4, 8), (2, 8, 6)]
    path.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + "".join(f"f {a} {b} {c}\n" for a, b, c in f))
    return path


@pytest.mark.parametrize("extra", [
    ["--object", "sphere", "--position", "0,0,0"],
    ["--object", "sphere", "--position", "0.1,-0.1,0.1", "--scale", "0.5"],
    ["--object", "cube", "--at", "40,50", "--scale", "30"],
    ["--object", "cylinder", "--path", "30,50:50,50", "--scale", "40"],
    ["--object", "CM_CUBE", "--at", "40,50"],  # a 80 cm cube modelled in centimetres: 80 m
])
def test_insert_refuses_the_camera_inside_the_object(room, tmp_path, capsys, extra):
    extra = [str(cube_obj(tmp_path / "cm.obj", 80.0)) if x == "CM_CUBE" else x for x in extra]
    err = refused(["insert", room[0], *extra, "-o", tmp_path / "o.exr"], capsys, "camera is inside",
                  [tmp_path / "o.exr", tmp_path / "o.png", tmp_path / "o_0000.exr"])
    assert err.startswith("phyir insert: error: --")


def test_insert_refuses_depth_that_is_not_metres(room, tmp_path, capsys):
    refused(["insert", room[1], "--object", "sphere", "--at", "40,50", "-o", tmp_path / "o.exr"], capsys,
            "--at", [tmp_path / "o.exr"])


def test_insert_warns_when_nothing_or_only_the_object_is_visible(room, tmp_path, capsys, egl):
    hidden = ["--position", "0.5,-1.7,-1", "--scale", "0.01"]  # under the floor
    rc, err = run_cli(["insert", room[0], "--object", "sphere", *hidden, "--quality", "draft",
                       "-o", tmp_path / "a.png"], capsys)
    assert rc == 0 and "warning: --position: no object is visible" in err
    close = ["--object", "cube", "--position", "0,0,-2", "--scale", "1", "--view", "perspective",
             "--size", "32x24", "--quality", "draft"]
    rc, err = run_cli(["insert", room[0], *close, "-o", tmp_path / "b.png"], capsys)
    assert rc == 0 and "covers the whole view" in err
    rc, err = run_cli(["insert", room[0], "--object", "sphere", "--at", "40,50", "--quality", "draft",
                       "-o", tmp_path / "c.png"], capsys)
    assert rc == 0 and "warning" not in err  # the default 25 cm sphere on the floor


def test_mesh_far_from_its_origin_stands_where_it_is_put(room, tmp_path, egl):
    """``--at`` stands the mesh's footprint centre on the point, wherever its local origin is: a cube
    modelled 100 m from its origin covers the same pixels as the same cube around its origin."""
    alphas = []
    for name, offset in (("near", 0.0), ("far", 100.0)):
        mesh = cube_obj(tmp_path / f"{name}.obj", 0.4, offset)
        out = tmp_path / f"{name}.exr"
        assert main(["insert", str(room[0]), "--object", str(mesh), "--at", "40,50", "--quality", "draft",
                     "-o", str(out)]) == 0
        alphas.append(io.exr.read_pixels(out, io.exr.read_headers(out))[0]["object.A"])
    assert alphas[0].sum() > 20
    assert abs(alphas[1].sum() / alphas[0].sum() - 1) < 0.01 and np.abs(alphas[0] - alphas[1]).max() < 0.05


def test_default_scale_primitives_25cm_meshes_their_units(tmp_path):
    assert views.make_object("sphere", None, "diffuse").bounding_sphere()[1] == pytest.approx(0.25, rel=1e-3)
    mesh = views.make_object(str(cube_obj(tmp_path / "m.obj", 2.0)), None, "diffuse")
    assert mesh.scale == 1.0
    from viewer.commands import insert as cmd

    assert (cmd.FOV, cmd.SCALE, cmd.RENDER_SIDE) == ((views.MIN_FOV, views.MAX_FOV),
                                                    (views.MIN_SCALE, views.MAX_SCALE), views.MAX_RENDER_SIDE)
    assert (cmd.POSITION, cmd.RENDER_PIXELS) == (views.MAX_DISTANCE, views.MAX_RENDER_PIXELS)
    from phyir.commands import export

    assert export.POSITION == views.MAX_DISTANCE


# ---------------------------------------------------------------------------------------------
# class 7: numeric options


INSERT_BAD = [("--position", v) for v in ("nan,0,0", "0,inf,0", "1e309,1,1", "0,0", "1,2,3,4",
                                          "2000,0,0")] + \
    [("--at", v) for v in ("nan,10", "10,-inf", "10", "1e309,3")] + \
    [("--fov", v) for v in ("0", "5", "151", "-60", *NON_FINITE, *NOT_NUMBERS)] + \
    [("--yaw", v) for v in ("nan", "inf", "1e309", "4000")] + \
    [("--pitch", v) for v in ("nan", "91", "-1e309")] + \
    [("--exposure", v) for v in ("nan", "inf", "-inf", "65", "1e309", "0x1p3")] + \
    [("--scale", v) for v in ("0", "-1", "nan", "1e30", "inf", "1e-9")] + \
    [("--frames", v) for v in ("0", "1", "1.5", "1e309", "100000", "nan")] + \
    [("--size", v) for v in ("0x0", "16384x8192", "8x0", "axb", "8193x8", "-64x-32", "4097x4096",
                             "64x64x2", "nanxnan")]


def test_option_types():
    import argparse

    from phyir.commands import options

    n = options.number(1, 10)
    assert (n(" 2"), n("1_0"), n("1e0")) == (2.0, 10.0, 1.0)
    i = options.number(0, 100, integer=True)
    assert (i("4"), i("4.0"), i("1e2")) == (4, 4, 100) and isinstance(i("4.0"), int)
    assert options.numbers(2, -1, 1)("0.5,-1") == (0.5, -1.0)
    assert options.size(8, 64, order="HxW", multiple=8)("16X32") == (16, 32)
    for parse, text in [(n, v) for v in (*NON_FINITE, *NOT_NUMBERS, "0.99", "11")] + \
            [(i, "4.5"), (i, "nan"), (options.numbers(2, -1, 1), "1"), (options.numbers(2, -1, 1), "0,2"),
             (options.size(8, 64, multiple=8), "12x16"), (options.size(8, 64, max_pixels=100), "16x16"),
             (options.finite, "inf"), (options.integer, "1.5")]:
        with pytest.raises(argparse.ArgumentTypeError):
            parse(text)


@pytest.mark.parametrize("argv,option", [(["eval", "--limit=0"], "--limit"), (["eval", "--spp=nan"], "--spp"),
                                         (["eval", "--relight=-1"], "--relight"),
                                         (["eval", "--probes-per-scene=1e309"], "--probes-per-scene"),
                                         (["eval", "--seed=1.5"], "--seed"),
                                         (["bench", "--repeats=0"], "--repeats"),
                                         (["bench", "--threads=nan"], "--threads")])
def test_eval_and_bench_numeric_options(capsys, argv, option):
    refused(argv, capsys, option)


def test_eval_points_only_with_data(tmp_path, capsys):
    """--points runs the model at free points; with prediction files or --real it was ignored."""
    (tmp_path / "gt").mkdir()
    argv = ["eval", str(tmp_path / "p.exr"), "--gt", str(tmp_path / "gt"), "--points", "4"]
    refused(argv, capsys, "--points")
    refused(["eval", "--real", str(tmp_path), "--points", "4"], capsys, "--points")


@pytest.mark.parametrize("option,value", INSERT_BAD)
def test_insert_numeric_options_refused_in_one_line(room, tmp_path, capsys, option, value):
    place = [] if option in ("--position", "--at") else ["--at", "40,50"]
    argv = ["insert", room[0], "--object", "sphere", *place, f"{option}={value}", "--view", "perspective",
            "-o", tmp_path / "o.exr"]
    refused(argv, capsys, option, [tmp_path / "o.exr", tmp_path / "o.png"])


@pytest.mark.parametrize("path", ["0,50", "0,50:nan,3", "0,50:200,10", "10,50:10,70", "1,2;3,4"])
def test_insert_bad_paths(room, tmp_path, capsys, path):
    refused(["insert", room[0], "--object", "sphere", f"--path={path}", "-o", tmp_path / "o.exr"], capsys,
            "--path", [tmp_path / "o_0000.exr"])


def test_path_points_wrap_across_the_seam():
    W = 128
    pts = views.path_points([(120.0, 50.0), (8.0, 50.0)], 5, W, 64)  # the short way: through column 0
    assert [round(u, 6) for u, _ in pts] == [120.0, 124.0, 0.0, 4.0, 8.0]
    assert all(0 <= u < W for u, _ in pts)
    pts = views.path_points([(0.0, 0.0), (127.5, 63.5)], 3, W, 64)
    assert all(0 <= u < W and 0 <= v < 64 for u, v in pts)
    assert pts[1] == (pytest.approx(127.75), pytest.approx(31.75))
    with pytest.raises(InputError, match="--path"):
        views.path_points([(0.0, 0.0), (128.0, 1.0)], 3, W, 64)


def test_insert_path_through_column_0_and_the_seam(room, tmp_path, capsys, egl):
    for path in ("0,50:10,50", "120,50:5,50", "127.9,0:0.1,63.9"):
        out = tmp_path / "p.png"
        rc, err = run_cli(["insert", room[0], "--object", "sphere", "--scale", "0.2", f"--path={path}",
                           "--frames", "3", "--quality", "draft", "-o", out], capsys)
        assert rc == 0, err
        assert all((tmp_path / f"p_{i:04d}.png").exists() for i in range(3))


def test_library_view_and_exposure_checks(room):
    scene = io.load_scene(room[0])
    for spec, name in ((views.ViewSpec("perspective", None, float("nan")), "--fov"),
                       (views.ViewSpec("perspective", None, 5.0), "--fov"),
                       (views.ViewSpec("perspective", None, 60.0, float("inf")), "--yaw"),
                       (views.ViewSpec("perspective", None, 60.0, 0.0, float("nan")), "--pitch")):
        with pytest.raises(InputError, match=name):
            spec.build(scene, None)
    for ev in (float("nan"), float("inf")):
        with pytest.raises(InputError, match="--exposure"):
            views.tonemap(np.ones((2, 2, 3), np.float32), ev)


def test_render_size_limits():
    views.check_render_size((2048, 2048))
    views.check_render_size((4096, 2048), pano_size=(2048, 4096))  # a big panorama's own size
    for size in ((4096, 2048), (2049, 2048), (8193, 8), (16384, 8192)):
        with pytest.raises(InputError, match="--size: a .* render is too large"):
            views.check_render_size(size)
    with pytest.raises(InputError, match="at most 2048 pixels per side"):
        views.check_render_size((4096, 8), max_side=2048)  # GL's renderbuffer limit


def test_animation_frames_are_streamed(tmp_path):
    """``write_animation`` takes a generator and keeps no frame but the previous one; the
    incremental flicker statistic equals the batch one."""
    rng = np.random.default_rng(0)
    kept: list[weakref.ref] = []
    alive_at: list[int] = []

    def frames(n=6):
        for k in range(n):
            alpha = np.zeros((16, 32), np.float32)
            alpha[4:8, 2 * k:2 * k + 4] = 1
            f = {"composite": rng.random((16, 32, 3), dtype=np.float32), "alpha": alpha,
                 "object": rng.random((16, 32, 3), dtype=np.float32) * alpha[..., None],
                 "shadow": np.zeros_like(alpha), "shadow_delta": np.zeros_like(alpha)}
            kept.append(weakref.ref(f["composite"]))
            alive_at.append(sum(r() is not None for r in kept))
            yield f
    stats = views.write_animation(frames(), str(tmp_path / "a.png"), None)
    assert max(alive_at) <= 3  # the new frame, the previous one (flicker) and the one being written
    assert len(list(tmp_path.glob("a_*.png"))) == 6 and (tmp_path / "a.gif").exists()
    rng = np.random.default_rng(0)
    kept.clear()
    assert stats == pytest.approx(views.flicker(list(frames())))
    assert json.loads((tmp_path / "a_flicker.json").read_text())["frames"] == 6


@pytest.mark.parametrize("value", ["4096x8192", "0x0", "33x66", "544x1088", "64x64", "nanxnan", "-32x-64"])
def test_predict_net_size_bounded(tmp_path, capsys, value):
    pano = tmp_path / "p.hdr"
    io.save_panorama(torch.rand(3, 32, 64), pano)
    refused(["predict", pano, f"--net-size={value}", "-o", tmp_path / "o.exr"], capsys, "--net-size",
            [tmp_path / "o.exr"])


def test_predict_net_size_bounded_in_the_library(tiny_weights):
    with pytest.raises(InputError, match="net_size: network size 1024x2048 is not possible"):
        phyir.predict(torch.rand(3, 32, 64), weights=tiny_weights[1], net_size=(1024, 2048))


SYNTH_BAD = [("--size", v) for v in ("65536x131072", "0x0", "2048x4096", "64x64", "axb")] + \
    [("--probe-size", v) for v in ("4096x8192", "0x0", "16x16", "2x4")] + \
    [("--probe-grid", "256x512")] + \
    [("--spp", v) for v in ("0", "nan", "1e309", "1.5", "100000")] + \
    [("--count", v) for v in ("0", "-1", "inf", "20000000")] + [("--seed", v) for v in ("-1", "nan")]


@pytest.mark.parametrize("option,value", SYNTH_BAD)
def test_synth_options_bounded(tmp_path, capsys, option, value):
    argv = ["synth", "--out", tmp_path / "d", "--count", "1", "--size", "16x32", "--probe-grid", "4x8",
            "--probe-size", "4x8", "--spp", "1", f"{option}={value}", "--quiet"]
    if option == "--probe-grid":
        argv[argv.index("--size") + 1] = "256x512"
        argv[argv.index("--probe-size") + 1] = "64x128"
    refused(argv, capsys, option, [tmp_path / "d"])


# ---------------------------------------------------------------------------------------------
# class 6: weights metadata and tensors


def weights_file(folder: Path, name: str, model, arch: dict | None = None, state: dict | None = None) -> Path:
    from safetensors.torch import save

    state = state if state is not None else {k: v.contiguous() for k, v in model.state_dict().items()}
    arch = model.config.to_dict() if arch is None else arch
    p = folder / f"{name}.safetensors"
    p.write_bytes(save(state, metadata={"format": "phyir-weights-1", "phyir.config": json.dumps(arch)}))
    return p


ARCH_BAD = [("probe_block", 0), ("probe_block", -16), ("probe_block", 1.5), ("probe_block", "16"),
            ("probe_block", True), ("norm", "layer"), ("norm", None), ("enc_width", 64), ("enc_width", 0),
            ("enc_width", float("nan")), ("dec_width", "0.5"), ("light_width", 1e9),
            ("light_head_kernel", 2), ("light_head_kernel", 0), ("light_scale", 0), ("gs_width", 10**9),
            ("gs_radius", -1), ("probe_size", [0, 0]), ("probe_size", [16]), ("probe_size", "16x32"),
            ("probe_size", [4096, 8192]), ("gs_targets", []), ("gs_targets", ["depth"]),
            ("gs_targets", ["albedo", "albedo"]), ("size", 5), ("size", "")]


@pytest.mark.parametrize("key,value", ARCH_BAD)
def test_weights_metadata_out_of_bounds(tmp_path, tiny_weights, key, value):
    model, _ = tiny_weights
    p = weights_file(tmp_path, "bad", model, {**model.config.to_dict(), key: value})
    with pytest.raises(InputError, match=f"architecture metadata {key} = ") as e:
        load_model(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)


def test_weights_metadata_not_an_object(tmp_path, tiny_weights):
    p = weights_file(tmp_path, "list", tiny_weights[0], [1, 2])
    with pytest.raises(InputError, match="corrupt architecture metadata"):
        load_model(p)


def test_huge_architecture_on_small_tensors_is_refused_without_building_it(tmp_path, tiny_weights):
    """enc_width 4 (in bounds: 16x the lite widths) on lite tensors: the shapes are compared with a
    model on the meta device, so the child's memory stays that of importing torch."""
    model, _ = tiny_weights
    arch = {**model.config.to_dict(), "enc_width": 4.0, "dec_width": 4.0, "light_width": 4.0}
    p = weights_file(tmp_path, "wide", model, arch)
    code = ("import sys; from phyir.learn.weights import load_model\n"
            "try:\n    load_model(sys.argv[1])\nexcept ValueError as e:\n    print(e)\n"
            f"print(int({PEAK_MB}))")
    out = subprocess.run([sys.executable, "-c", code, str(p)], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1"})
    msg, peak = out.stdout.strip().splitlines()
    assert "of wrong shape" in msg and str(p) in msg, out.stderr
    assert int(peak) < 800, peak  # building it would take 2.6 GB


@pytest.mark.parametrize("fault", ["nan", "inf", "-inf", "int8", "float64", "bool"])
def test_weights_tensor_values_and_dtypes(tmp_path, tiny_weights, capsys, fault):
    model, _ = tiny_weights
    state = {k: v.contiguous().clone() for k, v in model.state_dict().items()}
    k = "gmnet.encoder.conv1.weight" if "gmnet.encoder.conv1.weight" in state else next(iter(state))
    if fault in ("nan", "inf", "-inf"):
        state[k].view(-1)[3] = float(fault)
    else:
        state[k] = state[k].to(getattr(torch, fault))
    p = weights_file(tmp_path, fault, model, state=state)
    with pytest.raises(InputError, match=f"tensor {k}") as e:
        load_model(p)
    assert str(p) in str(e.value)
    pano = tmp_path / "p.hdr"
    io.save_panorama(torch.rand(3, 32, 64), pano)
    refused(["predict", pano, "--weights", p, "-o", tmp_path / "o.exr"], capsys, str(p), [tmp_path / "o.exr"])


@pytest.mark.parametrize("res", ["0x0", "-64x-128", "4096x8192", "32x64x2", "33x66", 5])
def test_weights_sidecar_resolution_out_of_bounds_warns(tmp_path, tiny_weights, res):
    import shutil

    from phyir.inference import DEFAULT_NET_SIZE, load_cached_model

    p = tmp_path / "w.safetensors"
    shutil.copy(tiny_weights[1], p)
    p.with_suffix(".json").write_text(json.dumps({"data": {"resolution": res}}))
    with pytest.warns(UserWarning, match="unreadable weights sidecar"):
        _, net = load_cached_model(p)
    assert net == DEFAULT_NET_SIZE


# ---------------------------------------------------------------------------------------------
# class 8: train


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("data")
    write_dataset(root, n_train=4, n_val=0, H=32, W=64, grid=(2, 4), probe_size=(8, 16))
    return root


TRAIN_ARGS = ["--stage", "gm", "--epochs", "1", "--batch-size", "2", "--size", "native", "--probe-grid",
              "native", "--no-val", "--no-progress", "--no-cache", "--model", "lite"]

TRAIN_BAD = [("--lr", v) for v in (*NON_FINITE, "0", "-1e-4", "100")] + \
    [("--batch-size", v) for v in ("0", "-2", "1.5", "nan", "1e309")] + \
    [("--epochs", v) for v in ("0", "-1", "inf")] + [("--workers", v) for v in ("-1", "1000", "nan")] + \
    [("--max-minutes", v) for v in ("0", "nan", "-inf")] + [("--max-steps", "0"), ("--ckpt-every", "0"),
                                                           ("--limit-train", "0"), ("--seed", "-1")] + \
    [("--size", v) for v in ("0x0", "48x96", "2048x4096", "nanxnan")] + [("--probe-grid", "0x0")]


@pytest.mark.parametrize("option,value", TRAIN_BAD)
def test_train_numeric_options(tmp_path, capsys, dataset, option, value):
    refused(["train", "--data", dataset, "--out", tmp_path / "run", *TRAIN_ARGS, f"{option}={value}"],
            capsys, option, [tmp_path / "run" / "gm" / "checkpoint.pt"])


@pytest.mark.parametrize("loss,name", [("sc_sigma=nan", "--loss sc_sigma"), ("sc_sigma=0", "--loss sc_sigma"),
                                       ("render_spp=0", "--loss render_spp"),
                                       ("si_lambda=2", "--loss si_lambda"),
                                       ("render_size=[0,0]", "--loss render_size"),
                                       ("depth_mode=l1", "--loss depth_mode")])
def test_train_loss_options(tmp_path, capsys, dataset, loss, name):
    refused(["train", "--data", dataset, "--out", tmp_path / "run", *TRAIN_ARGS, "--loss", loss], capsys,
            name, [tmp_path / "run" / "gm" / "checkpoint.pt"])


def test_train_loss_weights_from_a_config_file(tmp_path, capsys, dataset):
    cfg = tmp_path / "c.json"
    cfg.write_text('{"weights": {"depth": NaN}}')
    refused(["train", "--config", cfg, "--data", dataset, "--out", tmp_path / "run", *TRAIN_ARGS], capsys,
            "weights.depth", [tmp_path / "run" / "gm" / "checkpoint.pt"])


@pytest.mark.parametrize("doc", ['{"lr": NaN}', '{"batch_size": 0}', '{"epochs": 1.5}', '{"size": [0, 0]}',
                                 '{"workers": true}', '{"schedule": "linear"}'])
def test_train_config_file_numbers(tmp_path, capsys, dataset, doc):
    cfg = tmp_path / "c.json"
    cfg.write_text(doc)
    name = "--" + next(iter(json.loads(doc))).replace("_", "-")
    refused(["train", "--config", cfg, "--data", dataset, "--out", tmp_path / "run", "--no-progress"],
            capsys, name, [tmp_path / "run" / "gm" / "checkpoint.pt"])


def test_train_corrupt_scene_in_a_worker_is_one_line(tmp_path, capsys, dataset):
    import shutil

    data = tmp_path / "data"
    shutil.copytree(dataset, data)
    bad = data / "scene_000002.exr"
    data_bytes = bad.read_bytes()
    bad.write_bytes(data_bytes[:len(data_bytes) // 2])  # truncated pixels: met when a worker reads it
    for workers in ("0", "2"):
        err = refused(["train", "--data", data, "--out", tmp_path / f"run{workers}", *TRAIN_ARGS,
                       "--workers", workers], capsys, str(bad), progress=True)
        assert "DataLoader" not in err and "worker" not in err.lower(), err


def test_train_resume_with_other_options_is_refused(tmp_path, capsys, dataset):
    out = tmp_path / "run"
    base = ["train", "--data", dataset, "--out", out, *TRAIN_ARGS, "--epochs", "2"]
    assert run_cli([*base, "--max-steps", "1"], capsys)[0] == 0
    err = refused([*base, "--batch-size", "1", "--lr", "1e-3"], capsys, "resuming with options other than")
    assert "--batch-size 1 (checkpoint: 2)" in err and "--lr 0.001 (checkpoint: default)" in err
    assert str(out / "gm" / "checkpoint.pt") in err
    rc, err = run_cli([*base, "--max-steps", "2", "--workers", "0"], capsys)  # run-time options may change
    assert rc == 0 and "resuming at epoch" in err


# ---------------------------------------------------------------------------------------------
# the second corpus (tests/support/robustness): what it found in classes 5-8


def test_uniform_panoramas_warn_that_the_layers_are_guesses(tmp_path, capsys):
    """Black, clipped white, one bright pixel on black: exit 0 with no word before."""
    from phyir.commands.predict import uniform_warning

    spike = torch.zeros(3, 32, 64)
    spike[:, 5, 5] = 1e38
    for image in (torch.zeros(3, 32, 64), torch.ones(3, 32, 64), spike):
        assert "the panorama is uniform" in uniform_warning(image)
    assert uniform_warning(box_room(32, 64).image) is None
    io.save_panorama(torch.ones(3, 32, 64), tmp_path / "white.png")
    rc, err = run_cli(["predict", tmp_path / "white.png", "-o", tmp_path / "o.exr", "-q"], capsys)
    assert rc == 0 and err.startswith("phyir predict: warning: ") and "uniform" in err, err


def test_predict_outputs_naming_no_layer_is_refused(room, tmp_path, capsys):
    refused(["predict", room[0], "-o", tmp_path / "o.exr", "--outputs", " , "], capsys, "--outputs",
            [tmp_path / "o.exr"])


def test_export_places_objects_by_insert_rules(room, tmp_path, capsys):
    """export wrote a glTF with a sphere 1e300 m away, or around the camera."""
    out = tmp_path / "o.glb"
    base = ["export", room[0], "--gltf", out, "--object", "sphere"]
    refused(base + ["--position", "1e300,0,0"], capsys, "--position", [out])
    line = refused(base + ["--position", "0,0,0", "--scale", "5"], capsys, "--position", [out])
    assert "the camera is inside the object" in line


def test_depth_that_is_zero_everywhere_is_refused(room, tmp_path, capsys):
    """A depth layer of 0 (or negative / NaN, repaired to 0) exported a room collapsed to a point."""
    image = io.load_scene(room[0]).image.numpy()
    for value in (0.0, -2.0, float("nan")):
        p = tmp_path / "flat.exr"
        depth = np.full(image.shape[1:], value, np.float32)
        layers = {"R": image[0], "G": image[1], "B": image[2], "depth.Z": depth}
        io.exr.write_parts(p, [("scene", {}, layers)])
        refused(["export", p, "--gltf", tmp_path / "o.glb"], capsys, "the depth layer is 0 everywhere",
                [tmp_path / "o.glb"], progress=True)
        with pytest.raises(InputError, match="flat.exr: the depth layer is 0 everywhere"):
            views.load_insert_scene(str(p))


def test_weights_json_nested_too_deeply(tmp_path, tiny_weights):
    """A RecursionError traceback from the metadata's and the sidecar's JSON."""
    model, path = tiny_weights
    deep = "[" * 100_000 + "]" * 100_000
    bad = weights_file(tmp_path, "deep", model)
    from safetensors.torch import save

    bad.write_bytes(save({k: v.contiguous() for k, v in model.state_dict().items()},
                         metadata={"format": "phyir-weights-1", "phyir.config": deep}))
    with pytest.raises(InputError, match="corrupt architecture metadata \\(nested too deeply\\)"):
        load_model(bad)
    side = tmp_path / "side.safetensors"
    side.write_bytes(Path(path).read_bytes())
    side.with_suffix(".json").write_text(deep)
    with pytest.warns(UserWarning, match="side.json: unreadable weights sidecar"):
        phyir.predict(torch.rand(3, 32, 64), weights=side)
