"""The exported output set: a valid glb (pygltflib, trimesh), its lights and objects, atomic writes,
and the command's one-line errors."""

from __future__ import annotations

import argparse
import os

import numpy as np
import pygltflib
import pytest
import trimesh
from support.scenes import LAMP_CENTRE, LAMP_RADIANCE, LAMP_RADIUS, ROOM_HI, ROOM_LO, box_room

from phyir.commands import export as export_cmd
from phyir.errors import InputError
from phyir.export import bundle
from phyir.export.lights import LUMENS_PER_WATT, scene_lights, spot_rotation
from phyir.export.mitsuba import GlbFile, node_matrix
from phyir.io import load_panorama, save_scene

GRID = (32, 64)


@pytest.fixture(scope="module")
def room():
    return box_room(128, 256)


@pytest.fixture(scope="module")
def exported(room, tmp_path_factory):
    path = str(tmp_path_factory.mktemp("export") / "room.glb")
    return bundle.export_gltf(room, path, grid=GRID)


def check_buffers(doc: pygltflib.GLTF2, blob: bytes) -> None:
    """The glTF validator's structural checks that matter here: views inside the buffer, accessors
    inside their views, indices inside the vertex range, POSITION bounds equal to the data."""
    assert doc.buffers[0].byteLength == len(blob)
    for v in doc.bufferViews:
        assert v.byteOffset % 4 == 0 and v.byteOffset + v.byteLength <= len(blob)
    glb = GlbFile.__new__(GlbFile)
    glb.doc, glb.blob = doc, blob
    glb.dtypes = {pygltflib.FLOAT: np.float32, pygltflib.UNSIGNED_INT: np.uint32}
    for mesh in doc.meshes:
        for prim in mesh.primitives:
            pos = glb.array(prim.attributes.POSITION)
            acc = doc.accessors[prim.attributes.POSITION]
            np.testing.assert_array_equal(acc.min, pos.min(0))
            np.testing.assert_array_equal(acc.max, pos.max(0))
            idx = glb.array(prim.indices)
            assert idx.size % 3 == 0 and idx.max() < len(pos)
            for k in ("NORMAL", "TEXCOORD_0"):
                if getattr(prim.attributes, k) is not None:
                    assert doc.accessors[getattr(prim.attributes, k)].count == len(pos)


def test_the_glb_round_trips_through_pygltflib_and_trimesh(exported):
    doc = pygltflib.GLTF2().load(exported.glb)
    check_buffers(doc, doc.binary_blob())
    assert set(doc.extensionsUsed) == {"KHR_materials_emissive_strength", "KHR_materials_variants",
                                       "KHR_lights_punctual"}
    assert [v["name"] for v in doc.extensions["KHR_materials_variants"]["variants"]] == ["photo", "pbr"]
    assert len(doc.extensions["KHR_lights_punctual"]["lights"]) == exported.lights >= 1
    cam = next(n for n in doc.nodes if n.name == "camera")
    assert cam.camera == 0 and not cam.translation and not cam.rotation  # the origin, looking down -z
    # trimesh reads the same room: vertex count and bounds as written (the box room, within a cell)
    loaded = trimesh.load(exported.glb, process=False)
    mesh = loaded.geometry["room"]
    assert len(mesh.vertices) == exported.vertices == 33 * 65 and len(mesh.faces) == exported.faces
    np.testing.assert_allclose(mesh.bounds, [ROOM_LO, ROOM_HI], atol=0.05)
    assert isinstance(mesh.visual.material, trimesh.visual.material.PBRMaterial)


def test_the_environment_is_the_panorama(room, exported):
    assert os.path.basename(exported.exr) == "room_env.exr"
    np.testing.assert_allclose(load_panorama(exported.exr).numpy(), room.image.numpy(), rtol=1e-6)
    assert GlbFile(exported.glb).environment() == exported.exr


