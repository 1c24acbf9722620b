"""HDR light from an 8-bit panorama, measured against the HDR panorama it was photographed from.

Each HDR panorama is photographed by the evaluation's camera (:func:`phyir.learn.camera.ldr_copy`:
auto-exposed to median 0.18, clipped, 8-bit sRGB; optionally saved as a JPEG) and its light
recovered by each method of
:data:`METHODS`: ``naive`` (the LDR as it is), ``gain`` (one calibrated gain per clipped region,
:mod:`phyir.lighting.hdr_recovery`) and ``clipnet`` (:mod:`phyir.lighting.ldr_to_hdr`, where its
weights are present). Against the truth (the HDR in the LDR's units):

* spheres at the camera (:mod:`phyir.evaluation.real_lighting`'s protocol sphere lit by the whole
  panorama as distant light, no parallax, so what is measured is the recovery alone): diffuse,
  matte silver and mirror silver rel L1, the scale-invariant rel L1, the intensity ratio and the
  colour error;
* the clipped regions (8-connected, :func:`phyir.lighting.hdr_recovery.clipped_regions`): the
  recovered / true energy of each region and the share within a factor of 2 (``regions_within_2x``,
  regions under :data:`MIN_REGION_SR` steradians left out), and the mean |log luminance| error over
  the clipped pixels (``clipped_log_err``).
"""

from __future__ import annotations

import math
import os
import statistics
from collections.abc import Callable

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.evaluation import real_lighting as RL

MIN_REGION_SR = 1e-4  # steradians: smaller clipped regions (a few pixels at 1k) are not counted
SPHERE_KEYS = ("rel_l1", "si_rel_l1", "ratio", "colour_deg")


def _naive(ldr: Tensor) -> Tensor:
    return ldr


def _gain(ldr: Tensor) -> Tensor:
    from phyir.lighting.hdr_recovery import recover_clipped

    return recover_clipped(ldr, model=None)[0]


def methods(clipnet: str | os.PathLike | None = None, region_model=None,
            jpeg: bool = False) -> dict[str, Callable[[Tensor], Tensor]]:
    """The recoveries measured: naive, gain (one calibrated gain per region), regions (the shipped
    :class:`phyir.lighting.clip_regions.RegionModel` where present — with ``jpeg``, the law for JPEG
    input, as predict takes for a JPEG file — or ``region_model``) and, where its weights are present
    (``clipnet``, default the shipped ones), clipnet."""
    from phyir.lighting.hdr_recovery import recover_clipped, shipped_model
    from phyir.lighting.ldr_to_hdr import load_clipnet, recover

    out = {"naive": _naive, "gain": _gain}
    region_model = region_model or shipped_model(jpeg)
    if region_model is not None:
        out["regions"] = lambda ldr: recover_clipped(ldr, model=region_model)[0]
    model = load_clipnet(clipnet)
    if model is not None:
        out["clipnet"] = lambda ldr: recover(ldr, model)[0]
    elif clipnet is not None:
        from phyir.errors import InputError

        raise InputError(clipnet, "ClipNet weights not found")
    return out


def region_rows(ldr: Tensor, recovered: Tensor, truth: Tensor) -> dict[str, float]:
    """Energy ratios of the clipped regions and the log error over the clipped pixels."""
    from phyir.lighting.clip_regions import region_means
    from phyir.lighting.hdr_recovery import clipped_regions

    H, W = ldr.shape[-2:]
    clipped, labels, n = clipped_regions(ldr)
    if not bool(clipped.any()):
        return {"clipped_sr": 0.0}
    omega = pano.solid_angles(H, W)
    lr, lt = luminance(recovered.float()), luminance(truth.float())
    area, (mean_r, mean_t) = region_means(labels, n, lr, lt)
    big = area >= MIN_REGION_SR
    ratios = (mean_r[big] / mean_t[big].clamp_min(1e-30)).tolist()
    w = omega[clipped]
    err = (torch.log(lr[clipped] + 1e-4) - torch.log(lt[clipped] + 1e-4)).abs()
    out = {"clipped_sr": float(w.sum()), "clipped_log_err": float((err * w).sum() / w.sum()),
           "regions": float(len(ratios))}
    if ratios:
        out |= {"regions_within_2x": sum(0.5 <= r <= 2 for r in ratios) / len(ratios),
                "region_ratio_median": statistics.median(ratios)}
    return out


def evaluate_panorama(path: str | os.PathLike, clipnet: str | os.PathLike | None = None,
                      region_model=None, jpeg: int | None = None) -> dict[str, dict[str, float]]:
    """``{method: metrics}`` of one HDR panorama (module doc); ``clipnet``: weights to measure,
    ``region_model``: a :class:`phyir.lighting.clip_regions.RegionModel` instead of the shipped one;
    ``jpeg``: the copy saved as a JPEG of that quality (and the law for JPEG input shipped)."""
    from phyir.io import load_panorama
    from phyir.learn.camera import jpeg_linear, ldr_copy

    hdr = torch.nan_to_num(load_panorama(path).float(), nan=0.0, posinf=0.0).clamp_min(0)
    ldr, scale = ldr_copy(hdr)
    if jpeg is not None:
        ldr = jpeg_linear(ldr, jpeg)
    truth = hdr * scale
    envs = {name: fn(ldr) for name, fn in methods(clipnet, region_model, jpeg is not None).items()}
    stack = torch.stack([pano.resize_area(e.float(), *RL.INTEGRATION_SIZE) for e in (truth, *envs.values())])
    rows: dict[str, dict[str, float]] = {name: {} for name in envs}
    for mat in RL.MATERIALS:
        if mat.startswith("mirror"):
            continue  # a mirror at the camera shows the panorama itself: the region rows measure that
        px, _ = RL.render_sphere(stack, mat)  # distant light: the place only sets the view
        for i, name in enumerate(envs):
            m = RL.sphere_metrics(px[1 + i], px[0])
            rows[name] |= {f"{mat}.{k}": m[k] for k in SPHERE_KEYS}
    for name, env in envs.items():
        rows[name] |= region_rows(ldr, env, truth)
    return rows


