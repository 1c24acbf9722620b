"""Inference: any panorama (file, tensor or scene) -> a complete :class:`PanoScene` at the input's size.

``predict(source)`` runs the networks at their own resolution on the exposure-normalised image,
brings every layer back to the input's resolution by guided upsampling (edges follow the image) and
returns probes in the input's radiometric units:

1. GMNet (depth, normals, materials) and GSNet (refined base colour / roughness) run only when a
   wanted layer is missing from the input, or when LNet needs GMNet's layers as its inputs;
2. LNet predicts a probe grid;
3. with ``lighting="projection"`` each probe is re-read from the panorama itself where the camera saw
   the surface its texels look at (:mod:`phyir.lighting.projection`), LNet's probe filling in the rest.
   The default (:data:`DEFAULT_LIGHTING`) is LNet alone: with the shipped weights it measured better
   on the synthetic test split (README, "The model").

Layers the input already carries are used, never recomputed; ``outputs`` asks for a subset.  What
ran, what was reused and how long each stage took are recorded in ``scene.meta`` (keys ``predict.*``).
"""

from __future__ import annotations

import json
import math
import os
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from contextlib import nullcontext
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import Tensor

from phyir import pano
from phyir.errors import InputError, PhyIRError
from phyir.scene import PanoScene

OUTPUTS = ("depth", "normal", "albedo", "roughness", "metallic", "probes")
GM_LAYERS = ("depth", "normal", "albedo", "roughness", "metallic")
LIGHTING = ("projection", "lnet")
# `phyir eval --data <s128v2> --split test` (37 scenes), shipped lite weights: probe log-MSE lnet 0.0602
# vs projection 0.0623, relighting lnet better for all three spheres; projection wins only from
# ground-truth depth (0.0303), so the predicted depth's error is what holds it back
DEFAULT_LIGHTING = "lnet"
DEFAULT_NET_SIZE = (256, 512)  # when the weights don't record their training resolution
# every layer comes back at the input's size: ~140 bytes per input pixel at the peak
# (docs/robustness.md), so 4096x8192 needs ~5 GB; larger inputs are refused
MAX_PREDICT_SIZE = (4096, 8192)
GUIDE_RADIUS = 2  # guided upsampling window (net-resolution pixels)
GUIDE_EPS = 1e-3  # guided upsampling regulariser (guide = log(1 + normalised luminance))


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
            net_size = tuple(int(x) for x in str(res).split("x"))  # type: ignore[assignment]
        except KeyError:
            pass  # no recorded resolution: the default
        except (TypeError, ValueError) as e:  # (json.JSONDecodeError is a ValueError)
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


def load_input(source: str | os.PathLike | Tensor | PanoScene,
               hdr: bool | None = None) -> tuple[PanoScene, bool]:
    """(scene, is_hdr) of a file path, an image tensor [3,H,W] or a scene.  Files: HDR for OpenEXR and
    Radiance .hdr, LDR (sRGB-decoded to linear by the loader) for PNG/JPEG, unless ``hdr`` says."""
    from phyir import io

    if isinstance(source, (str, os.PathLike)):
        fmt = io.sniff(source)
        scene = io.load_scene(source)
        scene.meta.setdefault("source", Path(source).name)
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
    H, W = scene.size
    if H < 16 or abs(W / H - 2) > 0.02:
        raise InputError(None, f"expected an equirectangular panorama (W = 2H), got {H}x{W}")
    return scene, True if hdr is None else hdr


def _header_size(path: str | os.PathLike) -> tuple[int, int]:
    """(H, W) of an image or scene file from its header (the main part's, for OpenEXR)."""
    from phyir import io
    from phyir.io import exr, ldr, rgbe

    fmt = io.sniff(path)
    if fmt == "exr":
        headers = exr.read_headers(path)
        h = next((h for h in headers if h.name == "scene"), headers[0])
    else:
        h = rgbe.read_header(path) if fmt == "hdr" else ldr.read_info(path)
    return h.height, h.width


def _check_predict_size(path: str | os.PathLike | None, H: int, W: int) -> None:
    Hm, Wm = MAX_PREDICT_SIZE
    if H * W > Hm * Wm:
        raise InputError(path, f"{H}x{W} is too large to predict at full resolution (at most {Hm}x{Wm}, "
                               "which needs ~5 GB of memory); resize the panorama first")


def net_size_for(H: int, default: tuple[int, int]) -> tuple[int, int]:
    """The network's resolution: ``default``, or the input's rounded up to a multiple of 32 when that
    is smaller (never upsample a small input more than needed)."""
    Hn = min(default[0], max(32, 32 * math.ceil(H / 32)))
    return Hn, 2 * Hn


