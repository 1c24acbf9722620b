"""Parameter counts, FLOPs and CPU/GPU time of the PhyIR networks, per sub-network.

    python -m phyir.bench.profile [--sizes lite full] [--res 256x512] [--repeat 5] [--json FILE]
    python -m phyir.bench.profile --train-steps [--sizes lite] [--res 128x256] [--probe-grid 16x32]

FLOPs are counted with ``torch.utils.flop_counter.FlopCounterMode`` (convs and matmuls, 2 FLOPs per
multiply-add; norms, activations and the guided filter's box sums are not counted).  Times are the
median of ``repeat`` forward passes at batch size 1 under ``torch.no_grad`` after one warm-up:
``ms`` is wall time, ``cpu_ms`` the process's CPU time (all threads; on a machine shared with other
jobs it is the steadier number, and with one thread it is what the wall time would be alone).
Supplement Table 1 (V100, 256x512 input): GMNet 18 ms, LNet 4 ms, GSNet 8 ms.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from phyir.nets.model import PhyIRModel, count_parameters

PAPER_MS = {"gmnet": 18.0, "lnet": 4.0, "gsnet": 8.0}


def subnet_calls(model: PhyIRModel, image: torch.Tensor):
    """Callables running each sub-network on realistic inputs (earlier stages precomputed)."""
    with torch.no_grad():
        gm = model.gmnet(image)
    grid = model.default_grid(*image.shape[-2:])
    return {
        "gmnet": lambda: model.gmnet(image),
        "lnet": lambda: model.light(image, gm, grid),
        "gsnet": lambda: model.gsnet(image, gm),
    }


def profile(size: str, H: int = 256, W: int = 512, repeat: int = 5, device: str = "cpu") -> dict:
    """{sub-network: {params, gflops, ms}} plus a ``total`` row for one H x W panorama."""
    torch.manual_seed(0)
    model = PhyIRModel(size).to(device).eval()
    image = torch.rand(1, 3, H, W, device=device).contiguous(memory_format=torch.channels_last)
    rows = {}
    for name, fn in subnet_calls(model, image).items():
        with torch.no_grad():
            counter = FlopCounterMode(display=False)
            with counter:
                fn()
            fn()  # warm-up
            times, cpu = [], []
            for _ in range(repeat):
                if device.startswith("cuda"):
                    torch.cuda.synchronize()
                t0, c0 = time.perf_counter(), time.process_time()
                fn()
                if device.startswith("cuda"):
                    torch.cuda.synchronize()
                times.append(1000 * (time.perf_counter() - t0))
                cpu.append(1000 * (time.process_time() - c0))
        rows[name] = {"params": count_parameters(getattr(model, name)),
                      "gflops": counter.get_total_flops() / 1e9, "ms": statistics.median(times),
                      "cpu_ms": statistics.median(cpu), "paper_v100_ms": PAPER_MS[name]}
    rows["total"] = {k: sum(r[k] for r in rows.values())
                     for k in ("params", "gflops", "ms", "cpu_ms", "paper_v100_ms")}
    return {"size": size, "resolution": f"{H}x{W}", "device": device, "threads": torch.get_num_threads(),
            "rows": rows}


def _random_batch(B: int, H: int, W: int, grid: tuple[int, int], probe_size: tuple[int, int]):
    """A batch shaped like training data (values are irrelevant to the cost)."""
    import torch.nn.functional as F

    from phyir.scene import PanoScene

    g = torch.Generator().manual_seed(0)

    def r(*s: int) -> torch.Tensor:
        return torch.rand(*s, generator=g)

    return PanoScene(image=r(B, 3, H, W), depth=1 + 3 * r(B, 1, H, W),
                     normal=F.normalize(r(B, 3, H, W) - 0.5, dim=1), albedo=r(B, 3, H, W),
                     roughness=r(B, 1, H, W), metallic=r(B, 1, H, W), probes=r(B, *grid, 3, *probe_size),
                     masks={"emission": (r(B, 1, H, W) > 0.98).float()})


def profile_train_steps(size: str = "lite", H: int = 128, W: int = 256, grid: tuple[int, int] = (16, 32),
                        repeat: int = 3) -> dict:
    """Seconds per optimisation step of every stage at its default batch size (phyir.learn.train.STAGES):
    forward, losses with the stage's weights, backward, Adam step."""

    from phyir.learn.losses import STAGE_WEIGHTS, LossOptions, total_loss
    from phyir.learn.train import STAGES, StageForward

    torch.manual_seed(0)
    model = PhyIRModel(size)
    opts = LossOptions()
    rows = {}
    for name, st in STAGES.items():
        for sub in ("gmnet", "lnet", "gsnet"):
            getattr(model, sub).requires_grad_(sub in st.train)
        params = [p for p in model.parameters() if p.requires_grad]
        opt = torch.optim.Adam(params, lr=st.lr)
        net = StageForward(model, st)
        batch = _random_batch(st.batch_size, H, W, grid, model.config.probe_size)
        wall, cpu = [], []
        for i in range(repeat + 1):
            t0, c0 = time.perf_counter(), time.process_time()
            loss, _ = total_loss(net(batch.image, grid), batch, STAGE_WEIGHTS[name], opts, refined=st.refine)
            opt.zero_grad()
            loss.backward()
            opt.step()
            if i:  # the first step warms up
                wall.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
        rows[name] = {"batch": st.batch_size, "s_per_step": statistics.median(wall),
                      "cpu_s_per_step": statistics.median(cpu), "epochs": st.epochs,
                      "render": f"{opts.render_method} at {opts.render_size[0]}x{opts.render_size[1]}"}
    return {"size": size, "resolution": f"{H}x{W}", "probe_grid": f"{grid[0]}x{grid[1]}",
            "threads": torch.get_num_threads(), "rows": rows}


