"""More of the bad-input corpus (generated here, nothing committed): meshes (empty, non-manifold, NaN,
10M faces, corrupt), weights files (unreadable, wrong architecture), wrong magic bytes and 1x2
images for every reader, a panorama at the size limit, and no half-written output after a failing
``phyir predict`` / ``phyir insert``.  Outcomes: docs/robustness.md."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import time

import numpy as np
import OpenEXR
import pytest
import torch
from PIL import Image
from support.corpus import corpus_outcomes
from support.memory import PEAK_MB
from support.tiny_scenes import tiny_scene

import phyir
from phyir import io
from phyir.cli import main as cli
from phyir.errors import InputError
from phyir.io import exr, ldr, rgbe
from phyir.nets import ModelConfig

pytestmark = pytest.mark.usefixtures("one_thread")
trimesh = pytest.importorskip("trimesh")


def one_line_naming(e: BaseException, path) -> str:
    msg = str(e)
    assert str(path) in msg and "\n" not in msg, msg
    return msg


def leftovers(folder) -> list[str]:
    """Temporary files atomic_write would leave behind if a write was interrupted."""
    return [p.name for p in folder.iterdir() if ".tmp" in p.name]


# ---------------------------------------------------------------------------------------------
# meshes


def ply_binary(path, vertices, faces, declared_faces: int | None = None, sparse_to: int | None = None):
    """A binary little-endian PLY; ``declared_faces`` overrides the header's count and ``sparse_to``
    extends the file (sparsely: no disk used) to the size that count implies."""
    v = np.asarray(vertices, np.float32)
    f = np.asarray(faces, np.int32)
    nf = len(f) if declared_faces is None else declared_faces
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(v)}\nproperty float x\n"
            f"property float y\nproperty float z\nelement face {nf}\n"
            "property list uchar int vertex_indices\nend_header\n").encode()
    body = b"".join(struct.pack("<B3i", 3, *t) for t in f)
    with open(path, "wb") as fh:
        fh.write(head + v.tobytes() + body)
        if sparse_to:
            fh.truncate(sparse_to)
    return path


def test_meshes_declaring_10m_faces_are_refused_from_the_header(tmp_path, monkeypatch):
    """10M triangles: ~120 MB of int32 indices (and ~5x that inside trimesh).  PLY, OFF and binary STL
    headers declare their face count: the limit is applied before any parsing."""
    from phyir.insert import objects

    n = 10_000_000
    tri = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    ply = ply_binary(tmp_path / "big.ply", tri, [(0, 1, 2)], declared_faces=n, sparse_to=36 + 13 * n + 300)
    stl = tmp_path / "big.stl"
    with open(stl, "wb") as fh:
        fh.write(b"\0" * 80 + struct.pack("<I", n))
        fh.truncate(84 + 50 * n)  # 500 MB, sparse
    off = tmp_path / "big.off"
    off.write_text(f"OFF\n3 {n} 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n")  # truncated body: header decides

    def must_not_parse(*a, **k):
        raise AssertionError("the mesh was parsed despite its header")

    monkeypatch.setattr(trimesh, "load", must_not_parse)
    for path in (ply, stl, off):
        t0 = time.perf_counter()
        with pytest.raises(InputError, match="10,000,000 triangles .* more than the limit of 5,000,000") as e:
            objects.load_mesh(path)
        assert time.perf_counter() - t0 < 2.0
        one_line_naming(e.value, path)
    assert objects.declared_faces(str(ply_binary(tmp_path / "ok.ply", tri, [(0, 1, 2)]))) == 1
    (tmp_path / "x.obj").write_text("v 0 0 0\n")
    assert objects.declared_faces(str(tmp_path / "x.obj")) is None  # OBJ: counted after parsing


def test_empty_nan_and_non_manifold_binary_meshes(tmp_path):
    from phyir.insert.objects import load_mesh

    tri = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
    with pytest.raises(InputError, match="no triangles") as e:
        load_mesh(ply_binary(tmp_path / "empty.ply", tri, np.zeros((0, 3))))
    one_line_naming(e.value, tmp_path / "empty.ply")
    with pytest.raises(InputError, match="2 vertices are NaN or infinite"):
        load_mesh(ply_binary(tmp_path / "nan.ply", [*tri, (np.nan, 0, 0), (0, np.inf, 0)],
                             [(0, 1, 2), (2, 3, 4)]))
    with pytest.raises(InputError, match="faces refer to vertices that do not exist"):
        load_mesh(ply_binary(tmp_path / "index.ply", tri, [(0, 1, 7)]))
    # four triangles on one edge, an unused vertex, a duplicated face: loads, normals finite and unit
    v = [(0, 0, 0), (1, 0, 0), (0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (5, 5, 5)]
    faces = [(0, 1, 2), (0, 1, 3), (0, 1, 4), (0, 1, 5), (0, 1, 5)]
    m = load_mesh(ply_binary(tmp_path / "fan.ply", v, faces))
    assert len(m.faces) == 5 and not m.closed
    np.testing.assert_allclose(np.linalg.norm(m.normals, axis=1), 1.0, atol=1e-5)


MESH_CHILD = r"""
import json, sys
from phyir.errors import InputError
from phyir.insert.objects import load_mesh
for path in sys.argv[1:]:
    try:
        m = load_mesh(path)
        import numpy as np
        out = "ok" if np.isfinite(m.vertices).all() and np.isfinite(m.normals).all() else "NaN"
    except InputError as e:
        out = "InputError" if path in str(e) and "\n" not in str(e) else "bad message: " + str(e)
    print(json.dumps([path, out]), flush=True)
