"""Inference: any panorama (file, tensor or scene) -> a complete :class:`PanoScene` at the input's size.

``predict(source)`` runs the networks at their own resolution on the exposure-normalised image,
brings every layer back to the input's resolution by guided upsampling (edges follow the image) and
returns probes in the input's radiometric units:

1. the geometry network (``geometry``, default GMNet: depth, normals, materials) and GSNet (refined
   base colour / roughness) run only when a wanted layer is missing from the input, or when LNet needs
   the geometry layers as its inputs;
2. LNet predicts a probe grid;
3. the lighting method (``lighting``) makes the probes from LNet's and, for the methods that project,
   the panorama re-read where the camera saw the surface a probe's texels look at
   (:mod:`phyir.lighting.projection`).  Geometry networks and lighting methods are chosen by name from
   :mod:`phyir.estimators`' registries (``phyir predict --help`` lists them); the default lighting,
   :data:`DEFAULT_LIGHTING`, measured best on the synthetic split and the real panoramas.

Layers the input already carries are used, never recomputed; ``outputs`` asks for a subset.  What
ran, what was reused and how long each stage took are recorded in ``scene.meta`` (keys ``predict.*``).
"""

from __future__ import annotations

import functools
import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.errors import InputError, PhyIRError
from phyir.estimators import (  # DEFAULT_LIGHTING and DEFAULT_GEOMETRY are re-exported here
    DEFAULT_GEOMETRY,
    DEFAULT_LIGHTING,
    GeometryNetwork,
    LightingMethod,
    geometry_networks,
    lighting_methods,
)
from phyir.filters import guided_upsample
from phyir.geometry.depth_normal import upsample_depth
from phyir.geometry.plausible import away_share, collapsed, consistent_depth, depth_normals, plausible_gmnet
from phyir.scene import PanoScene

OUTPUTS = ("depth", "normal", "albedo", "roughness", "metallic", "probes")
GM_LAYERS = ("depth", "normal", "albedo", "roughness", "metallic")
DEFAULT_NET_SIZE = (256, 512)  # when the weights don't record their training resolution
# every layer comes back at the input's size: ~140 bytes per input pixel at the peak
# (docs/robustness.md), so 4096x8192 needs ~5 GB; larger inputs are refused
MAX_PREDICT_SIZE = (4096, 8192)
MIN_NET_INPUT = (16, 32)  # smaller panoramas hold too little for the networks
# the networks' resolution (--net-size, net_size=, a weights sidecar's resolution): H a multiple of
# 32, W = 2H, at most this.  Peak memory of predict on an input of the net's size (lite model, CPU,
# docs/robustness.md): 787 MB at 512x1024, 1785 MB at 1024x2048; 4096x8192 took 4.6 GB and failed
MAX_NET_SIZE = (512, 1024)
GUIDE_RADIUS = 2  # guided upsampling window (net-resolution pixels)
GUIDE_EPS = 1e-3  # guided upsampling regulariser (guide = log(1 + normalised luminance))
# depth follows the image's edges only at occlusions (phyir.geometry.depth_normal.upsample_depth: steps
# further than this in log depth from the normals'); inside surfaces the regulariser is this large, so
# wall texture doesn't print into the depth (it would tilt the depth's normals off the normal layer's)
OCCLUSION_TAU = 0.02
SURFACE_EPS = 1e3


class Cancelled(PhyIRError):
    """Raised when ``cancel`` asks predict to stop."""


# ---------------------------------------------------------------------------------------------
# model loading (cached)

_MODELS: dict[tuple, tuple] = {}
_MODELS_LOCK = threading.Lock()


