#!/usr/bin/env python3
"""Synthetic rooms, then GMNet fine-tunes, on one machine in a fixed wall-clock budget.

The recipe of a short GPU lease (docs/training.md, "A GPU lease"): for the first part of the budget
`phyir synth` runs in several processes at once (on CUDA where it works, on the CPU cores beside it);
then every variant (a `phyir train --config` file) fine-tunes GMNet from the shipped weights on the
rooms written so far, all variants at once on the same GPU; each result is stored as float16 release
weights (`python -m phyir.learn.weights ship`, from the checkpoint when the time ran out first).

    python scripts/train_gpu.py --minutes 9 --out runs/gpu --results OUT scripts/gpu_*.toml

Everything it runs is an ordinary, resumable command; a summary (scene counts, rates, steps,
seconds) goes to RESULTS/summary.json.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

PY = [sys.executable, "-m", "phyir.cli"]
SHIPPED = "checkpoints/phyir-lite.safetensors"


def log(msg: str) -> None:
    print(f"[train_gpu {time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def cuda_works() -> bool:
    """`phyir synth --device cuda` on one tiny room: the tracer's CUDA path has never run before."""
    try:
        import torch
        if not torch.cuda.is_available():
            return False
    except ImportError:
        return False
    tmp = Path("/tmp/train_gpu_smoke")
    r = subprocess.run(PY + ["synth", "--out", str(tmp), "--count", "1", "--size", "32x64", "--probe-grid",
                             "8x16", "--probe-size", "8x16", "--spp", "2", "--device", "cuda", "--quiet"],
                       capture_output=True, text=True, timeout=120)
    if r.returncode:
        log("synth on CUDA failed, the CPU does it: " + (r.stderr.strip().splitlines() or ["?"])[-1])
    return r.returncode == 0


def synth(args, deadline: float) -> dict:
    cuda = args.cuda_procs > 0 and cuda_works()
    devices = ["cuda"] * (args.cuda_procs if cuda else 0) + ["cpu"] * args.cpu_procs
    n = len(devices)
    procs = []
    for k, dev in enumerate(devices):
        env = dict(os.environ, OMP_NUM_THREADS="1")
        cmd = PY + ["synth", "--out", args.data, "--count", str(args.count), "--seed", str(args.seed),
                    "--size", args.size, "--probe-grid", args.probe_grid, "--spp", "8", "--shard", f"{k}/{n}",
                    "--device", dev, "--quiet"]
        err = open(f"/tmp/train_gpu_synth_{k}.log", "w+")  # a file: a pipe left unread fills up
        procs.append((subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err), err))
    until = time.strftime('%H:%M:%S', time.localtime(deadline))
    log(f"synth: {n} processes ({devices.count('cuda')} on CUDA) until {until}")
    t0 = time.time()
    while time.time() < deadline and any(p.poll() is None for p, _ in procs):
        time.sleep(2)
    for p, _ in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)  # phyir cleans its temporaries and exits 143
    failed = []
    for p, err in procs:
        p.wait(timeout=60)
        err.seek(0)
        lines = err.read().strip().splitlines()
        if p.returncode not in (0, 143) and lines:
            failed.append(lines[-1])
    scenes = len(list(Path(args.data).glob("scene_*.exr")))
    out = {"processes": n, "cuda_processes": devices.count("cuda"), "seconds": round(time.time() - t0, 1),
           "scenes": scenes, "failed": failed[:4]}
    log(f"synth: {scenes} scenes in {out['seconds']} s; failures: {failed[:2]}")
    return out


def train(args, deadline: float) -> dict:
    names = json.loads((Path(args.data) / "manifest.json").read_text())
    present = {p.name for p in Path(args.data).glob("scene_*.exr")}
    n_train = len([n for n in names["splits"]["train"] if n in present])
    steps_per_epoch = max(n_train // args.batch_size, 1)
    seconds = max(deadline - time.time() - 45, 30)  # 45 s: start-up, last checkpoint, shipping
    epochs = max(int(args.steps_per_second * seconds / steps_per_epoch), 1)
    log(f"train: {n_train} train scenes, {steps_per_epoch} steps/epoch, {epochs} epochs, {seconds:.0f} s")
    procs = {}
    Path(args.results).mkdir(parents=True, exist_ok=True)
    for cfg in args.configs:
        name = Path(cfg).stem
        env = dict(os.environ, OMP_NUM_THREADS="2")
        cmd = PY + ["train", "--config", cfg, "--data", args.data, "--out", f"{args.out}/{name}",
                    "--init", args.init, "--size", args.size, "--epochs", str(epochs),
                    "--batch-size", str(args.batch_size),
                    "--max-minutes", f"{seconds / 60:.2f}", "--workers", str(args.workers), "--no-progress",
                    "--limit-val", "16"]
        err = open(Path(args.results) / f"{name}.log", "w")  # a file: pipes of several processes fill up
        procs[name] = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
    results = {}
    for name, p in procs.items():
        p.wait()
        err = (Path(args.results) / f"{name}.log").read_text()
        stage = Path(args.out) / name / "gm"
        src = stage / "model.safetensors"
        src = src if src.is_file() else stage / "checkpoint.pt"
        res = {"returncode": p.returncode, "last": (err.strip().splitlines() or [""])[-1]}
        if src.is_file():
            rest = ["--rest", args.rest] if args.rest else []
            subprocess.run([sys.executable, "-m", "phyir.learn.weights", "ship", str(src),
                            str(Path(args.results) / f"{name}.safetensors"), *rest], check=True)
            lines = (stage / "log.jsonl").read_text().splitlines()
            res["steps"] = json.loads(lines[-1])["step"] if lines else 0
        results[name] = res
        log(f"train {name}: {res}")
    return {"train_scenes": n_train, "epochs": epochs, "seconds": round(seconds), "variants": results}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("configs", nargs="+", help="phyir train --config files, one fine-tune each")
    ap.add_argument("--minutes", type=float, default=9.0, help="the whole budget")
    ap.add_argument("--synth-share", type=float, default=0.55, help="share of the budget for synth")
    ap.add_argument("--data", default="data/gpu128")
    ap.add_argument("--out", default="runs/gpu")
    ap.add_argument("--results", default="runs/gpu/results")
    ap.add_argument("--init", default=SHIPPED, help="weights every variant starts from")
    ap.add_argument("--rest", help="weights whose LNet and GSNet complete each result (a geometry run's)")
    ap.add_argument("--size", default="128x256", help="rooms and training resolution")
    ap.add_argument("--probe-grid", default="16x32", help="rooms' probe grid ('none': geometry only)")
    ap.add_argument("--count", type=int, default=20000)
    ap.add_argument("--seed", type=int, default=30000)
    ap.add_argument("--cuda-procs", type=int, default=8)
    ap.add_argument("--cpu-procs", type=int, default=6)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--workers", type=int, default=4)
    ap.add_argument("--steps-per-second", type=float, default=12.0, help="guess, per variant, for the "
                    "cosine schedule's length (--max-minutes stops it in any case)")
    args = ap.parse_args()
    t0 = time.time()
    end = t0 + 60 * args.minutes
    summary = {"synth": synth(args, t0 + 60 * args.minutes * args.synth_share)}
    Path(args.results).mkdir(parents=True, exist_ok=True)
    (Path(args.results) / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    summary["train"] = train(args, end)
    summary["seconds"] = round(time.time() - t0, 1)
    (Path(args.results) / "summary.json").write_text(json.dumps(summary, indent=1) + "\n")
    log(f"done in {summary['seconds']} s")


if __name__ == "__main__":
    main()