def evaluate_ldr_light(paths: list[str | os.PathLike], log: Callable[[str], None] | None = None,
                       clipnet: str | os.PathLike | None = None, jpeg: int | None = None,
                       region_model: str | os.PathLike | None = None) -> dict:
    """:func:`evaluate_panorama` on HDR panoramas (files, or folders of them); ``{"<name>/<method>":
    metrics}`` plus ``"median/<method>"`` and, per method, ``ratio_range`` of the diffuse sphere;
    ``jpeg``: the copies saved as JPEGs of that quality; ``region_model``: the JSON file of a
    :class:`phyir.lighting.clip_regions.RegionModel` to measure instead of the shipped one."""
    from phyir.evaluation.real import panorama_files
    from phyir.lighting.clip_regions import RegionModel

    law = None
    if region_model is not None:
        from phyir.errors import InputError
        from phyir.io import check_input

        check_input(region_model)
        try:
            law = RegionModel.load(region_model)
        except (ValueError, KeyError, TypeError):  # not JSON, or JSON of something else
            law = None
        if law is None:
            raise InputError(region_model, "not a clipped-region model of this version's features "
                                           "(python -m phyir.learn.fit_clip_regions)")

    files = [f for f in panorama_files(paths) if f.suffix.lower() in (".hdr", ".exr")]
    out: dict[str, dict[str, float]] = {}
    for f in files:
        for name, row in evaluate_panorama(f, clipnet, law, jpeg).items():
            out[f"{f.stem}/{name}"] = row
        if log is not None:
            d = {k.split("/")[1]: v["diffuse.rel_l1"] for k, v in out.items() if k.startswith(f"{f.stem}/")}
            log(f"{f.stem}: diffuse rel L1 " + ", ".join(f"{k} {v:.3f}" for k, v in d.items()))
    names = sorted({k.split("/")[1] for k in out})
    for name in names:
        rows = [v for k, v in out.items() if k.endswith(f"/{name}")]
        keys = sorted({k for r in rows for k in r})
        med = {k: statistics.median([r[k] for r in rows if k in r and not math.isnan(r[k])]) for k in keys}
        ratios = [r["diffuse.ratio"] for r in rows]
        med |= {"diffuse.ratio_min": min(ratios), "diffuse.ratio_max": max(ratios)}
        out[f"median/{name}"] = med
    return out


def markdown_ldr_light(results: dict) -> str:
    from phyir.evaluation.metrics import markdown_table

    keys = ["diffuse.rel_l1", "diffuse.ratio", "diffuse.colour_deg", "matte_silver.rel_l1",
            "regions_within_2x", "region_ratio_median", "clipped_log_err"]
    return markdown_table(results, keys, digits=3)


def room_table(doc: dict) -> list[str]:
    """Markdown, one row per room of :func:`evaluate_ldr_light`'s results (validation rooms of
    ``hdri-indoor`` first, named so): each method's diffuse and matte-silver rel L1, diffuse
    intensity ratio and clipped regions within 2x, then the medians (the ratio as its range)."""
    from phyir.learn.ldr_pairs import is_validation

    methods = [m for m in ("naive", "gain", "regions", "clipnet") if f"median/{m}" in doc]
    recovering = [m for m in methods if m != "naive"]
    names = " / ".join(methods)
    out = [f"| room | diffuse rel L1: {names} | diffuse intensity ratio: {names} "
           f"| matte silver rel L1: {names} | clipped regions within 2×: {' / '.join(recovering)} |",
           "| --- | ---: | ---: | ---: | ---: |"]
    rooms = sorted({k.split("/")[0] for k in doc if not k.startswith("median/")},
                   key=lambda r: (not is_validation(r), r))
    for room in rooms + ["median"]:
        v = {m: doc[f"{room}/{m}"] for m in methods}
        cells = {key: " / ".join(format(v[m][key], ".3f") for m in methods)
                 for key in ("diffuse.rel_l1", "matte_silver.rel_l1")}
        ratio = " / ".join(f"{v[m]['diffuse.ratio_min']:.2f}–{v[m]['diffuse.ratio_max']:.2f}"
                           if room == "median" else f"{v[m]['diffuse.ratio']:.2f}" for m in methods)
        within = " / ".join(f"{100 * v[m].get('regions_within_2x', 0):.0f} %" for m in recovering)
        label = ("**median** (ratio: range)" if room == "median"
                 else room.replace("_1k", "") + (" (validation split)" if is_validation(room) else ""))
        out.append(f"| {label} | {cells['diffuse.rel_l1']} | {ratio} "
                   f"| {cells['matte_silver.rel_l1']} | {within} |")
    return out