def load_cached_model(weights: str | os.PathLike | None = None, device: str | torch.device = "cpu"):
    """``(model, net_size)`` for a weights file (default: the shipped ones), cached per file and device.

    ``net_size`` is the resolution the weights were trained at (their sidecar's ``data.resolution``),
    or :data:`DEFAULT_NET_SIZE`.
    """
    from phyir.learn.weights import default_weights_path, load_model, sidecar_path

    path = Path(weights) if weights is not None else default_weights_path()
    if weights is None and not path.exists():
        raise InputError(path, "the shipped weights are missing; pass weights=... (--weights)")
    try:
        key = (str(path.resolve()), path.stat().st_mtime_ns, str(torch.device(device)))
    except OSError:
        key = None
    with _MODELS_LOCK:
        if key is not None and key in _MODELS:
            return _MODELS[key]
    model = load_model(path, device)
    net_size = DEFAULT_NET_SIZE
    side = sidecar_path(path)
    if side.is_file():
        try:
            res = json.loads(side.read_text())["data"]["resolution"]
            net_size = check_net_size(tuple(int(x) for x in str(res).split("x")), "data.resolution")
        except KeyError:
            pass  # no recorded resolution: the default
        except (TypeError, ValueError, RecursionError) as e:  # (json.JSONDecodeError is a ValueError)
            import warnings

            warnings.warn(f"{side}: unreadable weights sidecar ({e}); assuming the network size "
                          f"{net_size[0]}x{net_size[1]}", UserWarning, stacklevel=2)
    with _MODELS_LOCK:
        if key is not None:
            _MODELS[key] = (model, net_size)
    return model, net_size


# ---------------------------------------------------------------------------------------------
# helpers


def _check_cancel(cancel) -> None:
    if cancel is None:
        return
    stop = cancel.is_set() if hasattr(cancel, "is_set") else cancel()
    if stop:
        raise Cancelled("prediction cancelled")


def load_input(source: str | os.PathLike | Tensor | PanoScene, hdr: bool | None = None,
               limit: Callable[[str, int, int], None] | None = None) -> tuple[PanoScene, bool]:
    """(scene, is_hdr) of a file path, an image tensor [3,H,W] or a scene.  Files: HDR for OpenEXR and
    Radiance .hdr, LDR (sRGB-decoded to linear by the loader) for PNG/JPEG, unless ``hdr`` says.
    ``limit(path, H, W)`` is checked on a file's header before it is decoded."""
    from phyir import io

    if isinstance(source, (str, os.PathLike)):
        scene, fmt = io.read_scene(source, limit=limit)
        scene.meta.setdefault("source", Path(source).name)
        scene.meta.setdefault("source_format", fmt)  # a JPEG's clipped light takes its own law
        return scene, (fmt in ("exr", "hdr")) if hdr is None else hdr
    if isinstance(source, PanoScene):
        scene = source
    elif isinstance(source, Tensor):
        if source.dim() != 3 or source.shape[0] != 3:
            raise InputError(None, f"expected an image tensor [3,H,W], got {list(source.shape)}")
        scene = PanoScene(image=source)
    else:
        raise TypeError(f"predict: expected a path, a tensor or a PanoScene, got {type(source).__name__}")
    if scene.batched:
        raise InputError(None, "expected one panorama, got a batch (predict each scene)")
    io.check_panorama_size(None, *scene.size, min_size=MIN_NET_INPUT)
    return scene, True if hdr is None else hdr


def check_predict_size(path: str | os.PathLike | None, H: int, W: int) -> None:
    """Refuse panoramas whose full-resolution layers would not fit in memory (:data:`MAX_PREDICT_SIZE`)."""
    Hm, Wm = MAX_PREDICT_SIZE
    if H * W > Hm * Wm:
        raise InputError(path, f"{H}x{W} is too large to predict at full resolution (at most {Hm}x{Wm}, "
                               "which needs ~5 GB of memory); resize the panorama first")


def check_net_size(size, what: str | os.PathLike | None = "net_size") -> tuple[int, int]:
    """``size`` (H, W) as the networks can run it: H a multiple of 32 from 32 to
    :data:`MAX_NET_SIZE`, W = 2H; else a one-line InputError naming ``what``."""
    try:
        H, W = (int(x) for x in size)
    except (TypeError, ValueError):
        raise InputError(what, f"expected a network size (H, W), got {size!r}") from None
    Hm, Wm = MAX_NET_SIZE
    if not (32 <= H <= Hm and H % 32 == 0 and W == 2 * H):
        raise InputError(what, f"network size {H}x{W} is not possible: need H a multiple of 32 from 32 "
                               f"to {Hm} and W = 2H (at most {Hm}x{Wm})")
    return H, W


