"""Training ClipNet (LDR -> HDR, :mod:`phyir.nets.clipnet`) on simulated photographs of HDR panoramas.

``python -m phyir.learn.train_clipnet --hdri ../shared/hdri-indoor --synth data/geo128 --out runs/clipnet
--minutes 60``: resumable (run it again to continue), a checkpoint every ``--ckpt-every`` steps and
at the end, one JSON line per step in ``OUT/log.jsonl`` (losses, CPU seconds) and the validation
split's figures every ``--val-every`` steps. ``--ship FILE`` writes the float16 weights users get.

Loss per image, over the pixels the photograph clipped (weights :func:`clip_weight` x solid angle):
the mean |log luminance| error, plus the |log| ratio of their total energy (what lights a sphere).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch
from torch import Tensor

from phyir import pano
from phyir.color import luminance
from phyir.learn import ldr_pairs as P
from phyir.nets.clipnet import ClipNet, apply_gain, clip_weight

EPS = 1e-4


def _clipped(ldr: Tensor, log_gain: Tensor, target: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Per pixel [B,H,W]: the clip weight x solid angle, the recovered and the true luminance."""
    H, W = ldr.shape[-2:]
    w = clip_weight(ldr)[:, 0] * pano.solid_angles(H, W, ldr.device, ldr.dtype)
    return w, luminance(apply_gain(ldr, log_gain)), luminance(target)


def _total(x: Tensor) -> Tensor:
    return x.flatten(1).sum(1)


