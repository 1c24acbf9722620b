"""``phyir info FILE...``: what a panorama or scene file holds."""

from __future__ import annotations

import argparse
import sys

HELP = "show the parts, layers, sizes, value ranges and NaN counts of panorama/scene files"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("files", nargs="+", metavar="FILE",
                        help="OpenEXR scene/panorama, Radiance .hdr, PNG or JPEG")


def run(args: argparse.Namespace) -> int:
    from phyir.errors import PhyIRError, shown

    status = 0
    for i, path in enumerate(args.files):
        try:
            text = describe(path)
        except PhyIRError as e:  # report and go on with the other files
            print(f"phyir info: error: {shown(str(e))}", file=sys.stderr)
            status = 2
            continue
        print(("\n" if i else "") + text, flush=True)
    return status


def describe(path: str) -> str:
    """The report for one file (raises InputError for unreadable files)."""
    import numpy as np

    from phyir import io
    from phyir.errors import InputError, shown

    raw = io.read_raw(path, panorama=False)
    lines = [f"{shown(path)}: {raw.format} ({raw.detail})"]
    for part in raw.parts:
        types = "/".join(sorted(set(part.pixel_types.values())))
        head = f"  part {part.name!r}: {part.height}x{part.width} (HxW), {types}"
        if "probes" in part.layers:
            grid, size = part.attrs.get("probeGrid", "?"), part.attrs.get("probeSize", "?")
            head += f", probe grid {grid}, probe size {size}"
        lines.append(head)
        lines.append(f"    {'layer':<16}{'channels':<30}{'min':>11}{'max':>11}{'mean':>11}"
                     f"{'NaN':>8}{'Inf':>8}")
        for name, a in part.layers.items():
            finite = np.isfinite(a)
            fa = a[finite]
            lo, hi, mean = ((f"{fa.min():.4g}", f"{fa.max():.4g}", f"{fa.mean():.4g}") if fa.size
                            else ("-", "-", "-"))
            chans = ",".join(part.layer_channels.get(name, (name,)))
            lines.append(f"    {name:<16}{chans:<30}{lo:>11}{hi:>11}{mean:>11}"
                         f"{int(np.isnan(a).sum()):>8}{int(np.isinf(a).sum()):>8}")
        if part.ignored:
            lines.append(f"    other channels: {', '.join(part.ignored)}")
        for k, v in sorted(part.attrs.items()):
            if k not in ("probeGrid", "probeSize"):
                lines.append(f"    attribute {k} = {v!r}")
    main = raw.part("scene") or raw.parts[0]
    try:
        io.check_panorama_size(path, main.height, main.width)
        lines.append(f"  usable as a panorama: yes ({main.height}x{main.width})")
    except InputError as e:
        lines.append(f"  usable as a panorama: no ({e.problem})")
        return "\n".join(lines)
    if "depth" in main.layers and "normal" in main.layers:
        lines.append(confidence_line(path))
    return "\n".join(lines)


def format_confidence(confidence: float) -> str:
    """The geometry confidence as every command and the viewer show it: two decimals, rounded down,
    so a score reads 1.00 only when it is 1 (0.996 reads 0.99) and a flagged one never reads as the
    threshold (0.4999 reads 0.49, not 0.50; phyir.evaluation.real.FLAG_BELOW)."""
    import math

    if not math.isfinite(confidence):
        return f"{confidence}"
    return f"{math.floor(confidence * 100 + 1e-9) / 100:.2f}"  # (+1e-9: 0.29 * 100 is 28.999...)


def confidence_line(path: str) -> str:
    """The geometry confidence of a scene with depth and normals (phyir.evaluation.real)."""
    import warnings

    from phyir import io
    from phyir.evaluation.real import flag_reason, scene_confidence

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # repairs were reported by the layer table above
        c = scene_confidence(io.load_scene(path))
    verdict = f"flagged: {flag_reason(c)}" if c["flagged"] else "plausible"
    return (f"  geometry confidence: {format_confidence(float(c['confidence']))} ({verdict}; nadir "
            f"floor-like {float(c['nadir_up']):.2f}, normals vs depth {float(c['consistency_deg']):.0f}°, "
            f"room size {float(c['far_m']):.1f} m, camera height {float(c['camera_height']):.2f} m)")