def test_the_lamp_becomes_spot_lights_where_it_is(room):
    lights, base = scene_lights(room)
    # bright_sources gathers the lamp's pixels into the cells of a coarse grid: a few lights
    assert 1 <= len(lights) <= 8
    power = np.array([x.radiant_intensity.max() for x in lights])
    centre = (power[:, None] * [x.position for x in lights]).sum(0) / power.sum()
    assert np.linalg.norm(centre - LAMP_CENTRE) < 0.05
    assert all(np.linalg.norm(x.position - LAMP_CENTRE) < LAMP_RADIUS for x in lights)
    assert all(x.direction @ [0, -1, 0] > 0.99 for x in lights)  # they face the floor
    # their radiant intensity: the lamp's radiance above the base image's level, times its area
    level = float(base.mean(0).max())
    expected = (LAMP_RADIANCE - level) * np.pi * LAMP_RADIUS**2
    assert power.sum() == pytest.approx(expected, rel=0.1)
    assert lights[0].intensity == pytest.approx(LUMENS_PER_WATT * power[0])


@pytest.mark.parametrize("d", [(0, 0, -1), (0, 0, 1), (0, -1, 0), (0.6, 0.0, 0.8), (-0.3, 0.9, 0.3)])
def test_spot_rotation_turns_minus_z_onto_the_direction(d):
    node = pygltflib.Node(rotation=list(spot_rotation(np.asarray(d, float))))
    m = node_matrix(node)
    np.testing.assert_allclose(-m[:3, 2], np.asarray(d) / np.linalg.norm(d), atol=1e-9)


def test_both_files_or_neither(tmp_path, room, monkeypatch):
    glb, env = str(tmp_path / "a.glb"), str(tmp_path / "a_env.exr")

    def fail(*args):
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        bundle.write_together([glb, env], [lambda tmp: open(tmp, "wb").write(b"x"), fail])
    assert os.listdir(tmp_path) == []
    # the second rename fails: the first file, already renamed, is removed
    replace = os.replace

    def replace_but_not_the_glb(src, dst):
        if os.fspath(dst) == glb:
            raise OSError(28, "No space left on device")
        replace(src, dst)

    monkeypatch.setattr(os, "replace", replace_but_not_the_glb)
    with pytest.raises(OSError):
        bundle.write_together([glb, env], [lambda tmp: open(tmp, "wb").write(b"x")] * 2)
    assert os.listdir(tmp_path) == []
    monkeypatch.setattr(os, "replace", replace)
    # a failing EXR writer leaves an older glb as it was, and no temporaries
    with open(glb, "wb") as f:
        f.write(b"old")
    monkeypatch.setattr(bundle.exr, "write_parts", fail)
    with pytest.raises(RuntimeError):
        bundle.export_gltf(room, glb, grid=GRID)
    assert os.listdir(tmp_path) == ["a.glb"] and open(glb, "rb").read() == b"old"


def run_export(argv: list[str]) -> int:
    parser = argparse.ArgumentParser()
    export_cmd.add_arguments(parser)
    return export_cmd.run(parser.parse_args(argv))


def test_the_command_exports_inserted_objects(tmp_path, room):
    scene = str(tmp_path / "room.exr")
    save_scene(room, scene)
    out = str(tmp_path / "out.glb")
    assert run_export([scene, "--gltf", out, "--grid", "16x32", "--object", "sphere", "--position",
                       "0.5,-1.0,-2.5", "--object", "cube", "--at", "128,120", "--scale", "0.2",
                       "--material", "matte-silver", "--material", "0.9,0.1,0.1,0.3,0"]) == 0
    doc = GlbFile(out).doc
    objs = [n for n in doc.nodes if n.name.startswith("object_")]
    assert [n.name for n in objs] == ["object_0_sphere", "object_1_cube"]
    m = node_matrix(objs[0])
    np.testing.assert_allclose(m[:3, 3], [0.5, -1.0, -2.5], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(m[:3, :3], axis=0), 0.2, rtol=1e-6)
    pbr = [doc.materials[doc.meshes[n.mesh].primitives[0].material].pbrMetallicRoughness for n in objs]
    assert (pbr[0].metallicFactor, pbr[0].roughnessFactor) == (1.0, 0.5)
    assert pbr[1].baseColorFactor[:3] == pytest.approx([0.9, 0.1, 0.1])
    assert os.path.exists(str(tmp_path / "out_env.exr"))


