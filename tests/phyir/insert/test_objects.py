"""Objects to insert: primitives, mesh files and their documented outcomes, materials."""

from __future__ import annotations

import numpy as np
import pytest

from phyir.errors import InputError
from phyir.insert import objects
from phyir.insert.objects import PRESETS, SceneObject, load_mesh, parse_material, primitive

trimesh = pytest.importorskip("trimesh")


def test_primitives_are_unit_size_with_unit_normals():
    s = primitive("sphere")
    np.testing.assert_allclose(np.linalg.norm(s.vertices, axis=1), 1.0, atol=1e-6)
    c = primitive("cube")
    np.testing.assert_allclose(c.bounds[0], -1)
    np.testing.assert_allclose(c.bounds[1], 1)
    # flat faces keep flat normals: every cube normal is an axis
    assert np.allclose(np.abs(c.normals).max(1), 1.0)
    y = primitive("cylinder")
    np.testing.assert_allclose(y.bounds[0], -1, atol=1e-6)
    np.testing.assert_allclose(y.bounds[1], 1, atol=1e-6)
    caps = np.abs(y.vertices[:, 1]) > 1 - 1e-6
    side = np.abs(y.normals[:, 1]) < 1e-6
    assert side.sum() > 0 and (np.abs(y.normals[~side, 1]) > 0.999).all() and caps.sum() > 0
    for m in (s, c, y):
        np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-5)
        # normals point outward (closed, origin-centred primitives)
        centres = m.vertices[m.faces].mean(1)
        fn = m.normals[m.faces].mean(1)
        assert ((centres * fn).sum(1) > 0).mean() > 0.99


@pytest.mark.parametrize("ext", ["obj", "ply", "stl", "off", "glb"])
def test_mesh_files_round_trip_with_normals_computed(tmp_path, ext):
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    path = tmp_path / f"ball.{ext}"
    mesh.export(path)
    m = load_mesh(path)
    assert len(m.faces) == len(mesh.faces)
    np.testing.assert_allclose(np.linalg.norm(m.vertices, axis=1), 0.3, atol=1e-5)
    # computed vertex normals of a sphere point along the position
    radial = m.vertices / np.linalg.norm(m.vertices, axis=1, keepdims=True)
    assert ((m.normals * radial).sum(1) > 0.97).all()


def _write_obj(path, vertices, faces):
    with open(path, "w") as f:
        for v in vertices:
            f.write("v " + " ".join(str(x) for x in v) + "\n")
        for t in faces:
            f.write("f " + " ".join(str(i + 1) for i in t) + "\n")
    return path


def test_bad_meshes_give_one_line_errors(tmp_path, monkeypatch):
    empty = tmp_path / "empty.obj"
    empty.write_text("# nothing here\n")
    with pytest.raises(InputError, match="no triangles"):
        load_mesh(empty)
    nan = _write_obj(tmp_path / "nan.obj", [(0, 0, 0), (1, 0, 0), ("nan", 1, 0)], [(0, 1, 2)])
    with pytest.raises(InputError, match="1 vertices are NaN"):
        load_mesh(nan)
    huge = _write_obj(tmp_path / "far.obj", [(0, 0, 0), (1e6, 0, 0), (0, 1, 0)], [(0, 1, 2)])
    with pytest.raises(InputError, match="m across"):
        load_mesh(huge)
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nformat garbage\n\x00\x01")
    with pytest.raises(InputError, match="cannot read the mesh"):
        load_mesh(garbage)
    with pytest.raises(InputError, match="no such file"):
        load_mesh(tmp_path / "missing.obj")
    quad = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (1, 1, 0)]
    ok = _write_obj(tmp_path / "many.obj", quad, [(0, 1, 2), (1, 3, 2)])
    monkeypatch.setattr(objects, "MAX_FACES", 1)
    with pytest.raises(InputError, match="more than the limit of 1"):
        load_mesh(ok)
    with pytest.raises(InputError) as info:
        load_mesh(empty)
    assert "\n" not in str(info.value) and str(info.value).startswith(str(empty))


