"""``phyir synth``: render a synthetic dataset (procedural rooms, path-traced ground truth)."""

from __future__ import annotations

import argparse

from phyir.commands import options

HELP = "generate synthetic indoor panoramas with ground-truth layers and light probes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, metavar="DIR", type=options.path,
                        help="output folder (created; resumable)")
    parser.add_argument("--count", type=options.number(1, 10**12, integer=True), required=True, metavar="N",
                        help="number of scenes in the dataset")
    parser.add_argument("--seed", type=options.number(0, 2**63 - 1, integer=True), default=0, metavar="S",
                        help="dataset seed (default 0)")
    parser.add_argument("--size", default="256x512", metavar="HxW", help="panorama size (default 256x512)")
    parser.add_argument("--probe-grid", default="64x128", metavar="HpxWp",
                        help="probe grid, dividing the size; 'none' for no probes (default 64x128)")
    parser.add_argument("--probe-size", default="16x32", metavar="hxw", help="probe size (default 16x32)")
    parser.add_argument("--spp", type=options.number(1, 10**12, integer=True), default=16, metavar="N",
                        help="camera samples per pixel (default 16)")
    parser.add_argument("--shard", default="0/1", metavar="i/n",
                        help="render only scenes with index %% n == i (default 0/1: all)")
    parser.add_argument("--device", default="cpu", choices=("cpu", "cuda"), help="device (default cpu)")
    parser.add_argument("--float32", action="store_true", help="write float32 files (default: half floats)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    import torch

    from phyir.errors import PhyIRError
    from phyir.synth.dataset import DatasetConfig, generate_dataset, parse_shard, parse_size

    if args.count < 1:
        raise PhyIRError(f"--count: must be at least 1, got {args.count}")
    if args.spp < 1:
        raise PhyIRError(f"--spp: must be at least 1, got {args.spp}")
    size = parse_size(args.size, "--size")
    grid = None if args.probe_grid.lower() == "none" else parse_size(args.probe_grid, "--probe-grid")
    if grid is not None and (size[0] % grid[0] or size[1] % grid[1]):
        raise PhyIRError(f"--probe-grid: {args.probe_grid} must divide --size {args.size}")
    if args.device == "cuda" and not torch.cuda.is_available():
        raise PhyIRError("--device cuda: no CUDA device is available")
    cfg = DatasetConfig(seed=args.seed, count=args.count, size=size, probe_grid=grid,
                        probe_size=parse_size(args.probe_size, "--probe-size"), spp=args.spp,
                        half=not args.float32)
    res = generate_dataset(args.out, cfg, parse_shard(args.shard), device=args.device,
                           progress=not args.quiet)
    print(f"phyir synth: {res['written']} written, {res['skipped']} already present, "
          f"{res['seconds']:.1f} s -> {args.out}")
    return 0
