"""``phyir export --blend``: a ready Blender scene built by Blender (docs/export.md, Blender).

Without Blender: the one-line errors (no program, a program that fails or writes half a file) and
that nothing is left behind.  With the ``blender`` on PATH (skipped where there is none): the .blend
reopened in Blender holds the room as shadow catcher, the camera, the lights off in renders, the
object and the world with the panorama turned right; and Cycles' render of a diffuse sphere in it
is as bright as ``phyir insert``'s within the tolerance docs/export.md states."""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from phyir import pano
from phyir.cli import main
from phyir.io import exr, load_scene

DEMO = "phyir/assets/demo.exr"
SPHERE = ["--object", "sphere", "--position", "0.0,-0.5,-2.0", "--scale", "0.25", "--material", "diffuse"]
CENTRE = np.array([0.0, -0.5, -2.0])  # the project's frame (+y up, -z forward); Blender: (x, -z, y)
SIZE, FOV, SAMPLES = 64, 20.0, 64  # the render: 64x64 px, 20 degrees, 64 samples a pixel (seconds)
RATIO = (0.90, 1.15)  # docs/export.md: Cycles' mean over the sphere / phyir insert's
BLENDER = shutil.which("blender")
needs_blender = pytest.mark.skipif(BLENDER is None, reason="Blender is not on PATH (Debian: apt-get install "
                                                           "blender); the .blend tests run it")


def one_line_error(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


def fake_blender(folder, body: str) -> str:
    """An executable that takes Blender's arguments and does ``body`` (Python; ``out``: the --out path)."""
    path = os.path.join(folder, "fake-blender")
    with open(path, "w") as f:
        f.write(f"#!{sys.executable}\nimport sys\nargs = sys.argv[sys.argv.index('--') + 1:]\n"
                f"out = args[args.index('--out') + 1]\n{body}\n")
    os.chmod(path, 0o755)
    return path


def test_no_blender_is_a_one_line_error_naming_the_option_and_writes_nothing(tmp_path, capsys, monkeypatch):
    out = tmp_path / "room.blend"
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(out), "--blender", "/nonexistent"])
    assert "--blender" in err and "/nonexistent: no such program" in err
    monkeypatch.setenv("PATH", str(tmp_path))  # no blender on PATH
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(out), "--gltf", str(tmp_path / "room.glb")])
    assert "--blend: needs Blender" in err and "--blender PATH" in err
    assert os.listdir(tmp_path) == []


def test_a_failing_blender_leaves_no_file_and_its_reason_is_the_error(tmp_path, capsys):
    out, glb = tmp_path / "room.blend", tmp_path / "room.glb"
    out.write_bytes(b"the user's old file")
    blender = fake_blender(str(tmp_path), "open(out, 'wb').write(b'half a file')\n"
                                          "print('phyir-blend: error: something broke', file=sys.stderr)\n"
                                          "sys.exit(1)")
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(out), "--gltf", str(glb), "--grid", "16x32",
                                  "--blender", blender])
    assert "--blender" in err and "failed (exit code 1): something broke" in err
    assert sorted(os.listdir(tmp_path)) == ["fake-blender", "room.blend"]  # no glb, EXR or temporaries
    assert out.read_bytes() == b"the user's old file"
    silent = fake_blender(str(tmp_path), "open(out, 'wb').write(b'not a blend')")  # exit 0, no summary
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(tmp_path / "b.blend"), "--grid", "16x32",
                                  "--blender", silent])
    assert "built no scene" in err
    assert sorted(os.listdir(tmp_path)) == ["fake-blender", "room.blend"]


def test_options_that_need_another(tmp_path, capsys):
    assert "nothing to write" in one_line_error(capsys, ["export", DEMO])
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(tmp_path / "r.blend"), "--exr",
                                  str(tmp_path / "e.exr")])
    assert err.endswith("--exr: names the panorama of --gltf: give --gltf too")
    err = one_line_error(capsys, ["export", DEMO, "--gltf", str(tmp_path / "r.glb"), "--blender", "blender"])
    assert err.endswith("--blender: runs Blender for --blend: give --blend too")
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(tmp_path / "r.blnd")])
    assert "expected a .blend file name" in err


# --------------------------------------------------------------------------------------------------
# with Blender