def test_non_manifold_and_degenerate_meshes_load(tmp_path):
    # three triangles on one edge (non-manifold), one degenerate triangle, an open surface
    v = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (2, 2, 2)]
    f = [(0, 1, 2), (0, 1, 3), (0, 1, 4), (5, 5, 5)]
    m = load_mesh(_write_obj(tmp_path / "fan.obj", v, f))
    assert len(m.faces) == 4 and np.isfinite(m.normals).all()
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-5)
    p = m.proxy_spheres()
    assert p.shape[1] == 4 and (p[:, 3] > 0).all() and np.isfinite(p).all()


def test_object_transform_and_duplicate():
    o = SceneObject(primitive("cube"), PRESETS["matte-silver"], position=np.array([1.0, 2.0, 3.0]), scale=0.5)
    c, r = o.bounding_sphere()
    np.testing.assert_allclose(c, [1, 2, 3], atol=1e-6)
    assert r == pytest.approx(0.5 * np.sqrt(3), rel=1e-5)
    assert o.base_offset() == pytest.approx(0.5)
    d = o.duplicate()
    d.material.roughness = 0.9
    d.position[0] = 5
    assert o.material.roughness == 0.5 and o.position[0] == 1
    proxies = o.world_proxies()
    assert (np.linalg.norm(proxies[:, :3] - c, axis=1) < r).all()


def test_materials_presets_and_custom():
    assert parse_material("mirror-silver") == PRESETS["mirror-silver"]
    assert PRESETS["diffuse"].base_color == (0.5, 0.5, 0.5) and PRESETS["diffuse"].roughness == 1.0
    assert PRESETS["matte-silver"].roughness == 0.5 and PRESETS["matte-silver"].metallic == 1.0
    m = parse_material("0.8,0.1,0.1,0.3,0")
    assert m.base_color == (0.8, 0.1, 0.1) and m.roughness == 0.3
    for bad in ("gold", "1,2,3", "0.5,0.5,0.5,1.5,0", "nan,0,0,0,0"):
        with pytest.raises(InputError, match="--material"):
            parse_material(bad)


def test_decimate_keeps_the_shape_normals_and_hard_edges():
    """Vertex clustering (the meshes drawn while dragging): a 20k-triangle sphere at <= 2048
    triangles stays within 1% of the sphere with radial normals and its area; a finely tessellated
    box keeps flat, axis-aligned normals on its faces (normals are grouped per axis direction)."""
    m = trimesh.creation.icosphere(subdivisions=5)
    ball = objects._finish(m.vertices, None, m.faces, "ball", "ball")
    lod = ball.lod(2048)
    assert 1000 < len(lod.faces) <= 2048 and lod is ball.lod(2048)  # computed once
    r = np.linalg.norm(lod.vertices, axis=1)
    assert r.min() > 0.99 and r.max() < 1.0001
    assert (np.sum(lod.normals * lod.vertices / r[:, None], 1) > 0.99).all()
    area = trimesh.Trimesh(lod.vertices, lod.faces, process=False).area
    assert area == pytest.approx(4 * np.pi, rel=0.02)
    assert not lod.closed and np.array_equal(lod.proxy_spheres(), ball.proxy_spheres())
    assert ball.lod(0) is ball and ball.lod(len(ball.faces)) is ball
    box = trimesh.creation.box(extents=(2.0, 1.0, 1.0)).subdivide().subdivide().subdivide()
    box.unmerge_vertices()
    flat = objects._finish(box.vertices, np.repeat(box.face_normals, 3, axis=0), box.faces, "box", "box")
    small = objects.decimate(flat, 400)
    assert len(small.faces) <= 400 < len(flat.faces)
    assert np.allclose(np.abs(small.normals).max(1), 1.0, atol=1e-6)
    lo, hi = small.bounds
    np.testing.assert_allclose(hi - lo, [2.0, 1.0, 1.0], rtol=0.1)