def clipped_losses(ldr: Tensor, log_gain: Tensor, target: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """``(pixel, energy, has)`` per image [B]: the weighted mean |log L_pred - log L_true| and the
    |log| ratio of the clipped energy, and whether the image has clipped pixels at all."""
    w, lp, lt = _clipped(ldr, log_gain, target)
    ws = _total(w)
    pixel = _total(w * (torch.log(lp + EPS) - torch.log(lt + EPS)).abs()) / ws.clamp_min(1e-12)
    energy = (torch.log(_total(w * lp) + 1e-12) - torch.log(_total(w * lt) + 1e-12)).abs()
    return pixel, energy, ws > 1e-6


def energy_ratios(ldr: Tensor, log_gain: Tensor, target: Tensor) -> Tensor:
    """Recovered / true energy of each image's clipped pixels [B] (NaN where none clipped)."""
    w, lp, lt = _clipped(ldr, log_gain, target)
    ep, et = _total(w * lp), _total(w * lt)
    return torch.where(et > 0, ep / et.clamp_min(1e-30), torch.full_like(et, math.nan))


@torch.no_grad()
def validate(model: ClipNet, images: list[Tensor], size: tuple[int, int]) -> dict[str, float]:
    """The validation panoramas through the evaluation's fixed camera: per image the clipped energy
    ratio (ours, and the naive LDR's), their medians and the share within a factor of 2."""
    model.eval()
    pairs = [P.fixed_photograph(x) for x in images]
    ldr = torch.stack([pano.resize_area(a, *size) for a, _ in pairs])
    target = torch.stack([pano.resize_area(b, *size) for _, b in pairs])
    ours = energy_ratios(ldr, model(ldr), target)
    naive = energy_ratios(ldr, torch.zeros_like(ldr[:, :1]), target)
    ok = ~torch.isnan(ours)
    model.train()
    return {"val_energy_ratio_median": float(ours[ok].median()),
            "val_naive_ratio_median": float(naive[ok].median()),
            "val_within_2x": float(((ours[ok] > 0.5) & (ours[ok] < 2)).float().mean()),
            "val_ratios": [round(float(r), 3) for r in ours]}


def _args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m phyir.learn.train_clipnet",
                                 description=__doc__.split("\n")[0])
    ap.add_argument("--hdri", required=True,
                    help="folder of real HDR panoramas (its validation split is held out)")
    ap.add_argument("--synth", help="a phyir synth folder: its rooms' images as more HDR panoramas")
    ap.add_argument("--synth-limit", type=int, default=2000)
    ap.add_argument("--out", required=True)
    ap.add_argument("--minutes", type=float, default=30.0)
    ap.add_argument("--steps", type=int, default=10**9)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--size", default="128x256", help="training resolution HxW")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--ckpt-every", type=int, default=200)
    ap.add_argument("--val-every", type=int, default=200)
    ap.add_argument("--ship", help="write the float16 weights here at the end")
    ap.add_argument("--init", help="start from these weights (a --ship file) when OUT has no checkpoint")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    a = _args(argv)
    size = tuple(int(v) for v in a.size.split("x"))
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    real = P.load_panoramas(P.hdr_files(a.hdri, "train"), (2 * size[0], 2 * size[1]))
    synth = P.synthetic_images(a.synth, size, a.synth_limit) if a.synth else []
    val = P.load_panoramas(P.hdr_files(a.hdri, "val"), (2 * size[0], 2 * size[1]))
    model = ClipNet()
    opt = torch.optim.Adam(model.parameters(), lr=a.lr)
    ckpt = out / "clipnet.pt"
    step, cpu = 0, 0.0
    gen = torch.Generator().manual_seed(a.seed)
    if ckpt.is_file():
        st = torch.load(ckpt, map_location="cpu", weights_only=False)
        model.load_state_dict(st["model"])
        opt.load_state_dict(st["opt"])
        step, cpu = st["step"], st["cpu_seconds"]
        gen.set_state(st["gen"])
    elif a.init:
        from phyir.errors import InputError
        from phyir.lighting.ldr_to_hdr import load_clipnet

        start = load_clipnet(a.init)
        if start is None:
            raise InputError(a.init, "no such ClipNet weights file (--init)")
        model.load_state_dict(start.state_dict())
    print(f"clipnet: {len(real)} real + {len(synth)} synthetic panoramas, {len(val)} held out; step {step}",
          flush=True)

    def save() -> None:
        torch.save({"model": model.state_dict(), "opt": opt.state_dict(), "step": step, "cpu_seconds": cpu,
                    "gen": gen.get_state()}, ckpt.with_suffix(".tmp"))
        ckpt.with_suffix(".tmp").replace(ckpt)

    t_end = time.monotonic() + 60 * a.minutes
    with open(out / "log.jsonl", "a") as log:
        while step < a.steps and time.monotonic() < t_end:
            c0 = time.process_time()
            half = a.batch // 2 if synth else 0
            ldr, target = P.batch(real, a.batch - half, gen, size)
            if half:
                l2, t2 = P.batch(synth, half, gen, size)
                ldr, target = torch.cat((ldr, l2)), torch.cat((target, t2))
            pixel, energy, has = clipped_losses(ldr, model(ldr), target)
            loss = ((pixel + energy) * has).sum() / has.sum().clamp_min(1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            step += 1
            cpu += time.process_time() - c0
            n = has.sum().clamp_min(1)
            row = {"step": step, "loss": loss.item(), "pixel": float((pixel.detach() * has).sum() / n),
                   "energy": float((energy.detach() * has).sum() / n), "cpu_hours": cpu / 3600}
            if step % a.val_every == 0:
                row |= validate(model, val, size)
            log.write(json.dumps(row) + "\n")
            log.flush()
            if step % a.ckpt_every == 0:
                save()
    save()
    if a.ship:
        from phyir.lighting.ldr_to_hdr import save_clipnet

        save_clipnet(model, a.ship, {"steps": step, "cpu_hours": round(cpu / 3600, 3), "size": a.size,
                                     "hdri_train": [p.name for p in P.hdr_files(a.hdri, "train")],
                                     "synth": a.synth, "held_out": list(P.HDRI_VALIDATION)})
    print(f"clipnet: stopped at step {step} ({cpu / 3600:.2f} CPU-hours); run again to resume", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