def net_size_for(H: int, default: tuple[int, int]) -> tuple[int, int]:
    """The network's resolution: ``default``, or the input's rounded up to a multiple of 32 when that
    is smaller (never upsample a small input more than needed)."""
    Hn = min(default[0], max(32, 32 * math.ceil(H / 32)))
    return Hn, 2 * Hn


def _guide(image: Tensor) -> Tensor:
    from phyir.color import luminance

    return torch.log1p(luminance(image.clamp_min(0)))[None]


def _upsample_layer(name: str, lo: Tensor, guide_lo: Tensor, guide_hi: Tensor,
                    normal_lo: Tensor | None = None) -> Tensor:
    """One layer ``lo [C,h,w]`` at the guide's full size; depth uses the normals at its resolution,
    when there are some, to find its occlusion edges."""
    if name == "depth":
        return upsample_depth(lo, guide_lo, guide_hi, normal=normal_lo, r=GUIDE_RADIUS, eps=GUIDE_EPS,
                              tau=OCCLUSION_TAU, surface_eps=SURFACE_EPS)
    out = guided_upsample(lo, guide_lo, guide_hi, GUIDE_RADIUS, GUIDE_EPS)
    if name == "normal":
        return out / torch.sqrt((out * out).sum(0, keepdim=True)).clamp_min(1e-8)
    return out.clamp(0, 1)


def lnet_probes_at(grid_probes: Tensor, points: Tensor) -> Tensor:
    """LNet's probe for 3D points [N,3]: bilinear in the probe grid [Hp,Wp,3,h,w] at the panorama
    position each point is seen at (probe (a, b) sits at the centre of block (a, b))."""
    Hp, Wp = grid_probes.shape[:2]
    u, v = pano.dir_to_uv(points.to(grid_probes), Hp, Wp, dim=-1)
    idx, wgt = pano.bilinear_taps(u, v, Hp, Wp)
    flat = grid_probes.reshape(Hp * Wp, -1)
    out = (flat[idx] * wgt[..., None]).sum(-2)
    return out.view(len(points), *grid_probes.shape[2:])


# ---------------------------------------------------------------------------------------------
# predict: options -> load -> plan -> networks -> upsampling -> lighting


@dataclass(frozen=True)
class PredictOptions:
    """Everything :func:`predict` can be told (see its docstring for each field's meaning)."""

    weights: str | os.PathLike | None = None
    device: str | torch.device | None = None
    outputs: Iterable[str] | None = None
    probes: str | None = "grid"
    points: Tensor | None = None
    lighting: str | None = None
    geometry: str | None = None
    net_size: tuple[int, int] | None = None
    hdr: bool | None = None
    model: Any = None
    amp: bool = True
    recover_hdr: bool = True  # LDR inputs: give clipped lamps and windows their energy back (image layer)
    refine_depth: bool = True  # the network's depth made to follow its normals (False: the raw depth)
    progress: Callable[[str, float], None] | None = None
    cancel: Callable[[], bool] | threading.Event | None = None

    def wanted(self) -> set[str]:
        """The validated set of layers to return; raises :class:`PhyIRError` on a bad option."""
        want = set(OUTPUTS if self.outputs is None else self.outputs)
        unknown = want - set(OUTPUTS)
        if unknown:
            raise PhyIRError(f"unknown outputs {sorted(unknown)} (choose from {', '.join(OUTPUTS)})")
        if self.probes not in ("grid", "points", None):
            raise PhyIRError(f"probes must be 'grid', 'points' or None, got {self.probes!r}")
        if self.probes is None:
            want.discard("probes")
        if self.probes == "points" and self.points is None:
            raise PhyIRError("probes='points' needs points=[N,3]")
        self.lighting_method()
        self.geometry_network()
        return want

    def lighting_method(self) -> LightingMethod:
        """The registered lighting method named by ``lighting`` (default :data:`DEFAULT_LIGHTING`)."""
        return lighting_methods().get(self.lighting or DEFAULT_LIGHTING)

    def geometry_network(self) -> GeometryNetwork:
        """The registered geometry network named by ``geometry`` (default :data:`DEFAULT_GEOMETRY`)."""
        return geometry_networks().get(self.geometry or DEFAULT_GEOMETRY)


