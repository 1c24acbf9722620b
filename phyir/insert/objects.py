"""Objects to insert: meshes (trimesh: OBJ, PLY, STL, OFF, GLB, ...), built-in unit primitives and
materials with the supplement's Table 2 presets.  No GL here: the GPU side is viewer/insertion.py.

Units and axes: a mesh keeps its own units (metres) and its local +y is its up axis (placement
stands it on surfaces along +y).  Primitives are unit-size: ``sphere`` of radius 1, ``cube``
spanning [-1, 1]^3, ``cylinder`` of radius 1 from y = -1 to 1; a scale multiplies them.

Loading outcomes (documented in docs/insertion.md, tested in tests/phyir/insert/test_objects.py):
* missing or unreadable file, no triangles, NaN/Inf vertices, more than :data:`MAX_FACES`
  triangles, zero or absurd size: :class:`~phyir.errors.InputError` with a one-line message (PLY,
  OFF and binary STL files declaring too many faces are refused from their header, before parsing);
* non-manifold or open meshes load as they are (rendering does not need a closed surface); their
  ambient-occlusion proxies are fitted to surface samples;
* missing or broken (zero, NaN) vertex normals are computed from the faces.
"""

from __future__ import annotations

import copy
import os
from dataclasses import dataclass, field

import numpy as np

from phyir.errors import InputError
from phyir.evaluation.metrics import RELIGHT_MATERIALS

MAX_FACES = 5_000_000
MAX_EXTENT = 1000.0  # metres
MIN_EXTENT = 1e-5
PRIMITIVES = ("sphere", "cube", "cylinder")
PROXY_COUNT = 8
MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


# ---------------------------------------------------------------------------------------------
# materials


@dataclass
class ObjectMaterial:
    """The BRDF parameters of phyir.shading.brdf: base colour (linear RGB), roughness R, metalness M."""

    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    roughness: float = 0.5
    metallic: float = 0.0

    def as_text(self) -> str:
        return ",".join(f"{x:g}" for x in (*self.base_color, self.roughness, self.metallic))


# supplement Table 2 (the relighting spheres), names as on the command line
PRESETS: dict[str, ObjectMaterial] = {name.replace("_", "-"): ObjectMaterial(tuple(b), r, m)
                                for name, (b, r, m) in RELIGHT_MATERIALS.items()}


def parse_material(text: str) -> ObjectMaterial:
    """A preset name (diffuse, matte-silver, mirror-silver) or ``B,B,B,R,M`` with values in [0, 1]."""
    key = text.strip().lower().replace("_", "-")
    if key in PRESETS:
        return copy.deepcopy(PRESETS[key])
    parts = text.split(",")
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 5 or not all(np.isfinite(vals)) or not all(0 <= x <= 1 for x in vals):
        raise InputError("--material", f"expected one of {', '.join(PRESETS)} or B,B,B,R,M with "
                                       f"values in [0, 1], got {text!r}")
    return ObjectMaterial(tuple(vals[:3]), vals[3], vals[4])  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------------------
# meshes


@dataclass
class Mesh:
    """Triangles with per-vertex normals (float32, local frame, +y up)."""

    vertices: np.ndarray  # [V, 3]
    normals: np.ndarray  # [V, 3] unit
    faces: np.ndarray  # [F, 3] uint32
    name: str = "mesh"
    proxies: np.ndarray | None = None  # [K, 4] spheres (centre, radius) for ambient occlusion
    closed: bool = False  # watertight with outward, consistent winding: back faces can be culled
    lods: dict = field(default_factory=dict, repr=False, compare=False)  # max faces -> decimate()

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return self.vertices.min(0), self.vertices.max(0)

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        """Centre of the bounding box and the radius reaching every vertex."""
        lo, hi = self.bounds
        c = 0.5 * (lo + hi)
        return c, float(np.sqrt(((self.vertices - c) ** 2).sum(1).max()))

    def proxy_spheres(self) -> np.ndarray:
        """Spheres ``[K, 4]`` approximating the volume (ambient occlusion), computed once."""
        if self.proxies is None:
            self.proxies = fit_proxies(self)
        return self.proxies

    def lod(self, max_faces: int) -> Mesh:
        """This mesh with at most ``max_faces`` triangles (:func:`decimate`, computed once per count);
        the mesh itself when it has no more than that or ``max_faces`` is 0."""
        if max_faces <= 0 or len(self.faces) <= max_faces:
            return self
        if max_faces not in self.lods:
            self.lods[max_faces] = decimate(self, max_faces)
        return self.lods[max_faces]