def format_train_table(res: dict, scenes: int) -> str:
    lines = [f"{res['size']} model, {res['resolution']}, probe grid {res['probe_grid']}, "
             f"{res['threads']} threads; epoch time for {scenes} training scenes",
             "| stage | batch | s/step (wall) | s/step (CPU) | min/epoch (CPU) | epochs |",
             "| --- | ---: | ---: | ---: | ---: | ---: |"]
    for name, r in res["rows"].items():
        ep = r["cpu_s_per_step"] * (scenes // r["batch"]) / 60
        lines.append(f"| {name} | {r['batch']} | {r['s_per_step']:.2f} | {r['cpu_s_per_step']:.2f} | "
                     f"{ep:.1f} | {r['epochs']} |")
    return "\n".join(lines)


def format_table(results: list[dict]) -> str:
    lines = ["| size | net | params | GFLOPs | ms (wall) | ms (CPU) | paper V100 ms |",
             "| --- | --- | ---: | ---: | ---: | ---: | ---: |"]
    for res in results:
        for name, r in res["rows"].items():
            lines.append(f"| {res['size']} | {name} | {r['params'] / 1e6:.2f} M | {r['gflops']:.1f} | "
                         f"{r['ms']:.0f} | {r['cpu_ms']:.0f} | {r['paper_v100_ms']:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["lite", "full"])
    ap.add_argument("--res", default="256x512", help="HxW of the panorama")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, help="torch threads (default: torch's)")
    ap.add_argument("--json", help="also write the results here")
    ap.add_argument("--train-steps", action="store_true", help="time one training step of every stage")
    ap.add_argument("--probe-grid", default="16x32", help="probe grid of the training step")
    ap.add_argument("--scenes", type=int, default=2000, help="training-set size for the epoch estimate")
    a = ap.parse_args(argv)
    H, W = (int(v) for v in a.res.lower().split("x"))
    if a.threads:
        torch.set_num_threads(a.threads)
    if a.train_steps:
        grid = tuple(int(v) for v in a.probe_grid.lower().split("x"))
        results = [profile_train_steps(s, H, W, grid, a.repeat) for s in a.sizes]
        for res in results:
            print(format_train_table(res, a.scenes))
        if a.json:
            with open(a.json, "w") as f:
                json.dump(results, f, indent=1)
        return 0
    results = [profile(s, H, W, a.repeat, a.device) for s in a.sizes]
    print(f"{a.res} panorama, batch 1, device {a.device}, {torch.get_num_threads()} threads")
    print(format_table(results))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