print("done", flush=True)
"""


@pytest.mark.slow  # ~5 s of CPU, but a minute of wall time on a loaded machine
def test_corrupt_mesh_corpus_never_crashes(tmp_path):
    """Truncated, bit-flipped and random files of every mesh format, read by trimesh in a child
    interpreter: each loads or gives a one-line InputError; no crash, no hang."""
    good = trimesh.creation.icosphere(subdivisions=1, radius=0.5)
    rng = np.random.default_rng(11)
    paths = []
    for ext in ("obj", "ply", "stl", "off", "glb"):
        data = good.export(file_type=ext)
        data = data.encode() if isinstance(data, str) else data
        variants = {"trunc": data[: len(data) // 2], "head": data[:40], "random": rng.bytes(3000),
                    "empty": b""}
        for k in range(2):
            b = bytearray(data)
            for i in rng.integers(0, len(b), 4):
                b[i] ^= int(rng.integers(1, 256))
            variants[f"flip{k}"] = bytes(b)
        for name, blob in variants.items():
            paths.append(tmp_path / f"{name}.{ext}")
            paths[-1].write_bytes(blob)
    results = corpus_outcomes(MESH_CHILD, paths)
    for p in paths:
        if p.name.startswith(("empty", "random", "head")):
            assert results[str(p)] == "InputError", p.name


# ---------------------------------------------------------------------------------------------
# weights files


@pytest.fixture(scope="module")
def pano_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("pano") / "room.hdr"
    io.save_panorama(tiny_scene(4, H=32, W=64).image, path)
    return path


def bad_weights(folder, good) -> dict[str, tuple[object, str]]:
    """name -> (path, expected message) of every unreadable / mismatched weights file."""
    from safetensors.torch import save

    model, path = good
    data = path.read_bytes()
    state = {k: v.contiguous() for k, v in model.state_dict().items()}
    cfg = model.config.to_dict()
    def meta(c):
        return {"format": "phyir-weights-1", "phyir.config": json.dumps(c)}
    files = {
        "missing": (None, "weights file not found"),
        "empty": (b"", "not a readable safetensors weights file"),
        "truncated": (data[: len(data) // 2], "not a readable safetensors weights file"),
        "random": (np.random.default_rng(3).bytes(4096), "not a readable safetensors weights file"),
        "huge header length": (struct.pack("<Q", 1 << 60) + b"{}", "not a readable safetensors weights file"),
        "not phyir": (save(state), "not a PhyIR weights file"),
        "config json": (save(state, metadata={"format": "phyir-weights-1", "phyir.config": "{oops"}),
                        "corrupt architecture metadata"),
        "unknown arch": (save(state, metadata=meta({**cfg, "depth_of_field": 3})), "unknown architecture"),
        "lite as full": (save(state, metadata=meta(ModelConfig.named("full", probe_size=(8, 16)).to_dict())),
                         "weights of architecture 'full' do not fit the 'full' model: .* of wrong shape"),
        "wrong shape": (save({**state, "lnet.head.0.weight": torch.zeros(3, 3)}, metadata=meta(cfg)),
                        "of wrong shape"),
    }
    out = {}
    for name, (blob, msg) in files.items():
        p = folder / (name.replace(" ", "_") + ".safetensors")
        if blob is not None:
            p.write_bytes(blob)
        out[name] = (p, msg)
    return out


def test_unreadable_and_mismatched_weights_through_predict(tmp_path, tiny_weights, pano_file):
    cases = bad_weights(tmp_path, tiny_weights)
    assert "lnet.head.0.weight" in tiny_weights[0].state_dict()  # the tensor "wrong shape" replaces
    for path, msg in cases.values():
        with pytest.raises(InputError, match=msg) as e:
            phyir.predict(pano_file, weights=path)
        one_line_naming(e.value, path)
    s = phyir.predict(pano_file, weights=tiny_weights[1])  # the good file works
    assert s.meta["predict.net_size"] == "32x64"


def test_weights_sidecar_missing_or_corrupt(tmp_path, tiny_weights, pano_file):
    import shutil

    w = tmp_path / "w.safetensors"
    shutil.copy(tiny_weights[1], w)  # no sidecar: the default network size
    s = phyir.predict(pano_file, weights=w, outputs=["depth"])
    assert s.meta["predict.net_size"] == "32x64"  # the default, capped at the input's size
    w2 = tmp_path / "w2.safetensors"
    shutil.copy(tiny_weights[1], w2)
    w2.with_suffix(".json").write_text("{truncated")
    with pytest.warns(UserWarning, match=r"w2.json: unreadable weights sidecar"):
        s = phyir.predict(pano_file, weights=w2, outputs=["depth"])
    assert torch.isfinite(s.depth).all()


def test_cli_predict_bad_weights_and_bad_input_write_nothing(tmp_path, tiny_weights, pano_file, capsys):
    (tmp_path / "w").mkdir()
    cases = bad_weights(tmp_path / "w", tiny_weights)
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    for name, (path, _) in cases.items():
        out = out_dir / "scene.exr"
        assert cli(["predict", str(pano_file), "-o", str(out), "--weights", str(path), "-q"]) == 2, name
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and str(path) in err and err.startswith("phyir predict: error:"), err
        assert not out.exists() and not leftovers(out_dir), name
    corrupt = tmp_path / "corrupt.exr"
    corrupt.write_bytes(exr.MAGIC + b"\x02\0\0\0garbage")
    out = out_dir / "c.exr"
    assert cli(["predict", str(corrupt), "-o", str(out), "--weights", str(tiny_weights[1]), "-q"]) == 2
    assert "corrupt or truncated OpenEXR header" in capsys.readouterr().err
    assert not out.exists() and not leftovers(out_dir)


def test_interrupted_write_leaves_no_partial_output(tmp_path, tiny_weights, pano_file, monkeypatch):
    """Ctrl-C while the scene file is being written: no output, no temporary; an existing output
    stays as it was."""
    out = tmp_path / "scene.exr"
    real = exr.write_parts

    def half_then_interrupt(path, parts, *a, **k):
        real(path, parts, *a, **k)
        with open(path, "r+b") as f:
            f.truncate(os.path.getsize(path) // 2)
        raise KeyboardInterrupt

    monkeypatch.setattr(exr, "write_parts", half_then_interrupt)
    assert cli(["predict", str(pano_file), "-o", str(out), "--weights", str(tiny_weights[1]), "-q"]) == 130
    assert not out.exists() and not leftovers(tmp_path)
    out.write_bytes(b"previous result")
    assert cli(["predict", str(pano_file), "-o", str(out), "--weights", str(tiny_weights[1]), "-q"]) == 130
    assert out.read_bytes() == b"previous result" and not leftovers(tmp_path)


def test_cli_insert_bad_mesh_writes_nothing(tmp_path, capsys):
    from support.scenes import box_room

    scene = tmp_path / "room.exr"
    io.save_scene(box_room(32, 64), scene)
    bad = {"nan.ply": ply_binary(tmp_path / "nan.ply", [(0, 0, 0), (1, 0, 0), (np.nan, 1, 0)], [(0, 1, 2)]),
           "random.glb": tmp_path / "random.glb", "big.ply": None}
    bad["random.glb"].write_bytes(np.random.default_rng(5).bytes(2000))
    bad["big.ply"] = ply_binary(tmp_path / "big.ply", [(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(0, 1, 2)],
                                declared_faces=10_000_000)
    for name, mesh in bad.items():
        out = tmp_path / "out" / "x.exr"
        out.parent.mkdir(exist_ok=True)
        assert cli(["insert", str(scene), "--object", str(mesh), "--at", "32,20", "-o", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert str(mesh) in err and "\n" not in err, err
        assert list(out.parent.iterdir()) == [], name


# ---------------------------------------------------------------------------------------------
# images: wrong magic bytes and 1x2 for every reader, a panorama at the size limit


def images(folder, H: int, W: int) -> dict[str, os.PathLike]:
    rng = np.random.default_rng(6)
    img = rng.random((3, H, W)).astype(np.float32)
    paths = {"exr": folder / f"{H}x{W}.exr", "hdr": folder / f"{H}x{W}.hdr", "png": folder / f"{H}x{W}.png",
             "jpeg": folder / f"{H}x{W}.jpg"}
    OpenEXR.File({}, {"R": img[0], "G": img[1], "B": img[2]}).write(str(paths["exr"]))
    paths["hdr"].write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {H} +X {W}\n".encode()
                             + rgbe.float_to_rgbe(img.transpose(1, 2, 0)).tobytes())
    Image.fromarray((img.transpose(1, 2, 0) * 255).astype(np.uint8)).save(paths["png"])
    Image.fromarray((img.transpose(1, 2, 0) * 255).astype(np.uint8)).save(paths["jpeg"])
    return paths


def test_wrong_magic_bytes_for_every_reader(tmp_path):
    good = images(tmp_path, 16, 32)
    for fmt, path in good.items():
        assert io.sniff(path) == fmt and io.load_panorama(path).shape == (3, 16, 32)
        data = bytearray(path.read_bytes())
        data[1] ^= 0x20  # one flipped bit in the signature
        bad = tmp_path / f"bad_{path.name}"
        bad.write_bytes(bytes(data))
        expect = "not an OpenEXR file" if fmt == "exr" else "not a supported image"
        with pytest.raises(InputError, match=expect) as e:
            io.load_scene(bad)
        one_line_naming(e.value, bad)
    # each low-level reader handed another format's file
    for reader, other, match in ((exr.read_headers, "png", "not an OpenEXR file"),
                                 (rgbe.read_header, "exr", "not a Radiance HDR file"),
                                 (ldr.read_info, "hdr", "not a readable image")):
        with pytest.raises(InputError, match=match) as e:
            reader(good[other])
        one_line_naming(e.value, good[other])


def test_1x2_images_of_every_format_are_refused(tmp_path):
    for path in images(tmp_path, 1, 2).values():
        with pytest.raises(InputError, match=r"absurd size: 1x2 \(HxW\) is smaller than the minimum") as e:
            io.load_panorama(path)
        one_line_naming(e.value, path)


def hdr_constant(path, H: int, W: int, rgbe_bytes=(128, 64, 32, 129), blue_run: int = 127) -> None:
    """A flat-colour Radiance file made of RLE runs (8 MB for 8192x16384), written in no time;
    ``blue_run`` < 127: the blue mantissa alternates (+1) every that many pixels (a larger file)."""
    line = bytearray([2, 2, W >> 8, W & 255])
    for c, b in enumerate(rgbe_bytes):
        run = blue_run if c == 2 else 127
        for k, start in enumerate(range(0, W, run)):
            line += bytes([128 + min(run, W - start), b + (k % 2 if c == 2 and run < 127 else 0)])
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {H} +X {W}\n".encode() + bytes(line) * H)


def test_just_over_the_size_limit_is_refused_from_the_header(tmp_path):
    hdr_constant(tmp_path / "over.hdr", 8193, 16386)
    with pytest.raises(InputError, match="absurd size: panorama is 8193x16386"):
        io.load_panorama(tmp_path / "over.hdr")


LIMIT_CHILD = r"""
import sys, time, warnings
import torch
torch.set_num_threads(1)
import phyir
from phyir import io
t = time.perf_counter()
img = io.load_panorama(sys.argv[1])
ok = tuple(img.shape) == (3, 8192, 16384) and bool(torch.isfinite(img).all())
ok = ok and float(img[0, 0, 0]) == 1.0 and float(img[:2, -1, -1].sum()) == 1.5  # RGBE (128,64,32|33,129)
seconds = time.perf_counter() - t
del img
try:  # refused from the header, before decoding
    phyir.predict(sys.argv[1])
    refused = "no"