def _finish(vertices: np.ndarray, normals: np.ndarray | None, faces: np.ndarray, name: str,
            where: str) -> Mesh:
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if len(f) == 0 or len(v) == 0:
        raise InputError(where, "the mesh has no triangles")
    if v.ndim != 2 or v.shape[1] != 3:  # e.g. an OBJ line "v 1 0": trimesh then gives [V, 2]
        raise InputError(where, f"vertices must have 3 coordinates (x y z), got array {list(v.shape)}")
    if f.size % 3:
        raise InputError(where, f"faces must be triangles, got array {list(f.shape)}")
    f = f.reshape(-1, 3)
    if len(f) > MAX_FACES:
        raise InputError(where, f"{len(f):,} triangles is more than the limit of {MAX_FACES:,}; "
                                "decimate the mesh first")
    bad = ~np.isfinite(v).all(1)
    if bad.any():
        raise InputError(where, f"{int(bad.sum())} vertices are NaN or infinite")
    if f.min() < 0 or f.max() >= len(v):
        raise InputError(where, "faces refer to vertices that do not exist")
    extent = float((v.max(0) - v.min(0)).max())
    if not MIN_EXTENT <= extent <= MAX_EXTENT:
        raise InputError(where, f"the mesh is {extent:.3g} m across; expected {MIN_EXTENT:g} to "
                                f"{MAX_EXTENT:g} m (meshes keep their units: metres)")
    n = _vertex_normals(v, f) if normals is None else np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(n, axis=1)
    broken = ~np.isfinite(length) | (length < 1e-8)
    if broken.any():
        n = np.where(broken[:, None], _vertex_normals(v, f), n)
        length = np.linalg.norm(n, axis=1)
    n = n / np.maximum(length, 1e-12)[:, None]
    n[~np.isfinite(n).all(1)] = (0.0, 1.0, 0.0)
    return Mesh(v.astype(np.float32), n.astype(np.float32), f.astype(np.uint32), name)