def test_one_scale_for_a_mesh_and_a_primitive_is_warned_about(tmp_path, room):
    import warnings

    import trimesh

    scene = str(tmp_path / "room.exr")
    save_scene(room, scene)
    mesh = str(tmp_path / "box.glb")
    trimesh.creation.box((0.3, 0.3, 0.3)).export(mesh)
    both = ["--object", "sphere", "--position", "0.5,-1.0,-2.5",
            "--object", mesh, "--position=-0.5,-1.0,-2.5"]
    with pytest.warns(UserWarning, match="give one --scale per --object"):
        assert run_export([scene, "--gltf", str(tmp_path / "a.glb"), "--grid", "16x32", *both,
                           "--scale", "0.2"]) == 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # one scale per object, or primitives only: nothing to say
        assert run_export([scene, "--gltf", str(tmp_path / "b.glb"), "--grid", "16x32", *both,
                           "--scale", "0.2", "--scale", "1"]) == 0
        assert run_export([scene, "--gltf", str(tmp_path / "c.glb"), "--grid", "16x32", "--object", "sphere",
                           "--position", "0.5,-1.0,-2.5", "--object", "cube", "--position=-0.5,-1.0,-2.5",
                           "--scale", "0.2"]) == 0


@pytest.mark.parametrize("extra, flag", [
    (["--grid", "64"], "--grid"), (["--grid", "1x8"], "--grid"), (["--grid", "4096x8192"], "--grid"),
    (["--object", "sphere"], "--object"),
    (["--object", "sphere", "--at", "1,2", "--scale", "1", "--scale", "2", "--scale", "3"], "--scale"),
])
def test_bad_options_are_one_line_errors(tmp_path, room, extra, flag):
    scene = str(tmp_path / "room.exr")
    save_scene(room, scene)
    with pytest.raises(InputError) as e:
        run_export([scene, "--gltf", str(tmp_path / "o.glb"), *extra])
    assert str(e.value).startswith(flag) and "\n" not in str(e.value)
    assert not os.path.exists(tmp_path / "o.glb")


@pytest.mark.parametrize("extra", [["--lights", "-1"], ["--lights", "1e9"], ["--fov", "0"], ["--fov", "nan"],
                                   ["--object", "sphere", "--at", "1,2", "--scale", "inf"]])
def test_bad_numbers_are_refused_in_one_line_by_the_command(tmp_path, room, extra, capsys):
    from phyir.cli import main

    scene = str(tmp_path / "room.exr")
    save_scene(room, scene)
    assert main(["export", scene, "--gltf", str(tmp_path / "o.glb"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"argument {extra[-2]}" in err[0]
    assert not os.path.exists(tmp_path / "o.glb")


def test_missing_scene_and_unwritable_output_are_one_line_errors(tmp_path, room):
    with pytest.raises(InputError, match="no such file"):
        run_export([str(tmp_path / "missing.exr"), "--gltf", str(tmp_path / "o.glb")])
    scene = str(tmp_path / "room.exr")
    save_scene(room, scene)
    with pytest.raises(InputError, match="--gltf: .*does not exist"):
        run_export([scene, "--gltf", str(tmp_path / "nope" / "o.glb")])
    with pytest.raises(InputError, match="--gltf: .*expected a .glb"):
        run_export([scene, "--gltf", str(tmp_path / "o.gltf")])
    with pytest.raises(InputError, match="--exr: .*is the input scene"):
        run_export([scene, "--gltf", str(tmp_path / "o.glb"), "--exr", scene])
    if os.geteuid() != 0:  # root writes anywhere
        ro = tmp_path / "ro"
        ro.mkdir(mode=0o500)
        with pytest.raises(InputError, match="not writable"):
            run_export([scene, "--gltf", str(ro / "o.glb")])
