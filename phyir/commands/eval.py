"""``phyir eval``: the paper's metrics for predictions against ground truth, as JSON and Markdown."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from phyir.commands import options
from phyir.commands import predict as predict_cmd

HELP = "evaluate predictions (or the model on a synthetic split) with the paper's metrics"

# column groups of the Markdown tables
DEPTH = ["depth.mae", "depth.abs_rel", "depth.sq_rel", "depth.rmse", "depth.rmse_log", "depth.log10",
         "depth.delta1", "depth.delta2", "depth.delta3"]
NORMAL = ["normal.mean", "normal.median", "normal.pct_11.25", "normal.pct_22.5", "normal.pct_30"]
MATERIAL = ["albedo_mse", "albedo_si_mse", "roughness_mse", "metallic_mse", "metallic_auc"]
LIGHT = ["probe_log_mse", "relight_diffuse", "relight_matte_silver", "relight_mirror_silver"]
SPHERES = ["diffuse.rel_l1", "diffuse.si_rel_l1", "diffuse.ratio", "diffuse.colour_deg",
           "matte_silver.rel_l1", "matte_silver.si_rel_l1", "matte_silver.ratio"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("predictions", nargs="*", metavar="PRED",
                        help="predicted scene files or folders (matched to --gt by file name)")
    parser.add_argument("--gt", metavar="DIR", help="folder of ground-truth scene files")
    parser.add_argument("--data", metavar="DIR", help="synthetic dataset: run the model on --split")
    parser.add_argument("--split", default="test", choices=("train", "val", "test"))
    parser.add_argument("--weights", metavar="FILE", help="weights for --data (default: the shipped model)")
    parser.add_argument("--device", type=options.device, help="cpu, cuda, ... (default: cuda when available)")
    parser.add_argument("--limit", type=options.number(1, 10**9, integer=True),
                        help="evaluate the first N scenes only")
    parser.add_argument("--probes-per-scene", type=options.number(1, 10**6, integer=True), default=256,
                        help="random ground-truth probe cells compared per scene (--data)")
    parser.add_argument("--relight", type=options.number(0, 10**4, integer=True), default=16,
                        help="probes per scene rendered for the relighting error (0: skip)")
    parser.add_argument("--spp", type=options.number(1, 65536, integer=True), default=64,
                        help="samples per pixel of the relit spheres")
    parser.add_argument("--points", type=options.number(0, 4096, integer=True), default=0,
                        help="--data: also the light at N free points per scene against probes path-traced "
                             "there (phyir.evaluation.points; 0: skip)")
    parser.add_argument("--seed", type=options.number(0, 2**63 - 1, integer=True), default=0)
    parser.add_argument("--json", metavar="FILE", type=options.path, help="write the results as JSON")
    parser.add_argument("--markdown", metavar="FILE", type=options.path,
                        help="write the Markdown tables (also printed)")
    parser.add_argument("--real", metavar="PATH", nargs="+",
                        help="real panoramas without ground truth (.hdr/.exr/.png/.jpg files or folders of "
                             "them): geometry checks, "
                             "invariances and lighting at a point (phyir.evaluation.real)")
    parser.add_argument("--scans", metavar="DIR",
                        help="scanned rooms with ground-truth depth (rgb.* + depth.npy/.exr/16-bit .png "
                             "per room): the field's depth protocol, normals, the constant-depth baseline "
                             "(phyir.evaluation.real_depth)")
    parser.add_argument("--ldr-light", nargs="+", metavar="HDR",
                        help="HDR panoramas (files or folders): their auto-exposed 8-bit copies' light "
                             "recovered by each method (naive, gain, clipnet) against the HDR, at the camera "
                             "and per clipped region (phyir.evaluation.ldr_light)")
    parser.add_argument("--clipnet", metavar="FILE",
                        help="--ldr-light: ClipNet weights to measure (default: the shipped ones, if any)")
    parser.add_argument("--region-model", metavar="FILE",
                        help="--ldr-light: a clipped-region model to measure instead of the shipped one "
                             "(JSON: python -m phyir.learn.fit_clip_regions)")
    parser.add_argument("--jpeg", metavar="Q", type=options.number(1, 100, integer=True),
                        help="--ldr-light: the 8-bit copies saved as JPEGs of quality Q (regions: the law "
                             "for JPEG input, as phyir predict uses for a .jpg)")
    parser.add_argument("--sheet", metavar="PNG", type=options.path,
                        help="--real, --scans: write a contact sheet of the rooms")
    parser.add_argument("--lighting", choices=predict_cmd.lighting_methods().names(),
                        help="--real: predict's lighting method for the probe grid (default: predict's; "
                             "phyir predict --help describes them)")


def markdown(results: dict[str, dict[str, float]]) -> str:
    from phyir.evaluation.metrics import markdown_table

    margins = {m: r for m, r in results.items() if m.startswith("margin/")}
    results = {m: r for m, r in results.items() if m not in margins}
    parts = []
    for title, keys in (("Depth", DEPTH), ("Normals (degrees, %)", NORMAL), ("Materials (MSE)", MATERIAL),
                        ("Lighting (log-space MSE)", LIGHT),
                        ("Spheres lit by the light at free points (rel L1, ratio, degrees)", SPHERES)):
        rows = {m: r for m, r in results.items() if any(k in r for k in keys)}
        if rows:
            heads = [k for k in keys if any(k in r for r in rows.values())]
            parts.append(f"**{title}**\n\n" + markdown_table(rows, heads))
    extra = {m: {k: v for k, v in r.items() if k == "predict_seconds"} for m, r in results.items()}
    extra = {m: r for m, r in extra.items() if r}
    if extra:
        parts.append("**Time**\n\n" + markdown_table(extra, ["predict_seconds"], digits=3))
    for name, r in margins.items():
        parts.append(margin_table(name, r))
    return "\n".join(parts)


def margin_table(name: str, r: dict[str, float]) -> str:
    """One row per metric: the relative margin, its 95 % bootstrap interval, scenes where better."""
    title = name.removeprefix("margin/").replace("-vs-", " vs ")
    lines = [f"**Margins per scene: {title}** (model / baseline - 1; 95 % bootstrap interval over scenes)",
             "", "| metric | margin | 95 % interval | scenes better |", "| --- | ---: | ---: | ---: |"]
    def pct(x: float) -> str:  # two decimals for margins under 1 %
        return f"{100 * x:+.{2 if abs(x) < 0.01 else 1}f} %"

    for key in DEPTH + NORMAL + MATERIAL + LIGHT:
        if f"{key}.margin" in r:
            v = {f: r[f"{key}.{f}"] for f in ("margin", "ci_low", "ci_high", "better", "scenes")}
            lines.append(f"| {key} | {pct(v['margin'])} | {pct(v['ci_low'])} … {pct(v['ci_high'])} | "
                         f"{v['better']:.0f} of {v['scenes']:.0f} |")
    return "\n".join(lines) + "\n"


def _pairs(preds: list[str], gt_dir: Path) -> list[tuple[Path, Path]]:
    import os

    from phyir.errors import InputError, shown
    from phyir.io import check_input, folder_files

    files: list[Path] = []
    for s in preds:
        p = Path(s)
        files += [Path(q) for q in folder_files(p, (".exr",))] if p.is_dir() else [p]  # no temporaries
    if not files:
        raise InputError(preds[0] if preds else None, "no prediction files")
    pairs = []
    for f in files:
        g = gt_dir / f.name
        if os.path.lexists(g):  # [issue 22] a FIFO or a folder there is said as such
            check_input(g)
        else:
            raise InputError(g, f"no ground truth for prediction {shown(f)}")
        pairs.append((f, g))
    return pairs


def run(args: argparse.Namespace) -> int:

    from phyir.errors import PhyIRError
    from phyir.io import load_scene

    if getattr(args, "real", None):
        return run_real(args)
    if getattr(args, "scans", None):
        return run_scans(args)
    if getattr(args, "ldr_light", None):
        from phyir.evaluation.ldr_light import evaluate_ldr_light, markdown_ldr_light

        results = evaluate_ldr_light(args.ldr_light, log=lambda s: print(s, file=sys.stderr, flush=True),
                                     clipnet=args.clipnet, jpeg=args.jpeg, region_model=args.region_model)
        write_outputs(args, results, markdown_ldr_light(results))
        return 0
    if bool(args.data) == bool(args.predictions):
        raise PhyIRError("give either prediction files with --gt, or --data (run the model)")
    if args.data:
        from phyir.evaluation.synthetic import evaluate_model

        results = evaluate_model(args.data, args.split, weights=args.weights, device=args.device,
                                 limit=args.limit, probes_per_scene=args.probes_per_scene,
                                 relight=args.relight, spp=args.spp, seed=args.seed,
                                 log=lambda s: print(s, file=sys.stderr, flush=True))
        if args.points:
            from phyir.evaluation.points import evaluate_model_points

            results |= evaluate_model_points(
                args.data, args.split, count=args.points, weights=args.weights, device=args.device,
                limit=args.limit, spp=args.spp, seed=args.seed,
                log=lambda s: print(s, file=sys.stderr, flush=True))
    else:
        if not args.gt:
            raise PhyIRError("prediction files need --gt DIR (the ground-truth scenes)")
        if args.points:
            raise PhyIRError("--points runs the model at free points: give it with --data, not with "
                             "prediction files")
        from phyir.evaluation.metrics import MetricMeter
        from phyir.evaluation.synthetic import evaluate_pair

        meter = MetricMeter()
        for f, g in _pairs(args.predictions, Path(args.gt)):
            pred, gt = load_scene(f), load_scene(g)
            if pred.size != gt.size:
                raise PhyIRError(f"{f}: size {pred.size[0]}x{pred.size[1]} differs from the ground "
                                 f"truth's {gt.size[0]}x{gt.size[1]}")
            meter.add(evaluate_pair(pred, gt, relight=args.relight, spp=args.spp))
        results = {"predictions": meter.result()}
    write_outputs(args, results, markdown(results))
    return 0


def write_outputs(args: argparse.Namespace, results: dict, md: str) -> None:
    """Print the Markdown; write --json and --markdown (atomically) when asked."""
    import json

    from phyir.io import AtomicSet

    print(md)
    with AtomicSet() as files:  # one set: never a new JSON beside an old Markdown
        if args.json:
            Path(files.add(args.json)).write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")
        if args.markdown:
            Path(files.add(args.markdown)).write_text(md)


def run_real(args: argparse.Namespace) -> int:
    """``--real DIR``: :func:`phyir.evaluation.real.evaluate_real`, its tables printed, the per-panorama
    seconds on stderr, JSON / Markdown / contact sheet written when asked."""

    from phyir.errors import PhyIRError
    from phyir.evaluation.real import evaluate_real, markdown_real, save_contact_sheet

    if args.data or args.predictions or args.gt or args.points:
        raise PhyIRError("--real evaluates a folder of panoramas on its own (no --data, --gt, PRED or "
                         "--points)")
    options = {k: v for k, v in (("weights", args.weights), ("device", args.device),
                                 ("lighting", args.lighting)) if v is not None}
    results, sheet = evaluate_real(args.real, log=lambda s: print(s, file=sys.stderr, flush=True), **options)
    write_outputs(args, results, markdown_real(results))
    if args.sheet:
        save_contact_sheet(sheet, args.sheet)
    return 0


def run_scans(args: argparse.Namespace) -> int:
    """``--scans DIR``: :func:`phyir.evaluation.real_depth.evaluate_scans`, one line per room on stderr,
    the table printed, JSON / Markdown / contact sheet written when asked."""
    from phyir.errors import PhyIRError
    from phyir.evaluation.real_depth import evaluate_scans, markdown_scans

    if args.data or args.predictions or args.gt or args.points or args.real:
        raise PhyIRError("--scans evaluates a folder of scanned rooms on its own (no --data, --gt, PRED, "
                         "--real or --points)")
    options = {k: v for k, v in (("weights", args.weights), ("device", args.device)) if v is not None}
    results = evaluate_scans(args.scans, sheet=args.sheet,
                             log=lambda s: print(s, file=sys.stderr, flush=True), **options)
    write_outputs(args, results, markdown_scans(results))
    return 0