def _cluster(mesh: Mesh, cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertex clustering on a ``cells``^3 grid over the bounding box: (vertices, normals, faces).
    Every vertex of a cell moves to the cell's mean, so the result has no cracks; within a cell,
    vertices whose normals round to different axis directions stay apart (hard edges keep their
    normals), each with the mean normal of its group.  Faces with two corners in one cell vanish."""
    v, n = mesh.vertices.astype(np.float64), mesh.normals.astype(np.float64)
    lo, hi = mesh.bounds
    size = max(float((hi - lo).max()), 1e-12)
    ijk = np.clip(((v - lo) / size * cells).astype(np.int64), 0, cells - 1)
    cell = (ijk[:, 0] * cells + ijk[:, 1]) * cells + ijk[:, 2]
    cell_ids, cell_of = np.unique(cell, return_inverse=True)
    centre = np.zeros((len(cell_ids), 3))
    np.add.at(centre, cell_of, v)
    centre /= np.bincount(cell_of, minlength=len(cell_ids))[:, None]
    bins = ((np.rint(n).astype(np.int64) + 1) * (9, 3, 1)).sum(1)  # 27 axis directions
    _, vert_of = np.unique(cell_of * 27 + bins, return_inverse=True)
    nv = int(vert_of.max()) + 1
    out_cell = np.zeros(nv, np.int64)
    out_cell[vert_of] = cell_of
    normal = np.zeros((nv, 3))
    np.add.at(normal, vert_of, n)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    f = vert_of[mesh.faces.astype(np.int64)]
    c = out_cell[f]
    f = f[(c[:, 0] != c[:, 1]) & (c[:, 1] != c[:, 2]) & (c[:, 0] != c[:, 2])]
    if len(f):  # one copy of each triangle (same corners, same winding)
        roll = np.argmin(f, axis=1)
        f = np.stack([f[np.arange(len(f)), (roll + k) % 3] for k in range(3)], 1)
        f = np.unique(f, axis=0)
    return centre[out_cell], normal, f


def decimate(mesh: Mesh, max_faces: int) -> Mesh:
    """A coarser stand-in of ``mesh`` with at most ``max_faces`` triangles (vertex clustering on the
    finest grid that gets there), for the passes that draw it small or blurred while an object is
    dragged.  It shares the mesh's ambient-occlusion proxies and is never marked closed
    (clustering can fold triangles over, so back faces are not culled)."""
    cells = max(int(np.sqrt(max_faces)), 2)
    while True:
        v, n, f = _cluster(mesh, cells)
        if len(f) <= max_faces or cells <= 2:
            break
        cells = max(min(cells - 1, int(cells * 0.95 * np.sqrt(max_faces / len(f)))), 2)
    if len(f) == 0:  # everything in one cell: the mesh is its bounding box's size at most
        return mesh
    return Mesh(v.astype(np.float32), n.astype(np.float32), f.astype(np.uint32), f"{mesh.name} (lod)",
                mesh.proxy_spheres())


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals (vertices of degenerate faces only get (0, 1, 0))."""
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 x area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(length > 1e-20, n / np.maximum(length, 1e-30), np.array([0.0, 1.0, 0.0]))


def declared_faces(path: str) -> int | None:
    """The face count a PLY, OFF or binary STL file declares in its header (read without parsing the
    body), or None for other formats or an unreadable header (the parser then decides)."""
    import struct

    with open(path, "rb") as f:
        head = f.read(64 * 1024)
    size = os.path.getsize(path)
    if head.startswith(b"ply"):
        for line in head.split(b"end_header")[0].splitlines():
            words = line.split()
            if len(words) == 3 and words[:2] == [b"element", b"face"] and words[2].isdigit():
                return int(words[2])
        return None
    lines = [ln.split(b"#")[0].strip() for ln in head.splitlines()[:64]]
    lines = [ln for ln in lines if ln]
    if lines and lines[0].endswith(b"OFF") and len(lines) > 1:  # OFF, COFF, NOFF: "nv nf ne" next
        counts = lines[1].split()
        if len(counts) >= 2 and counts[1].isdigit():
            return int(counts[1])
        return None
    if len(head) >= 84:  # binary STL: 80-byte header, uint32 count, 50 bytes per triangle
        (n,) = struct.unpack("<I", head[80:84])
        if size == 84 + 50 * n:
            return n
    return None


def load_mesh(path: str | os.PathLike) -> Mesh:
    """Read a mesh file (every part of a scene file merged into one mesh); see the module doc."""
    import trimesh

    from phyir.io import check_input

    p = os.fspath(path)
    check_input(p, "mesh file")  # a FIFO, a device, a folder, a symlink loop: said as such
    declared = declared_faces(p)
    if declared is not None and declared > MAX_FACES:  # refused before parsing (nothing allocated)
        raise InputError(p, f"{declared:,} triangles (declared in the file's header) is more than the "
                            f"limit of {MAX_FACES:,}; decimate the mesh first")
    try:
        # textures and materials are never used (the object's material is --material): not decoded,
        # so a small GLB with a 12000^2 embedded image costs nothing
        loaded = trimesh.load(p, force="mesh", process=False, skip_materials=True)
    except Exception as e:  # trimesh raises many types for bad files
        msg = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(p, f"cannot read the mesh: {msg}") from None
    if not isinstance(loaded, trimesh.Trimesh):
        raise InputError(p, "the file holds no triangle mesh")
    # normals from the faces: area-weighted over shared vertices, flat where the file splits them
    mesh = _finish(np.asarray(loaded.vertices), None, np.asarray(loaded.faces), os.path.basename(p), p)
    welded = trimesh.Trimesh(mesh.vertices, mesh.faces, process=True, validate=False)
    mesh.closed = bool(welded.is_watertight and welded.is_winding_consistent and welded.volume > 0)
    return mesh


def primitive(name: str) -> Mesh:
    """A unit primitive (see the module doc) with sharp edges where it has them."""
    import trimesh

    if name == "sphere":
        m = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
        v = np.asarray(m.vertices)
        mesh = _finish(v, v / np.linalg.norm(v, axis=1, keepdims=True), m.faces, name, name)
        mesh.proxies = np.array([[0.0, 0.0, 0.0, 1.0]], dtype=np.float32)
        mesh.closed = True
        return mesh
    if name == "cube":
        m = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    elif name == "cylinder":
        m = trimesh.creation.cylinder(radius=1.0, height=2.0, sections=64)
        m.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))  # z -> y
    else:
        raise InputError("--object", f"unknown primitive {name!r}; expected {', '.join(PRIMITIVES)} "
                                     "or a mesh file")
    # split vertices so flat faces keep flat normals (angle threshold: sharp edges)
    flat = m.copy()
    flat.unmerge_vertices()
    fv = np.asarray(flat.vertices)
    fn = np.repeat(np.asarray(flat.face_normals), 3, axis=0)
    if name == "cylinder":  # smooth side: radial normals where the face is not a cap
        radial = fv * np.array([1.0, 0.0, 1.0])
        side = np.abs(fn[:, 1]) < 0.5
        fn = np.where(side[:, None], radial / np.maximum(np.linalg.norm(radial, axis=1, keepdims=True),
                                                         1e-12), fn)
    mesh = _finish(fv, fn, np.arange(len(fv)).reshape(-1, 3), name, name)
    mesh.closed = True
    return mesh