def guided_upsample(src: Tensor, guide_lo: Tensor, guide_hi: Tensor, r: int = GUIDE_RADIUS,
                    eps: float = GUIDE_EPS) -> Tensor:
    """Fast guided-filter upsampling (He & Sun 2015) of ``src [C,h,w]`` to the size of ``guide_hi
    [1,H,W]``: the local linear model src ≈ a·guide + b is fitted at low resolution (windows of
    (2r+1)², wrapping in longitude), its coefficients are upsampled, and applied to the full-resolution
    guide, so edges of the output follow edges of the image."""
    from phyir.nets.gsnet import box_mean

    H, W = guide_hi.shape[-2:]
    g, p = guide_lo, src
    m = box_mean(torch.cat((g, g * g, p, g * p)), r)
    C = p.shape[0]
    mg, mgg, mp, mgp = m[:1], m[1:2], m[2:2 + C], m[2 + C:]
    a = (mgp - mg * mp) / ((mgg - mg * mg).clamp_min(0) + eps)
    b = mp - a * mg
    ab = pano.resize_area(box_mean(torch.cat((a, b)), r), H, W)
    return ab[:C] * guide_hi + ab[C:]


def _guide(image: Tensor) -> Tensor:
    from phyir.learn.datasets import luminance

    return torch.log1p(luminance(image.clamp_min(0)))[None]


def _upsample_layer(name: str, lo: Tensor, guide_lo: Tensor, guide_hi: Tensor) -> Tensor:
    if name == "depth":
        return torch.exp(guided_upsample(torch.log(lo.clamp_min(1e-4)), guide_lo, guide_hi))
    out = guided_upsample(lo, guide_lo, guide_hi)
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
# predict


