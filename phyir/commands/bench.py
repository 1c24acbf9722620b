"""``phyir bench [TARGET...]``: benchmarks that measure time against error.

Each target is a module with ``run_bench(out_dir, *, quick, device, repeats, threads, log) -> dict`` that
writes ``<target>.json`` and ``<target>.png`` into ``out_dir`` and prints its table.  Add a target by
adding it to :data:`TARGETS`; ``phyir bench`` alone runs every target whose module exists.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util

HELP = "benchmark PhyIR components: time against error, JSON + PNG + table (targets: render)"

# target name -> module implementing run_bench
TARGETS = {"render": "phyir.bench_render"}


def available() -> list[str]:
    return [t for t, mod in TARGETS.items() if importlib.util.find_spec(mod) is not None]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("targets", nargs="*", metavar="TARGET",
                        help=f"what to benchmark: {', '.join(TARGETS)} (default: all available)")
    parser.add_argument("--quick", action="store_true", help="small sizes and few repeats (smoke test)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    parser.add_argument("--repeats", type=int, default=None, metavar="N",
                        help="timed runs per measurement after one warm-up (default: per target)")
    parser.add_argument("--threads", type=int, default=None, metavar="N",
                        help="torch CPU threads during the run (default: torch's; 1 = fair CPU times "
                             "on a shared machine)")
    parser.add_argument("-o", "--out", default="benchmarks/results", metavar="DIR",
                        help="output folder for <target>.json and <target>.png (default benchmarks/results)")


def run(args: argparse.Namespace) -> int:
    import torch

    from phyir.errors import InputError

    targets = args.targets or available()
    for t in targets:
        if t not in TARGETS:
            raise InputError("TARGET", f"unknown benchmark {t!r}; available: {', '.join(available())}")
    if args.device not in ("cpu", "cuda") and not args.device.startswith("cuda:"):
        raise InputError("--device", f"expected cpu or cuda, got {args.device!r}")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device", "CUDA is not available on this machine")
    for flag, val in (("--repeats", args.repeats), ("--threads", args.threads)):
        if val is not None and val < 1:
            raise InputError(flag, f"expected a positive integer, got {val}")
    for t in targets:
        mod = importlib.import_module(TARGETS[t])
        mod.run_bench(args.out, quick=args.quick, device=args.device, repeats=args.repeats,
                      threads=args.threads, log=lambda s: print(s, flush=True))
    return 0
