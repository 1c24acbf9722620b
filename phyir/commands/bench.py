"""``phyir bench [TARGET...]``: benchmarks that measure time against error.

Each target is a module with ``run_bench(out_dir, *, quick, device, repeats, threads, log) -> dict`` that
writes ``<target>.json`` and ``<target>.png`` into ``out_dir`` and prints its table; it may define
``format_table(result) -> str`` and ``key_numbers(result) -> dict[str, float]`` for the report.  Add a
target by adding it to :data:`BUILTIN_TARGETS`, or, from another package, to the ``phyir.bench_targets``
entry-point group (the viewer's ``shading``); ``phyir bench`` alone runs every target whose module exists.
After the targets, ``report.md`` and ``report.json`` gather them all (:mod:`phyir.bench.report`).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import importlib.util

from phyir.commands import options

HELP = ("benchmark PhyIR: time and error of every stage; per target JSON + PNG, and report.md/.json "
        "(targets: modules, skips, render, synth, model, shading)")

# target name -> module implementing run_bench
BUILTIN_TARGETS = {
    "modules": "phyir.bench.modules",  # per-module time and memory vs the supplement's Table 1
    "skips": "phyir.bench.skips",  # time saved and result changed by every skip
    "render": "phyir.bench.render",  # rendering layer: methods x sample counts, time vs error
    "synth": "phyir.bench.synth",  # data generator: samples per pixel vs noise
    "model": "phyir.bench.model",  # model size x resolution vs depth / albedo / relighting error
}
# plug-ins: the viewer's ``shading`` (its shading settings vs the converged reference)
TARGETS = BUILTIN_TARGETS | {ep.name: ep.value
                             for ep in importlib.metadata.entry_points(group="phyir.bench_targets")}


def available() -> list[str]:
    out = []
    for t, mod in TARGETS.items():
        try:
            found = importlib.util.find_spec(mod) is not None
        except ModuleNotFoundError:  # its package is missing
            found = False
        if found:
            out.append(t)
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("targets", nargs="*", metavar="TARGET",
                        help=f"what to benchmark: {', '.join(TARGETS)} (default: all available)")
    parser.add_argument("--quick", action="store_true", help="small sizes and few repeats (smoke test)")
    parser.add_argument("--device", default="cpu", help="cpu or cuda (default cpu)")
    parser.add_argument("--repeats", type=options.number(1, 10**4, integer=True), default=None, metavar="N",
                        help="timed runs per measurement after one warm-up (default: per target)")
    parser.add_argument("--threads", type=options.number(1, 1024, integer=True), default=None, metavar="N",
                        help="torch CPU threads during the run (default: torch's; 1 = fair CPU times "
                             "on a shared machine)")
    parser.add_argument("-o", "--out", default="benchmarks/results", metavar="DIR", type=options.path,
                        help="output folder for <target>.json/.png and report.md/.json "
                             "(default benchmarks/results)")


def run(args: argparse.Namespace) -> int:
    import os
    import time
    from pathlib import Path

    import torch

    from phyir.bench import measure as bench_measure
    from phyir.bench import report as bench_report
    from phyir.errors import InputError

    have = available()
    targets = list(dict.fromkeys(args.targets)) or have
    for t in targets:
        if t not in TARGETS:
            raise InputError("TARGET", f"unknown benchmark {t!r}; available: {', '.join(have)}")
        if t not in have:
            raise InputError("TARGET", f"benchmark {t!r} is not available in this checkout "
                                       f"(module {TARGETS[t]} missing)")
    if args.device not in ("cpu", "cuda") and not args.device.startswith("cuda:"):
        raise InputError("--device", f"expected cpu or cuda, got {args.device!r}")
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        raise InputError("--device", "CUDA is not available on this machine")
    for flag, val in (("--repeats", args.repeats), ("--threads", args.threads)):
        if val is not None and val < 1:
            raise InputError(flag, f"expected a positive integer, got {val}")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "not a folder")
    out.mkdir(parents=True, exist_ok=True)
    if not os.access(out, os.W_OK):
        raise InputError(out, "folder is not writable")
    machine = bench_measure.machine_info(args.device)
    if args.threads is not None:
        machine["torch_threads"] = args.threads
    entries = {}
    t_all = time.perf_counter()
    for t in targets:
        mod = importlib.import_module(TARGETS[t])
        lines: list[str] = []

        def log(s: str, lines: list[str] = lines) -> None:
            lines.append(s)
            print(s, flush=True)

        t0 = time.perf_counter()
        result = mod.run_bench(out, quick=args.quick, device=args.device, repeats=args.repeats,
                               threads=args.threads, log=log)
        entries[t] = bench_report.target_entry(t, mod, result, time.perf_counter() - t0, out, lines)
        entries[t]["command"] = _command(args)
        print(f"bench {t}: {entries[t]['seconds']:.1f} s", flush=True)
    report = bench_report.build_report(
        entries, command=_command(args), quick=args.quick, device=args.device, threads=args.threads,
        repeats=args.repeats, machine=machine, not_available=[t for t in TARGETS if t not in have],
        total_seconds=time.perf_counter() - t_all)
    js, md = bench_report.write_report(out, report)
    print(f"bench: wrote {md} and {js} ({report['total_seconds']:.0f} s)")
    return 0


def _command(args: argparse.Namespace) -> str:
    """The command line that reproduces this run."""
    import shlex

    parts = ["phyir", "bench", *args.targets]
    if args.quick:
        parts.append("--quick")
    device = args.device if args.device != "cpu" else None
    for flag, val in (("--device", device), ("--repeats", args.repeats), ("--threads", args.threads)):
        if val is not None:
            parts += [flag, str(val)]
    return shlex.join([*parts, "-o", str(args.out)])