def run_blender(*args: str) -> str:
    proc = subprocess.run([BLENDER, "--background", "--factory-startup", *args], capture_output=True,
                          text=True, errors="replace", stdin=subprocess.DEVNULL, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    return proc.stdout


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """``phyir export demo.exr --blend room.blend --gltf room.glb`` with the diffuse sphere."""
    if BLENDER is None:
        pytest.skip("Blender is not on PATH (Debian: apt-get install blender); the .blend tests run it")
    folder = tmp_path_factory.mktemp("blend")
    assert main(["export", DEMO, "--blend", str(folder / "room.blend"), "--gltf", str(folder / "room.glb"),
                 *SPHERE]) == 0
    return folder


QUERY = """
import bpy, json
from mathutils import Vector
s = bpy.data.scenes["room"]
w = s.world.node_tree
room = bpy.data.objects["room"]
mat = room.active_material.node_tree
comp = s.node_tree if hasattr(s, "node_tree") else s.compositing_node_group  # Blender 3-4, 5
print("QUERY " + json.dumps({
    "collections": {c.name: sorted(o.name for o in c.objects) for c in s.collection.children},
    "render": {c.name: not c.hide_render for c in s.collection.children},
    "lights": sorted({o.data.type for o in s.objects if o.type == "LIGHT"}),
    "camera": [s.camera.name, *s.camera.matrix_world.translation,
               *(s.camera.matrix_world.to_3x3() @ Vector((0, 0, -1)))],
    "sphere": list(bpy.data.objects["object_0_sphere"].matrix_world.translation),
    "catcher": room.is_shadow_catcher,
    "world": [w.nodes["Panorama"].image.name, w.nodes["Panorama"].image.filepath,
              w.nodes["Panorama"].image.packed_file is not None,
              *w.nodes["Rotation"].inputs["Rotation"].default_value],
    "world_links": sorted([l.from_node.bl_idname, l.from_socket.name, l.to_node.bl_idname]
                          for l in w.links),
    "room_emits": mat.nodes["EXR"].image == w.nodes["Panorama"].image,
    "emission_source": mat.nodes["Emission Source"].inputs["Fac"].default_value,
    "layers": [l.name for l in s.view_layers], "transparent": s.render.film_transparent,
    "compositor": sorted([l.from_node.name, l.from_socket.name.replace("Environment", "Env"), l.to_node.name]
                         for l in comp.links),
}))
"""


@needs_blender
def test_the_blend_and_the_gltf_set_are_written_together(built):
    assert sorted(os.listdir(built)) == ["room.blend", "room.glb", "room_env.exr"]  # no temporaries
    with open(built / "room.blend", "rb") as f:
        assert f.read(4) in (b"BLEN", b"\x28\xb5\x2f\xfd")  # a .blend, plain or zstd-compressed
    from phyir.export.mitsuba import GlbFile

    assert GlbFile(str(built / "room.glb")).environment() == str(built / "room_env.exr")


@needs_blender
def test_reopened_in_blender_the_scene_is_ready(built):
    out = run_blender(str(built / "room.blend"), "--python-exit-code", "1", "--python-expr", QUERY)
    q = json.loads(next(ln for ln in out.splitlines() if ln.startswith("QUERY "))[6:])
    assert q["collections"]["room"] == ["room"] and q["collections"]["objects"] == ["object_0_sphere"]
    assert len(q["collections"]["lights"]) == 17 and q["lights"] == ["SPOT"]  # 16 lights + their group
    assert q["render"] == {"room": True, "objects": True, "lights": False}  # EXR emission: lights off
    assert q["catcher"] and q["room_emits"] and q["emission_source"] == 0
    name, x, y, z, *look = q["camera"]
    assert name == "camera" and np.allclose([x, y, z], 0, atol=1e-6)
    assert np.allclose(look, [0, 1, 0], atol=1e-5)  # the panorama's centre: glTF -z = Blender +y
    assert np.allclose(q["sphere"], [CENTRE[0], -CENTRE[2], CENTRE[1]], atol=1e-5)  # (x, -z, y)
    image, path, packed, *rotation = q["world"]  # inside the file, and where the EXR is beside it
    assert (image, path, packed) == ("room_env.exr", "//room_env.exr", True)
    assert np.allclose(rotation, [0, 0, -math.pi / 2])  # Cycles' equirect centre (+x) onto +y
    assert q["world_links"] == [["ShaderNodeBackground", "Background", "ShaderNodeOutputWorld"],
                                ["ShaderNodeMapping", "Vector", "ShaderNodeTexEnvironment"],
                                ["ShaderNodeTexCoord", "Generated", "ShaderNodeMapping"],
                                ["ShaderNodeTexEnvironment", "Color", "ShaderNodeBackground"]]
    assert q["layers"] == ["objects", "photograph"] and q["transparent"]
    assert ["photograph", "Env", "Shadows"] in q["compositor"]
    assert ["objects", "Shadow Catcher", "Shadows"] in q["compositor"]
    assert ["objects", "Image", "Objects Over"] in q["compositor"]


@needs_blender
def test_blenders_own_failure_is_the_one_line_error(tmp_path, capsys):
    """The real Blender, handed a glb that is not one: the script's reason, and no file."""
    (tmp_path / "bad.glb").write_bytes(b"not a glb")
    bad, real = str(tmp_path / "bad.glb"), BLENDER
    wrapper = fake_blender(str(tmp_path), f"import os\nargs[args.index('--glb') + 1] = {bad!r}\n"
                                          f"head = sys.argv[1:sys.argv.index('--') + 1]\n"
                                          f"os.execv({real!r}, [{real!r}, *head, *args])")
    err = one_line_error(capsys, ["export", DEMO, "--blend", str(tmp_path / "room.blend"), "--grid", "16x32",
                                  "--blender", wrapper])
    assert "failed (exit code 1)" in err and "bad.glb: not a binary glTF (.glb)" in err
    assert sorted(os.listdir(tmp_path)) == ["bad.glb", "fake-blender"]


RENDER = """
import bpy, math
from mathutils import Vector
s = bpy.context.scene
s.camera.rotation_mode = "QUATERNION"
s.camera.rotation_quaternion = Vector(({x}, {y}, {z})).normalized().to_track_quat("-Z", "Y")
s.camera.data.sensor_fit = "VERTICAL"
s.camera.data.angle_y = math.radians({fov})
s.render.resolution_x = s.render.resolution_y = {size}
s.cycles.samples = {samples}
s.cycles.seed = 0
if hasattr(s.render.image_settings, "media_type"):  # Blender 5
    s.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
s.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
s.render.image_settings.color_depth = "32"
s.render.filepath = {out!r}
bpy.ops.render.render(write_still=True)
"""


def passes(path: str, prefix: str, names: str = "RGB") -> np.ndarray:
    chans = exr.read_pixels(path, exr.read_headers(path))[0]
    return np.stack([chans[f"{prefix}.{c}"] for c in names], -1)


def sphere_pixels(alpha: np.ndarray) -> np.ndarray:
    """The object's interior: alpha 1, eroded by one pixel (as the Mitsuba comparison)."""
    inside = alpha >= 0.999
    for axis in (0, 1):
        inside &= np.roll(inside, 1, axis) & np.roll(inside, -1, axis)
    return inside


@needs_blender
@pytest.mark.gl
@pytest.mark.slow
def test_cycles_renders_the_sphere_as_bright_as_phyir_insert(built, egl, tmp_path):
    from viewer.commands import insert

    parser = argparse.ArgumentParser()
    insert.add_arguments(parser)
    ins = str(tmp_path / "insert.exr")
    insert.run(parser.parse_args([DEMO, *SPHERE, "--view", "perspective", "--size", f"{SIZE}x{SIZE}",
                                  "--fov", str(FOV), "-o", ins]))
    a = passes(ins, "object", "A")[..., 0]
    ref, inside = passes(ins, "object") / np.maximum(a, 1e-6)[..., None], sphere_pixels(a)

    out = str(tmp_path / "cycles.exr")
    x, y, z = CENTRE[0], -CENTRE[2], CENTRE[1]  # the camera aims at the sphere, as phyir insert's view
    run_blender(str(built / "room.blend"), "--python-exit-code", "1", "--python-expr",
                RENDER.format(x=x, y=y, z=z, fov=FOV, size=SIZE, samples=SAMPLES, out=out))
    comp = passes(out, "Composite.Combined")  # what the user gets: the sphere over the photograph
    ratio = float(comp[inside].mean() / ref[inside].mean())
    l1 = float(np.abs(comp[inside] - ref[inside]).sum() / np.abs(ref[inside]).sum())
    print(f"Cycles / phyir insert over {inside.sum()} sphere pixels: mean {ratio:.3f}, relative L1 {l1:.3f}")
    assert RATIO[0] <= ratio <= RATIO[1]

    # around the sphere the composite is the panorama seen by the camera: the world is turned right
    yaw, pitch = math.atan2(CENTRE[0], -CENTRE[2]), math.atan2(CENTRE[1], math.hypot(CENTRE[0], CENTRE[2]))
    crop = pano.perspective_crop(load_scene(DEMO).image, SIZE, SIZE, FOV, yaw, pitch).permute(1, 2, 0).numpy()
    around = a == 0
    assert np.abs(comp - crop)[around].sum() / np.abs(crop[around]).sum() < 0.06
    chans = exr.read_pixels(out, exr.read_headers(out))[0]
    if "objects.Combined.A" in chans:  # Blender 3-4 save the view layers' passes too: how it composites
        objects = passes(out, "objects.Combined", "RGBA")
        photo, catcher = passes(out, "photograph.Env"), passes(out, "objects.Shadow Catcher")
        assert (objects[..., 3][inside] > 0.99).all()
        away = objects[..., 3] == 0
        assert np.allclose(comp[away], (photo * catcher)[away], rtol=1e-3, atol=1e-4)
        assert np.allclose(comp[inside], objects[..., :3][inside], rtol=1e-3, atol=1e-4)
