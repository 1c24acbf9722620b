"""Evaluation on the user's own panoramas, which have no ground truth (issues 19 and 20).

What can be checked without ground truth is whether the prediction behaves like indoor geometry and
like a function of the scene rather than of the picture:

* **plausibility** — the floor below the camera and the ceiling above it: ``nadir_up`` is the share of
  pixels below :data:`NADIR_LAT` whose normal is within :data:`UP_TOL_DEG` of +y, ``zenith_down`` the
  share above :data:`ZENITH_LAT` within it of −y; ``camera_height`` (m) is the median of −y over the
  nadir cap's points (depth × direction) and ``floor_planarity`` the median |y + height| / height
  there (0: a flat floor);
* **consistency** — ``consistency_deg``: the mean angle between the predicted normals and the normals
  of the predicted depth (central differences of the point map, wrapping in longitude) over
  |latitude| < :data:`CONSISTENCY_LAT` (the poles' differences degenerate);
* **invariances** — medians over pixels of the relative difference (depth |a−b|/b, base colour
  Σ|a−b| / max(Σb, :data:`ALBEDO_FLOOR`)) or the angle (normals, degrees) between the prediction of a
  transformed input, brought back, and the prediction of the input: ``yaw`` (rolled by W/4 columns,
  rolled and rotated back with :func:`phyir.transforms.rotate_yaw`), ``exposure_1_16``/``exposure_16``
  (radiance × 1/16 and × 16), ``ldr`` (the auto-exposed 8-bit copy,
  :func:`phyir.learn.camera.ldr_copy`, predicted with ``hdr=False``) and ``res_half``/``res_double``
  (the input area-resized to half and twice its width, 512 and 2048 for a 1k panorama; compared at
  half the input's size);
* **confidence** — :func:`scene_confidence`, a score in [0, 1] from plausibility, consistency and
  the room's size;
* **lighting at a point** — :mod:`phyir.evaluation.real_lighting`, for the input and for its LDR copy.

:func:`evaluate_real` runs all of it on a folder; ``phyir eval --real DIR`` is its command line.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from phyir import pano
from phyir.color import linear_to_srgb
from phyir.evaluation import real_lighting as RL
from phyir.learn.camera import ldr_copy
from phyir.scene import PanoScene
from phyir.sheets import ramp_colours

NADIR_LAT = -65.0  # degrees: below this the camera sees the floor in any room
ZENITH_LAT = 70.0  # degrees: above this, the ceiling
UP_TOL_DEG = 20.0
CONSISTENCY_LAT = 60.0
CONSISTENCY_SIZE = (256, 512)  # consistency is measured at most at this size (the networks')
CONSISTENCY_SCALE_DEG = 30.0  # the consistency angle at which confidence halves (random normals: 90)
FLAG_BELOW = 0.5
FAR_QUANTILE = 0.9  # the room's size: this quantile of the depth over the panorama's pixels (m)
FAR_SCALE_M = 12.0  # the size at which the room-size factor halves confidence (a hall)
ALBEDO_FLOOR = 0.03  # Σ RGB below which base colour differences are relative to this (black pixels)
EXPOSURES = {"exposure_1_16": 1 / 16, "exposure_16": 16.0}
EXTENSIONS = (".hdr", ".exr", ".png", ".jpg", ".jpeg")
GEOMETRY_KEYS = ["nadir_up", "zenith_down", "floor_planarity", "camera_height", "consistency_deg",
                 "confidence", "flagged", "seconds"]
INVARIANCE_KEYS = ["yaw.depth", "yaw.albedo", "yaw.normal_deg", "exposure_1_16.depth", "exposure_1_16.albedo",
                   "exposure_16.depth", "exposure_16.albedo", "ldr.depth", "ldr.normal_deg", "res_half.depth",
                   "res_half.normal_deg", "res_double.depth", "res_double.normal_deg"]
LIGHT_METRICS = ["rel_l1", "si_rel_l1", "ratio", "colour_deg"]

Predictor = Callable[..., PanoScene]


# ---------------------------------------------------------------------------------------------
# plausibility, consistency, confidence


def _lat_deg(H: int, W: int) -> Tensor:
    return torch.rad2deg(pano.pixel_lonlat(H, W, dtype=torch.float64)[1])


def plausibility(scene: PanoScene) -> dict[str, float]:
    """``nadir_up``, ``zenith_down``, ``floor_planarity`` and ``camera_height`` (see the module doc)."""
    H, W = scene.size
    lat = _lat_deg(H, 1)[:, 0]  # the caps are whole rows: only those are read (a 360 camera's panorama
    nadir, zenith = lat < NADIR_LAT, lat > ZENITH_LAT  # in float64 is 400 MB a layer)
    cos_tol = math.cos(math.radians(UP_TOL_DEG))
    n_nadir = scene.normal[1, nadir].double()
    n_zenith = scene.normal[1, zenith].double()
    # the floor's points: y = depth * sin(latitude), as phyir.pano.depth_to_points gives it
    y = (scene.depth[0, nadir].double() * torch.sin(torch.deg2rad(lat[nadir]))[:, None]).flatten()
    height = float((-y).median())
    planarity = float((y + height).abs().median() / height) if height > 0 else math.nan
    return {"nadir_up": float((n_nadir > cos_tol).double().mean()),
            "zenith_down": float((n_zenith < -cos_tol).double().mean()),
            "floor_planarity": planarity, "camera_height": height}


def central_normals(depth: Tensor) -> Tensor:
    """Unit normals [3,H,W] of a radial depth [1,H,W] by central differences of the point map (wrapping
    in longitude, one-sided at the pole rows), facing the camera.  Unlike
    :func:`phyir.pano.normals_from_depth` nothing adapts to creases: this is the plain derivative."""
    p = pano.depth_to_points(depth.double())
    du = torch.roll(p, -1, -1) - torch.roll(p, 1, -1)
    H = p.shape[-2]
    i = torch.arange(H)
    dv = p[:, (i + 1).clamp(max=H - 1)] - p[:, (i - 1).clamp(min=0)]
    n = torch.cross(dv, du, dim=0)
    n = n / _norm0(n)
    return torch.where((n * p).sum(0, keepdim=True) > 0, -n, n)


def angle_deg(a: Tensor, b: Tensor) -> Tensor:
    """Per-pixel angle (degrees) between the vectors [3,...] of ``a`` and ``b`` (normalised first)."""
    a, b = a.double(), b.double()
    a, b = a / _norm0(a), b / _norm0(b)
    return torch.rad2deg(torch.acos((a * b).sum(0).clamp(-1, 1)))


def _norm0(x: Tensor) -> Tensor:
    # sqrt of a sum: torch's CPU vector_norm over the leading axis is ~20x slower (phyir.pano)
    return torch.sqrt((x * x).sum(0, keepdim=True)).clamp_min(1e-12)


def _measured(layer: Tensor) -> Tensor:
    """A layer ``[C,H,W]`` area-resized to at most :data:`CONSISTENCY_SIZE` (in float32: in float64 a
    360 camera's layer is 400 MB), as the geometry facts below read it."""
    return pano.resize_area(layer.float(), *CONSISTENCY_SIZE) if layer.shape[-2] > CONSISTENCY_SIZE[0] \
        else layer


def consistency_deg(scene: PanoScene) -> float:
    """Mean angle between the predicted normals and those of the predicted depth (module doc).

    Both are area-resized to at most :data:`CONSISTENCY_SIZE` first, so the number measures the
    geometry rather than the guided upsampling's pixel-scale texture, and is the same whatever the
    input's resolution (at 1k it reads ~4 degrees more on the same prediction)."""
    return _consistency(_measured(scene.depth), _measured(scene.normal))


def _consistency(depth: Tensor, normal: Tensor) -> float:
    H, W = depth.shape[-2:]
    band = _lat_deg(H, W).abs() < CONSISTENCY_LAT
    return float(angle_deg(normal.double(), central_normals(depth.double()))[band].mean())


def far_depth(scene: PanoScene) -> float:
    """The room's size: the :data:`FAR_QUANTILE` quantile of the depth over the panorama's pixels
    (area-resized to at most :data:`CONSISTENCY_SIZE` first, as :func:`consistency_deg`)."""
    return _far(_measured(scene.depth))


def _far(depth: Tensor) -> float:
    return float(torch.quantile(depth.float().flatten(), FAR_QUANTILE))


def scene_confidence(scene: PanoScene) -> dict[str, float | bool]:
    """How much to trust a predicted scene's geometry, from facts that need no ground truth.

    ``confidence = nadir_up / (1 + (consistency_deg / CONSISTENCY_SCALE_DEG)²) / (1 + (far_m /
    FAR_SCALE_M)²)``: a room whose floor below the camera isn't predicted as a floor is wrong whatever
    else holds; the more the normals disagree with the depth, the more at least one of them is wrong
    (good predictions read 5-15°: factor 0.8-0.97; normals collapsed to +y read 85-95°: ~0.1); and
    the larger the room (``far_m``, :func:`far_depth`), the larger the depth's relative error (the
    networks learnt from rooms, not halls: a 3 m room keeps 0.94, a 12 m hall half). Over 55 rooms
    with true depth (22 held-out halls, 30 held-out rooms, the 3 scans) the confidence's Spearman
    correlation with the median-aligned AbsRel is -0.61 (``python -m benchmarks.confidence_vs_error``;
    without the size factor -0.24, the size alone +0.54). The ceiling is left out: real ceilings
    (domes, skylights, lamps at the zenith) fail the test legitimately.
    Returns the :func:`plausibility` facts, ``consistency_deg``, ``far_m``, ``confidence`` and
    ``flagged`` (confidence < :data:`FLAG_BELOW`).
    """
    out: dict[str, float | bool] = dict(plausibility(scene))
    depth = _measured(scene.depth)  # read once by both facts
    c, far = _consistency(depth, _measured(scene.normal)), _far(depth)
    conf = float(out["nadir_up"]) / (1 + (c / CONSISTENCY_SCALE_DEG) ** 2) / (1 + (far / FAR_SCALE_M) ** 2)
    out |= {"consistency_deg": c, "far_m": far, "confidence": conf, "flagged": conf < FLAG_BELOW}
    return out


def flag_reason(confidence: dict[str, float | bool]) -> str:
    """Why :func:`scene_confidence`'s result is flagged, in a few words: a space beyond
    :data:`FAR_SCALE_M` (its depth may be well off) or implausible geometry."""
    far = float(confidence["far_m"])
    return f"a {far:.0f} m space, its depth may be well off" if far > FAR_SCALE_M else "implausible geometry"


# ---------------------------------------------------------------------------------------------
# invariances


def median_rel(a: Tensor, b: Tensor, floor: float = 1e-6) -> float:
    """Median over pixels of Σ_c|a−b| / max(Σ_c b, floor) (channels first)."""
    num = (a.double() - b.double()).abs().sum(0)
    return float((num / b.double().sum(0).clamp_min(floor)).median())


def median_angle(a: Tensor, b: Tensor) -> float:
    return float(angle_deg(a, b).median())


def yaw_back(scene: PanoScene, shift: int) -> PanoScene:
    """The prediction of an input rolled ``shift`` columns right, brought back to the input's frame:
    rolled back, normals rotated back about +y (:func:`phyir.transforms.rotate_yaw` by −shift)."""
    from phyir.transforms import rotate_yaw

    return rotate_yaw(scene.replace(probes=None), -shift)


def _compare(a: PanoScene, b: PanoScene, layers: tuple[str, ...], size: tuple[int, int] | None = None
             ) -> dict[str, float]:
    """Invariance errors of ``a`` against the reference ``b`` (area-resized to ``size`` first)."""
    def get(s: PanoScene, k: str) -> Tensor:
        t = getattr(s, k).double()
        return t if size is None else pano.resize_area(t, *size)

    out = {}
    for k in layers:
        if k == "normal":
            out["normal_deg"] = median_angle(get(a, k), get(b, k))
        else:
            out[k] = median_rel(get(a, k), get(b, k), ALBEDO_FLOOR if k == "albedo" else 1e-6)
    return out


def invariances(image: Tensor, ref: PanoScene, ldr_pred: PanoScene, is_hdr: bool,
                predict: Predictor) -> dict[str, float]:
    """Every invariance error of the module doc (``predict(image, **options)`` predicts)."""
    H, W = image.shape[-2:]
    shift = W // 4
    geo = ("depth", "normal", "albedo")
    out = {}
    rolled = predict(torch.roll(image, shift, -1), hdr=is_hdr, outputs=geo, probes=None)
    out |= _prefix("yaw", _compare(yaw_back(rolled, shift), ref, geo))
    for name, k in EXPOSURES.items():
        p = predict(image * k, hdr=is_hdr, outputs=("depth", "albedo"), probes=None)
        out |= _prefix(name, _compare(p, ref, ("depth", "albedo")))
    out |= _prefix("ldr", _compare(ldr_pred, ref, ("depth", "normal")))
    half = (H // 2, W // 2)
    for name, size in (("res_half", half), ("res_double", (2 * H, 2 * W))):
        p = predict(pano.resize_area(image, *size), hdr=is_hdr, outputs=("depth", "normal"), probes=None)
        out |= _prefix(name, _compare(p, ref, ("depth", "normal"), half))
    return out


def _prefix(p: str, d: dict[str, float]) -> dict[str, float]:
    return {f"{p}.{k}": v for k, v in d.items()}


# ---------------------------------------------------------------------------------------------
# a panorama, a folder


def panorama_files(paths: str | os.PathLike | list[str | os.PathLike]) -> list[Path]:
    """The panoramas named: files as given, folders expanded to their panoramas (:data:`EXTENSIONS`,
    sorted by name; hidden files, our writes' temporaries among them, are not panoramas)."""
    from phyir.io import folder_files

    items = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    out: list[Path] = []
    for p in items:
        out += [Path(f) for f in folder_files(p, tuple(EXTENSIONS))] if Path(p).is_dir() else [Path(p)]
    return out


def evaluate_panorama(path: str | os.PathLike, *, methods: dict[str, RL.LightMethod] | None = None,
                      **options) -> tuple[dict[str, float | bool], dict, dict[str, np.ndarray]]:
    """Geometry row, lighting rows (``{"hdr"|"ldr": {method: metrics}}``) and contact-sheet tiles of one
    panorama; ``options`` go to every :func:`phyir.predict` call (weights, device, lighting).
    ``seconds`` is the wall time of all of it, loading included."""
    from phyir.inference import load_input
    from phyir.inference import predict as phyir_predict

    t0 = time.perf_counter()
    scene, is_hdr = load_input(path)
    image = torch.nan_to_num(scene.image.float(), nan=0.0, posinf=0.0).clamp_min(0)

    def predict(x: Tensor, **kw) -> PanoScene:
        return phyir_predict(x, **(options | kw))

    ref = predict(image, hdr=is_hdr)
    ldr, scale = ldr_copy(image)
    ldr_pred = predict(ldr, hdr=False)
    row: dict[str, float | bool] = dict(scene_confidence(ref))
    row |= invariances(image, ref, ldr_pred, is_hdr, predict)
    light, spheres = RL.evaluate_lighting(image, ldr, scale, {"hdr": ref, "ldr": ldr_pred}, methods)
    row["seconds"] = time.perf_counter() - t0
    return row, light, sheet_tiles(image, ref, spheres)


def evaluate_real(folder: str | os.PathLike | list[str | os.PathLike], *,
                  log: Callable[[str], None] | None = None,
                  methods: dict[str, RL.LightMethod] | None = None, **options) -> tuple[dict, list]:
    """:func:`evaluate_panorama` on every panorama of ``folder`` (a folder, a file, or a list of
    them: :func:`panorama_files`).  Returns the results
    ``{"geometry": {name|"median": row}, "lighting": {"<name>/<hdr|ldr>"|"median/<hdr|ldr>": {key: v}}}``
    (lighting keys ``<method>.<material>.<metric>`` and ``<method>.peak_deg``) and the contact-sheet
    rows ``[(name, tiles)]``."""
    from phyir.errors import InputError

    files = panorama_files(folder)
    if not files:
        where = folder if isinstance(folder, (str, os.PathLike)) else ", ".join(map(str, folder))
        raise InputError(where, f"no panoramas ({', '.join(EXTENSIONS)})")
    geometry: dict[str, dict] = {}
    lighting: dict[str, dict[str, float]] = {}
    sheet = []
    for i, f in enumerate(files):
        row, light, tiles = evaluate_panorama(f, methods=methods, **options)
        geometry[f.stem] = row
        for inp, per_method in light.items():
            lighting[f"{f.stem}/{inp}"] = {f"{m}.{k}": v for m, r in per_method.items() for k, v in r.items()}
        sheet.append((f.stem, tiles))
        if log is not None:
            log(f"[{i + 1}/{len(files)}] {f.name}: {row['seconds']:.2f} s, confidence "
                f"{row['confidence']:.2f}{' (flagged)' if row['flagged'] else ''}")
    geometry["median"] = _median(list(geometry.values()))
    for inp in ("hdr", "ldr"):
        rows = [r for k, r in lighting.items() if k.endswith(f"/{inp}")]
        lighting[f"median/{inp}"] = _median(rows)
    return {"geometry": geometry, "lighting": lighting}, sheet


def _median(rows: list[dict]) -> dict[str, float]:
    """Per-key median of the numeric entries (``flagged`` becomes the share flagged)."""
    out: dict[str, float] = {}
    for k in rows[0]:
        vals = [float(r[k]) for r in rows if k in r and not math.isnan(float(r[k]))]
        if vals:
            out[k] = statistics.fmean(vals) if k == "flagged" else statistics.median(vals)
    return out


# ---------------------------------------------------------------------------------------------
# report


def markdown_real(results: dict) -> str:
    """The Markdown tables: geometry facts, invariances, then lighting per method (rows: panorama /
    input, then the medians)."""
    from phyir.evaluation.metrics import markdown_table as table

    def markdown_table(rows: dict, keys: list[str], digits: int) -> str:
        return table(rows, keys, digits=digits).replace("| method |", "| panorama |", 1)

    geo = {k: {c: float(v) for c, v in r.items()} for k, r in results["geometry"].items()}
    parts = ["**Geometry without ground truth** (shares in [0,1], planarity relative to the camera height, "
             "height in m, angles in degrees; median row: `flagged` is the share flagged)\n\n"
             + markdown_table(geo, GEOMETRY_KEYS, digits=3),
             "**Invariances** (median over pixels: relative difference for depth and base colour, degrees "
             "for normals)\n\n" + markdown_table(geo, INVARIANCE_KEYS, digits=3)]
    light = results["lighting"]
    methods = sorted({k.split(".")[0] for r in light.values() for k in r},
                     key=lambda m: (m == "naive", m))
    for m in methods:
        keys = [f"{mat}.{x}" for mat in RL.MATERIALS for x in LIGHT_METRICS] + ["peak_deg"]
        rows = {name: {k: r[f"{m}.{k}"] for k in keys if f"{m}.{k}" in r} for name, r in light.items()}
        short = {k: k.replace("matte_silver", "matte").replace("mirror_silver", "mirror")
                 .replace("diffuse", "diff") for k in keys}
        rows = {name: {short[k]: v for k, v in r.items()} for name, r in rows.items()}
        # the naive LDR environment is the light at the camera too
        where = "the light at the camera" if m in RL.AT_CAMERA | {"naive"} else "its light there"
        parts.append(f"**Lighting at {RL.SPHERE_CENTRE} m: {m}**, {where} (spheres vs the panorama as light; "
                     "rel L1, scale-invariant rel L1, intensity ratio, colour angle in degrees; "
                     "peak_deg: brightest direction)\n\n"
                     + markdown_table(rows, [short[k] for k in keys], digits=3))
    return "\n".join(parts)


# ---------------------------------------------------------------------------------------------
# contact sheet (numpy + Pillow)

TILE = (128, 256)  # panorama tiles of the contact sheet
SPHERE_TILE = 32  # the sphere images' own size: four rows fit a panorama tile
def _depth_colours(depth: Tensor) -> np.ndarray:
    """Log depth between its 2nd and 98th percentiles through :data:`phyir.sheets.DEPTH_RAMP`."""
    d = np.log(np.maximum(depth[0].numpy(), 1e-3))
    lo, hi = np.percentile(d, (2, 98))
    return ramp_colours((d - lo) / max(hi - lo, 1e-6))


def sheet_tiles(image: Tensor, scene: PanoScene, spheres: dict[str, Tensor]) -> dict[str, np.ndarray]:
    """The contact sheet's tiles of one panorama: input, depth, normals, base colour (uint8 [h,w,3]
    at :data:`TILE`) and the spheres (rows: truth then each method; columns: the materials), shown
    with the input's display exposure."""
    from PIL import Image

    from phyir.color import exposure_scale, to_srgb8

    s = float(exposure_scale(image))
    small = {k: pano.resize_area(getattr(scene, k).float(), *TILE) for k in ("depth", "normal", "albedo")}
    tiles = {"input": to_srgb8(pano.resize_area(image, *TILE), s), "depth": _depth_colours(small["depth"])}
    n = small["normal"] / _norm0(small["normal"])
    tiles["normals"] = ((n.permute(1, 2, 0).numpy() * 0.5 + 0.5) * 255 + 0.5).clip(0, 255).astype(np.uint8)
    tiles["albedo"] = (linear_to_srgb(small["albedo"].permute(1, 2, 0).numpy()) * 255 + 0.5).astype(np.uint8)
    who = ["truth"] + sorted({k.split("/")[0] for k in spheres} - {"truth"})
    block = np.zeros((SPHERE_TILE * len(who), SPHERE_TILE * len(RL.MATERIALS), 3), np.uint8)
    for r, w in enumerate(who):
        for c, mat in enumerate(RL.MATERIALS):
            if f"{w}/{mat}" in spheres:
                img = Image.fromarray(to_srgb8(spheres[f"{w}/{mat}"].float(), s))
                if img.size != (SPHERE_TILE, SPHERE_TILE):
                    img = img.resize((SPHERE_TILE, SPHERE_TILE), Image.BILINEAR)
                block[r * SPHERE_TILE:(r + 1) * SPHERE_TILE, c * SPHERE_TILE:(c + 1) * SPHERE_TILE] = img
    tiles["spheres"] = block
    tiles["sphere_rows"] = np.array(who)
    return tiles


SHEET_COLUMNS = ("input", "depth", "normals", "albedo", "spheres")


def save_contact_sheet(rows: list[tuple[str, dict[str, np.ndarray]]], path: str | os.PathLike) -> None:
    """One row per room: input, depth, normals, base colour and the spheres (truth vs ours), a legend
    under them."""
    from phyir.sheets import SheetStyle, save_sheet

    who = ", ".join(str(w) for w in rows[0][1]["sphere_rows"])
    legend = (f"spheres at {RL.SPHERE_CENTRE} m: rows {who}; columns {', '.join(RL.MATERIALS)}; the "
              "input's display exposure")
    save_sheet(path, [(name, [tiles[k] for k in SHEET_COLUMNS]) for name, tiles in rows], SHEET_COLUMNS,
               legend, SheetStyle(legend_height=28, legend_offset=(0, 2)))