def object_mesh(spec: str) -> Mesh:
    """``sphere|cube|cylinder`` or a mesh file path."""
    if spec in PRIMITIVES:
        return primitive(spec)
    if os.path.splitext(spec)[1].lower() not in MESH_SUFFIXES and not os.path.lexists(spec):
        raise InputError("--object", f"expected {', '.join(PRIMITIVES)} or a mesh file "
                                     f"({', '.join(MESH_SUFFIXES)}), got {spec!r}")
    return load_mesh(spec)


def fit_proxies(mesh: Mesh, count: int = PROXY_COUNT, seed: int = 0) -> np.ndarray:
    """``[K, 4]`` spheres covering the mesh: k-means of surface samples; each radius is the RMS
    distance of its cluster's samples (a sphere through the cluster's surface)."""
    rng = np.random.default_rng(seed)
    v, f = mesh.vertices.astype(np.float64), mesh.faces.astype(np.int64)
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    n = 2048
    pick = rng.choice(len(f), size=n, p=area / area.sum()) if area.sum() > 0 else rng.integers(0, len(f), n)
    r1, r2 = rng.random((2, n, 1))
    s = np.sqrt(r1)
    pts = (1 - s) * a[pick] + s * (1 - r2) * b[pick] + s * r2 * c[pick]
    k = min(count, n)
    centres = pts[rng.choice(n, k, replace=False)]
    for _ in range(12):
        lab = ((pts[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
        for j in range(k):
            if (lab == j).any():
                centres[j] = pts[lab == j].mean(0)
    lab = ((pts[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
    out = []
    for j in range(k):
        q = pts[lab == j]
        if len(q):
            out.append((*centres[j], float(np.sqrt(((q - centres[j]) ** 2).sum(1).mean()))))
    return np.asarray(out, dtype=np.float32)


# ---------------------------------------------------------------------------------------------
# objects in the scene


@dataclass
class SceneObject:
    """One inserted object: a mesh, its material and its placement (world frame, metres)."""

    mesh: Mesh
    material: ObjectMaterial = field(default_factory=ObjectMaterial)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))  # of the mesh's local origin
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    scale: float = 1.0
    visible: bool = True
    name: str = ""
    support: tuple[np.ndarray, np.ndarray] | None = None  # (point, normal) of the surface it rests on

    def __post_init__(self):
        self.position = np.asarray(self.position, dtype=np.float64)
        self.rotation = np.asarray(self.rotation, dtype=np.float64)
        if not self.name:
            self.name = self.mesh.name

    def model_matrix(self) -> np.ndarray:
        """4x4 local -> world."""
        m = np.eye(4)
        m[:3, :3] = self.rotation * self.scale
        m[:3, 3] = self.position
        return m

    def bounding_sphere(self) -> tuple[np.ndarray, float]:
        c, r = self.mesh.bounding_sphere()
        return self.rotation @ (c * self.scale) + self.position, r * self.scale

    def world_proxies(self) -> np.ndarray:
        p = self.mesh.proxy_spheres().astype(np.float64)
        out = np.empty_like(p)
        out[:, :3] = p[:, :3] @ (self.rotation * self.scale).T + self.position
        out[:, 3] = p[:, 3] * self.scale
        return out

    def base_offset(self) -> float:
        """Distance from the local origin down to the lowest vertex along local +y, scaled."""
        return -float(self.mesh.vertices[:, 1].min()) * self.scale

    def duplicate(self) -> SceneObject:
        return SceneObject(self.mesh, copy.deepcopy(self.material), self.position.copy(),
                           self.rotation.copy(), self.scale, self.visible, self.name + " copy",
                           None if self.support is None else (self.support[0].copy(), self.support[1].copy()))