@dataclass
class PredictReport:
    """What one :func:`predict` call did, as values (``scene.meta`` holds the same as header strings)."""

    seconds: dict[str, float] = field(default_factory=dict)  # per stage, and "total"
    computed: list[str] = field(default_factory=list)  # layers (and "probes") the model produced
    reused: list[str] = field(default_factory=list)  # layers taken from the input
    lighting: str = ""  # the lighting method, when probes were computed
    geometry: str = ""  # the geometry network, when it ran
    net_size: tuple[int, int] | None = None  # network resolution, when the networks ran
    exposure_scale: float | None = None  # factor the networks' input was normalised by
    gm_pass: str = ""  # "upright", or "mirrored": GMNet's pass on the input mirrored through the horizon
    hdr_recovery: Any = None  # LDR inputs: phyir.lighting.hdr_recovery.Recovery of the image layer
    normals_from: str = ""  # "network", or "depth" when the network's normals were implausible
    normals_away: float | None = None  # share of the network's normals facing away from the camera
    depth_refined: bool = False  # the depth was made consistent with the network's normals
    floor_height: float | None = None  # m (network units): the floor under the camera was levelled


class _Clock:
    """Stage timings, progress callbacks and cancellation checks between stages."""

    def __init__(self, opts: PredictOptions, report: PredictReport):
        self.opts, self.report = opts, report
        self.start = self.last = time.perf_counter()
        _check_cancel(opts.cancel)

    def step(self, name: str, frac: float) -> None:
        self.report.seconds[name] = round(time.perf_counter() - self.last, 4)
        if self.opts.progress is not None:
            self.opts.progress(name, frac)
        _check_cancel(self.opts.cancel)
        self.last = time.perf_counter()


@dataclass(frozen=True)
class _Plan:
    """Which layers are wanted, given, missing, and which networks must run."""

    want: set[str]
    have: set[str]
    have_probes: bool
    need_probes: bool
    missing: set[str]
    gm_inputs: set[str]  # GMNet layers the later networks read (LNet reads all five)
    run_gm: bool
    lighting: LightingMethod
    geometry: GeometryNetwork

    @staticmethod
    def of(scene: PanoScene, opts: PredictOptions, want: set[str]) -> _Plan:
        have = {k for k in GM_LAYERS if getattr(scene, k) is not None}
        have_probes = scene.probes is not None and opts.probes == "grid"
        need_probes = "probes" in want and not have_probes
        missing = {k for k in GM_LAYERS if k in want and k not in have}
        gm_inputs = set(GM_LAYERS) if need_probes else missing
        return _Plan(want, have, have_probes, need_probes, missing, gm_inputs, bool(gm_inputs - have),
                     opts.lighting_method(), opts.geometry_network())


@dataclass
class _NetOut:
    """The networks' results at their resolution, and what upsampling and lighting need."""

    gm: dict[str, Tensor]
    refined: dict[str, Tensor]
    lnet_grid: Tensor | None
    image: Tensor  # the input, finite and >= 0, on the device
    xn: Tensor  # the exposure-normalised network input [1,3,Hn,Wn]
    scale: float  # exposure normalisation factor
    net_size: tuple[int, int]


def _model_and_device(opts: PredictOptions) -> tuple[Any, torch.device, tuple[int, int]]:
    if opts.model is None:
        dev = torch.device(opts.device) if opts.device is not None else \
            torch.device("cuda" if torch.cuda.is_available() else "cpu")
        model, trained = load_cached_model(opts.weights, dev)
        return model, dev, trained
    dev = next(opts.model.parameters()).device if opts.device is None else torch.device(opts.device)
    return opts.model.to(dev).eval(), dev, DEFAULT_NET_SIZE