except phyir.InputError as e:
    refused = "yes" if "too large to predict" in str(e) and sys.argv[1] in str(e) else str(e)
peak = int(%PEAK_MB%)
print(ok, refused, round(seconds, 1), peak)
""".replace("%PEAK_MB%", PEAK_MB)


@pytest.mark.slow
def test_panorama_at_the_size_limit_loads_and_predict_refuses_it(tmp_path):
    """8192x16384 (the largest accepted size) loads (1.6 GB of float32), in a child interpreter whose
    peak memory is measured; predict refuses it (MAX_PREDICT_SIZE) instead of needing ~19 GB."""
    path = tmp_path / "limit.hdr"
    # the flat 8 MB file would be refused as a decompression bomb (phyir.io.sniff: over 384 MiB of
    # pixels from a file under 1/96 of that); blue runs of 8 pixels make it 34 MB, enough to hold them
    hdr_constant(path, 8192, 16384, blue_run=8)
    proc = subprocess.run([sys.executable, "-c", LIMIT_CHILD, str(path)], capture_output=True, text=True,
                          timeout=500)  # ~15 s of CPU; minutes of wall time on a loaded machine
    assert proc.returncode == 0, proc.stderr[-2000:]
    ok, refused, seconds, peak_mb = proc.stdout.split()
    assert ok == "True" and refused == "yes", proc.stdout
    assert int(peak_mb) < 6000, f"peak memory {peak_mb} MB"  # measured: 5.0 GB
    print(f"8192x16384: loaded in {seconds} s, peak {peak_mb} MB")


def test_predict_refuses_inputs_over_its_size_limit(tmp_path, tiny_weights, pano_file, monkeypatch, capsys):
    from phyir import inference

    monkeypatch.setattr(inference, "MAX_PREDICT_SIZE", (16, 32))
    for decoder in (io.exr, io.rgbe, io.ldr):
        monkeypatch.setattr(decoder, "read_pixels", lambda *a, **k: pytest.fail("decoded despite the header"))
    with pytest.raises(InputError, match="32x64 is too large to predict at full resolution") as e:
        phyir.predict(pano_file, weights=tiny_weights[1])
    one_line_naming(e.value, pano_file)
    monkeypatch.undo()
    monkeypatch.setattr(inference, "MAX_PREDICT_SIZE", (16, 32))
    with pytest.raises(InputError, match="^32x64 is too large"):  # a tensor: checked after all
        phyir.predict(torch.rand(3, 32, 64), weights=tiny_weights[1])
    out = tmp_path / "o.exr"
    assert cli(["predict", str(pano_file), "-o", str(out), "--weights", str(tiny_weights[1]), "-q"]) == 2
    assert "too large to predict" in capsys.readouterr().err and not out.exists()