def predict(source: str | os.PathLike | Tensor | PanoScene, *, weights: str | os.PathLike | None = None,
            device: str | torch.device | None = None, outputs: Iterable[str] | None = None,
            probes: str | None = "grid", points: Tensor | None = None, lighting: str | None = None,
            net_size: tuple[int, int] | None = None, hdr: bool | None = None, model=None,
            amp: bool = True, progress: Callable[[str, float], None] | None = None,
            cancel: Callable[[], bool] | threading.Event | None = None) -> PanoScene:
    """Predict every missing layer of a panorama; returns an unbatched scene at the input's size, on
    the CPU.

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
    ``lighting``: ``"projection"`` (probes re-read from the panorama where the camera saw, LNet
    elsewhere) or ``"lnet"`` (LNet only); default :data:`DEFAULT_LIGHTING`.
    ``net_size``: network resolution (H, W) (default: the weights' training resolution, at most the
    input's).  ``progress(stage, fraction)`` is called between stages; ``cancel`` (a callable or an
    Event) is checked between stages and raises :class:`Cancelled`.
    """
    t_start = time.perf_counter()
    times: dict[str, float] = {}

    def step(name: str, t0: float, frac: float) -> float:
        times[name] = round(time.perf_counter() - t0, 4)
        if progress is not None:
            progress(name, frac)
        _check_cancel(cancel)
        return time.perf_counter()

    _check_cancel(cancel)
    t = time.perf_counter()
    if isinstance(source, (str, os.PathLike)):
        _check_predict_size(source, *_header_size(source))  # before decoding a huge file
    scene, is_hdr = load_input(source, hdr)
    _check_predict_size(None, *scene.size)
    want = set(OUTPUTS if outputs is None else outputs)
    unknown = want - set(OUTPUTS)
    if unknown:
        raise PhyIRError(f"unknown outputs {sorted(unknown)} (choose from {', '.join(OUTPUTS)})")
    if probes not in ("grid", "points", None):
        raise PhyIRError(f"probes must be 'grid', 'points' or None, got {probes!r}")
    if probes is None:
        want.discard("probes")
    if probes == "points" and points is None:
        raise PhyIRError("probes='points' needs points=[N,3]")
    lighting = lighting or DEFAULT_LIGHTING
    if lighting not in LIGHTING:
        raise PhyIRError(f"lighting must be one of {LIGHTING}, got {lighting!r}")
    t = step("load", t, 0.05)

    H, W = scene.size
    have = {k for k in GM_LAYERS if getattr(scene, k) is not None}
    have_probes = scene.probes is not None and probes == "grid"
    need_probes = "probes" in want and not have_probes
    missing = {k for k in GM_LAYERS if k in want and k not in have}
    # LNet reads all five GMNet layers (taken from the input where it has them)
    gm_inputs = set(GM_LAYERS) if need_probes else missing
    run_gm = bool(gm_inputs - have)
    computed: list[str] = []

    out = scene.map(lambda x: x)  # shallow copy
    out.meta = dict(scene.meta)
    lnet_grid = None
    if run_gm or need_probes:
        if model is None:
            dev = torch.device(device) if device is not None else \
                torch.device("cuda" if torch.cuda.is_available() else "cpu")
            model, trained = load_cached_model(weights, dev)
        else:
            dev = next(model.parameters()).device if device is None else torch.device(device)
            model = model.to(dev).eval()
            trained = DEFAULT_NET_SIZE
        t = step("model", t, 0.1)
        Hn, Wn = net_size or net_size_for(H, trained)
        from phyir.learn.datasets import exposure_scale

        img = torch.nan_to_num(scene.image.float(), nan=0.0, posinf=0.0).clamp_min(0)
        x = pano.resize_area(img, Hn, Wn).to(dev)
        s = float(exposure_scale(x)) if is_hdr else 1.0
        xn = (x * s)[None]
        use_amp = amp and dev.type == "cuda"
        autocast = torch.autocast("cuda", dtype=torch.float16) if use_amp else nullcontext()
        gm: dict[str, Tensor] = {}
        with torch.inference_mode(), autocast:
            if run_gm:
                raw = model.gmnet(xn)
                gm = {k: v.float() for k, v in raw.items()}
                t = step("gmnet", t, 0.35)
            for k in have & gm_inputs:  # the input's own layers, at the network's resolution
                v = pano.resize_area(getattr(scene, k).float(), Hn, Wn).to(dev)[None]
                gm[k] = F.normalize(v, dim=1) if k == "normal" else v
            refined: dict[str, Tensor] = {}
            if missing & set(model.gsnet.targets):
                refined = {k: v.float() for k, v in model.gsnet(xn, gm).items()}
                t = step("gsnet", t, 0.45)
            if need_probes:
                grid = model.default_grid(Hn, Wn)
                lnet_grid = model.light(xn, gm, grid)[0].float() / s
                t = step("lnet", t, 0.6)
        guide_lo = _guide(xn[0].float())
        guide_hi = _guide(img.to(dev) * s)
        # projection needs depth (and uses normals) even when they are not outputs
        geo_only = {"depth", "normal"} - have - want if (need_probes and lighting == "projection") else set()
        geo: dict[str, Tensor] = {}
        for k in sorted(missing | geo_only, key=GM_LAYERS.index):
            lo = refined.get(k, gm[k])[0]
            up = _upsample_layer(k, lo, guide_lo, guide_hi) if (Hn, Wn) != (H, W) else lo
            if k in missing:
                setattr(out, k, up.float().cpu())
                computed.append(k)
            else:
                geo[k] = up.float().cpu()
        t = step("upsample", t, 0.7)
        out.meta["exposure_scale"] = f"{s:.6g}"
        out.meta["predict.net_size"] = f"{Hn}x{Wn}"
        if weights is not None:
            out.meta["predict.weights"] = Path(weights).name
    # keep only what was asked for or given
    for k in GM_LAYERS:
        if k not in want and k not in have:
            setattr(out, k, None)

    if need_probes:
        assert lnet_grid is not None
        lnet_grid = lnet_grid.cpu()
        if lighting == "projection":
            # in exposure-normalised units, like the networks: sums over a panorama of radiance
            # near float32's limit would overflow
            proj_scene = PanoScene(image=img * s, depth=geo.get("depth", out.depth),
                                   normal=geo.get("normal", out.normal))
        if probes == "grid":
            if lighting == "projection":
                from phyir.lighting.projection import projected_probe_grid

                out.probes = projected_probe_grid(proj_scene, lnet_grid * s) / s
            else:
                out.probes = lnet_grid
        else:
            pts = points.reshape(-1, 3).float().cpu()
            fb = lnet_probes_at(lnet_grid, pts)
            if lighting == "projection":
                from phyir.lighting.projection import project_probes

                fb = project_probes(proj_scene, pts, tuple(fb.shape[-2:]), fb * s)[0] / s
            out.probes = fb[:, None]
            out.meta["probe_layout"] = "points"
        computed.append("probes")
        t = step("probes", t, 0.95)
    elif not have_probes:
        out.probes = None

    times["total"] = round(time.perf_counter() - t_start, 4)
    out.meta["predict.computed"] = " ".join(computed)
    out.meta["predict.reused"] = " ".join(k for k in (*GM_LAYERS, "probes")
                                          if (k in have or (k == "probes" and have_probes)))
    out.meta["predict.lighting"] = lighting if "probes" in computed else ""
    out.meta["predict.seconds"] = json.dumps(times)
    if progress is not None:
        progress("done", 1.0)
    return out


def predict_many(sources: Sequence[str | os.PathLike], **kwargs) -> list[PanoScene]:
    """:func:`predict` for several inputs with the same settings (the model is loaded once)."""
    return [predict(s, **kwargs) for s in sources]