def _run_networks(scene: PanoScene, is_hdr: bool, plan: _Plan, opts: PredictOptions,
                  clock: _Clock) -> _NetOut:
    from phyir.color import clean_radiance, exposure_scale

    model, dev, trained = _model_and_device(opts)
    geometry = plan.geometry.load(model, dev) if plan.run_gm else None
    clock.step("model", 0.1)
    Hn, Wn = check_net_size(opts.net_size) if opts.net_size else net_size_for(scene.size[0], trained)
    img = clean_radiance(scene.image)
    x = pano.resize_area(img, Hn, Wn).to(dev)
    s = float(exposure_scale(x)) if is_hdr else 1.0
    xn = (x * s)[None]
    autocast = torch.autocast("cuda", dtype=torch.float16) if opts.amp and dev.type == "cuda" \
        else nullcontext()
    gm: dict[str, Tensor] = {}
    refined: dict[str, Tensor] = {}
    lnet_grid = None
    with torch.inference_mode(), autocast:
        if plan.run_gm:
            gm, clock.report.gm_pass = plausible_gmnet(geometry, xn)
            clock.report.geometry = plan.geometry.name
            if opts.refine_depth:
                _consistent_depth(gm, plan, clock.report)
            clock.step("gmnet", 0.35)
        for k in plan.have & plan.gm_inputs:  # the input's own layers, at the network's resolution
            v = pano.resize_area(getattr(scene, k).float(), Hn, Wn).to(dev)[None]
            gm[k] = F.normalize(v, dim=1) if k == "normal" else v
        if plan.missing & set(model.gsnet.targets):
            refined = {k: v.float() for k, v in model.gsnet(xn, gm).items()}
            clock.step("gsnet", 0.45)
        if plan.need_probes:
            lnet_grid = model.light(xn, gm, model.default_grid(Hn, Wn))[0].float() / s
            clock.step("lnet", 0.6)
    return _NetOut(gm, refined, lnet_grid, img.to(dev), xn, s, (Hn, Wn))


def _consistent_depth(gm: dict[str, Tensor], plan: _Plan, report: PredictReport) -> None:
    """:func:`phyir.geometry.plausible.consistent_depth` on GMNet's layers, only where the depth is
    predicted, not the input's."""
    if "depth" not in gm or "normal" not in gm or plan.have & {"depth", "normal"}:
        return
    depth, normal, report.floor_height = consistent_depth(gm["depth"], gm["normal"])
    gm["depth"] = depth.to(gm["depth"].dtype)
    if normal is not None:
        gm["normal"] = normal.to(gm["normal"].dtype)
    report.depth_refined = True


def _upsample_layers(scene: PanoScene, out: PanoScene, net: _NetOut, plan: _Plan,
                     report: PredictReport) -> dict[str, Tensor]:
    """Missing layers at the input's size into ``out``; returns the geometry that only projection
    lighting needs (depth, normals that are not outputs)."""
    H, W = scene.size
    guide_lo = _guide(net.xn[0].float())
    guide_hi = _guide(net.image * net.scale)
    projection = plan.need_probes and plan.lighting.projects
    geo_only = {"depth", "normal"} - plan.have - plan.want if projection else set()
    geo: dict[str, Tensor] = {}
    keys = sorted(plan.missing | geo_only, key=GM_LAYERS.index)
    surface = _surface_normals(net) if {"depth", "normal"} & set(keys) else None
    for k in keys:
        lo = net.refined.get(k, net.gm[k])[0]
        if k == "normal" and surface is not None:
            lo, report.normals_away = surface
            report.normals_from = "depth" if collapsed(report.normals_away) else "network"
        normal_lo = surface[0] if k == "depth" and surface is not None else None
        up = _upsample_layer(k, lo, guide_lo, guide_hi, normal_lo) if net.net_size != (H, W) else lo
        if k in plan.missing:
            setattr(out, k, up.float().cpu())
            report.computed.append(k)
        else:
            geo[k] = up.float().cpu()
    return geo


def _surface_normals(net: _NetOut) -> tuple[Tensor, float] | None:
    """The normals [3,h,w] that describe GMNet's depth and the share of the normal layer facing away
    from the camera: the layer itself, or, where it has collapsed
    (:func:`phyir.geometry.plausible.collapsed`, judged at the network's resolution), the normals of
    the predicted depth; None without a normal layer."""
    if "normal" not in net.gm:
        return None
    normal = net.refined.get("normal", net.gm["normal"])[0].float()
    away = away_share(normal)
    return (depth_normals(net.gm["depth"][0].float()) if collapsed(away) else normal), away


def _probes(out: PanoScene, net: _NetOut, geo: dict[str, Tensor], plan: _Plan,
            opts: PredictOptions) -> Tensor:
    """The probes to return: a grid [Hp,Wp,3,h,w] or, for ``probes="points"``, [N,1,3,h,w]."""
    assert net.lnet_grid is not None
    lnet_grid = net.lnet_grid.cpu()
    pts = None if opts.probes == "grid" else opts.points.reshape(-1, 3).float().cpu()
    lnet = lnet_grid if pts is None else lnet_probes_at(lnet_grid, pts)
    method = plan.lighting

    @functools.cache
    def reread() -> Tensor:
        """The panorama re-read from each probe along the predicted depth, LNet's probe where unseen
        (DepthSurface works in exposure-normalised units itself)."""
        from phyir.lighting.projection import project_probes, projected_probe_grid

        proj_scene = PanoScene(image=net.image.cpu(), depth=geo.get("depth", out.depth),
                               normal=geo.get("normal", out.normal))
        if pts is None:
            return projected_probe_grid(proj_scene, lnet_grid)
        return project_probes(proj_scene, pts, tuple(lnet.shape[-2:]), lnet)[0]

    def projected() -> Tensor:
        if not method.projects:
            raise PhyIRError(f"lighting method {method.name!r} reads the projected probes: register it "
                             "with projects=True")
        return reread()

    probes = method.estimate(lnet, projected)
    return probes if pts is None else probes[:, None]


def _recover_hdr(out: PanoScene, report: PredictReport) -> None:
    """An LDR input's clipped regions given their light back: by ClipNet where its weights are
    shipped (:mod:`phyir.lighting.ldr_to_hdr`), else by the region model fitted on real HDR
    panoramas (:mod:`phyir.lighting.clip_regions`; a JPEG file's by the law for JPEG input), or the
    calibrated gain per region where its file is missing (:mod:`phyir.lighting.hdr_recovery`)."""
    from phyir.lighting.hdr_recovery import Recovery, clipped_regions, recover_clipped
    from phyir.lighting.ldr_to_hdr import load_clipnet, recover

    model = load_clipnet()
    if model is not None:
        _, _, regions = clipped_regions(out.image.float())
        image, sr, gain = recover(out.image, model)
        rec = Recovery(regions, sr, gain, "clipnet")
    else:
        jpeg = out.meta.get("source_format") == "jpeg"
        image, rec = recover_clipped(out.image, model="shipped-jpeg" if jpeg else "shipped")
    if rec.regions:
        out.image = image
        report.hdr_recovery = rec


def _write_meta(out: PanoScene, report: PredictReport, weights: str | os.PathLike | None) -> None:
    """The report as the scene's header strings (they travel into the saved EXR)."""
    if report.net_size is not None:
        out.meta["exposure_scale"] = f"{report.exposure_scale:.6g}"
        out.meta["predict.net_size"] = f"{report.net_size[0]}x{report.net_size[1]}"
        if weights is not None:
            out.meta["predict.weights"] = Path(weights).name
    out.meta["predict.computed"] = " ".join(report.computed)
    out.meta["predict.reused"] = " ".join(report.reused)
    out.meta["predict.lighting"] = report.lighting
    if report.geometry and report.geometry != DEFAULT_GEOMETRY:  # (absent: the default network)
        out.meta["predict.geometry"] = report.geometry
    if report.gm_pass:
        out.meta["predict.gm_pass"] = report.gm_pass
    if report.hdr_recovery is not None:
        rec = report.hdr_recovery
        out.meta["predict.hdr_recovery"] = (f"{rec.method}: {rec.regions} clipped regions "
                                            f"({rec.solid_angle:.3g} sr) brightened; "
                                            f"energy x{rec.energy_gain:.3g}")
    if report.normals_from:
        out.meta["predict.normals"] = report.normals_from
        out.meta["predict.normals_away"] = f"{report.normals_away:.4f}"
    if report.depth_refined:
        out.meta["predict.depth"] = "refined by the normals"
    if report.floor_height is not None:
        out.meta["predict.floor_height"] = f"{report.floor_height:.4g}"
    out.meta["predict.seconds"] = json.dumps(report.seconds)


def predict(source: str | os.PathLike | Tensor | PanoScene, options: PredictOptions | None = None,
            **kwargs) -> PanoScene:
    """Predict every missing layer of a panorama; returns an unbatched scene at the input's size, on
    the CPU.  Options are a :class:`PredictOptions` or its fields as keywords:

    ``source``: a file (anything :func:`phyir.io.load_scene` reads: HDR or LDR, any 2:1 size, scene
    files with some layers), an image tensor [3,H,W] (HDR unless ``hdr=False``) or a PanoScene.
    ``weights``: a weights file (default: the shipped ones); or pass a loaded ``model``
    (:class:`phyir.nets.PhyIRModel`).  ``device``: default CUDA when available; on CUDA the networks
    run in float16 autocast (``amp``), the rest in float32.
    ``outputs``: the layers wanted (default all of :data:`OUTPUTS`); others are neither computed
    nor returned unless the input had them.
    ``probes``: ``"grid"`` (LNet's grid, at the network's probe grid), ``"points"`` (probes at the 3D
    ``points [N,3]`` only, returned as ``scene.probes [N,1,3,h,w]`` with ``meta["probe_layout"] =
    "points"``) or None (no probes).
    ``lighting``: how the probes are made, the name of a method in
    :func:`phyir.estimators.lighting_methods` (default :data:`DEFAULT_LIGHTING`); ``geometry``: the
    network predicting depth, normals and materials, a name in
    :func:`phyir.estimators.geometry_networks` (default :data:`DEFAULT_GEOMETRY`).
    ``net_size``: network resolution (H, W) (default: the weights' training resolution, at most the
    input's).  ``refine_depth``: pull near-level and near-plumb normals onto gravity's directions and
    make the predicted depth follow them — the network's normals where plausible, else the depth's own
    (default True; False gives GMNet's raw depth and normals).  ``progress(stage, fraction)`` is called
    between stages; ``cancel`` (a callable or an Event) is checked between stages and raises
    :class:`Cancelled`.
    """
    return predict_with_report(source, options, **kwargs)[0]


def predict_with_report(source: str | os.PathLike | Tensor | PanoScene, options: PredictOptions | None = None,
                        **kwargs) -> tuple[PanoScene, PredictReport]:
    """:func:`predict` and its :class:`PredictReport` (stage times, computed and reused layers)."""
    opts = replace(options or PredictOptions(), **kwargs)
    report = PredictReport()
    clock = _Clock(opts, report)
    scene, is_hdr = load_input(source, opts.hdr, limit=check_predict_size)  # checked before decoding
    check_predict_size(None, *scene.size)
    plan = _Plan.of(scene, opts, opts.wanted())
    clock.step("load", 0.05)
    out = scene.map(lambda x: x)  # shallow copy
    out.meta = dict(scene.meta)
    if plan.run_gm or plan.need_probes:
        net = _run_networks(scene, is_hdr, plan, opts, clock)
        geo = _upsample_layers(scene, out, net, plan, report)
        clock.step("upsample", 0.7)
        report.net_size, report.exposure_scale = net.net_size, net.scale
    if not is_hdr and opts.recover_hdr:
        _recover_hdr(out, report)
        if plan.run_gm or plan.need_probes:
            net.image = out.image.to(net.image.device)  # projection reads the recovered light
    for k in GM_LAYERS:  # keep only what was asked for or given
        if k not in plan.want and k not in plan.have:
            setattr(out, k, None)
    if plan.need_probes:
        out.probes = _probes(out, net, geo, plan, opts)
        if opts.probes == "points":
            out.meta["probe_layout"] = "points"
        report.computed.append("probes")
        clock.step("probes", 0.95)
    elif not plan.have_probes:
        out.probes = None
    report.seconds["total"] = round(time.perf_counter() - clock.start, 4)
    report.reused = [k for k in (*GM_LAYERS, "probes")
                     if k in plan.have or (k == "probes" and plan.have_probes)]
    report.lighting = plan.lighting.name if "probes" in report.computed else ""
    _write_meta(out, report, opts.weights)
    if opts.progress is not None:
        opts.progress("done", 1.0)
    return out, report


def predict_many(sources: Sequence[str | os.PathLike], **kwargs) -> list[PanoScene]:
    """:func:`predict` for several inputs with the same settings (the model is loaded once)."""
    return [predict(s, **kwargs) for s in sources]
