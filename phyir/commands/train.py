"""``phyir train``: one stage of the four-stage PhyIR training (docs/training.md)."""

from __future__ import annotations

import argparse
import json

from phyir.commands import options as types

HELP = "train GMNet / LNet / GSNet in the stages of the paper (resumable, multi-GPU via torchrun)"


def _size(text: str) -> tuple[int, int] | str:
    if text.lower() == "native":
        return "native"
    try:
        H, W = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected HxW, e.g. 128x256, got {text!r}") from None
    return H, W


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", help="JSON or TOML file of training options (flags below override it)")
    p.add_argument("--data", help="dataset folder written by `phyir synth` (scene files + manifest)")
    p.add_argument("--stage", choices=("gm", "light", "joint", "gs"), help="training stage (default gm)")
    p.add_argument("--out", type=types.path,
                   help="run folder; each stage writes <out>/<stage>/ (default runs/phyir)")
    p.add_argument("--model", choices=("lite", "full"), help="architecture for a fresh start (default lite)")
    p.add_argument("--init", help="weights to start from (default: the previous stage's export; "
                                  "'scratch' for random)")
    p.add_argument("--epochs", type=types.integer, help="override the stage's epoch count")
    p.add_argument("--lr", type=types.finite, help="override the stage's learning rate")
    p.add_argument("--batch-size", type=types.integer, help="override the stage's global batch size")
    p.add_argument("--size", type=_size, help="training resolution HxW (default 128x256; 'native')")
    p.add_argument("--probe-grid", type=_size, help="merge ground-truth probes to this HpxWp grid "
                                                    "(default 16x32; 'native' keeps the files' grid)")
    p.add_argument("--schedule", choices=("constant", "cosine"))
    p.add_argument("--seed", type=types.integer)
    p.add_argument("--workers", type=types.integer,
                   help="data-loading worker processes per training process")
    p.add_argument("--device", choices=("auto", "cpu", "cuda"))
    p.add_argument("--no-amp", dest="amp", action="store_const", const=False, help="disable mixed precision")
    p.add_argument("--no-augment", dest="augment", action="store_const", const=False)
    p.add_argument("--ldr-share", type=types.finite,
                   help="share of training images photographed by a random camera, 8-bit (default 0.3)")
    p.add_argument("--no-val", dest="val", action="store_const", const=False)
    p.add_argument("--max-minutes", type=types.finite,
                   help="stop with a checkpoint after this many minutes")
    p.add_argument("--max-steps", type=types.integer, help="stop with a checkpoint at this global step")
    p.add_argument("--ckpt-every", type=types.integer, help="checkpoint every N steps (default 200)")
    p.add_argument("--no-cache", dest="cache", action="store_const", const=False,
                   help="don't keep resampled scenes in <out>/cache/")
    p.add_argument("--limit-train", type=types.integer, help="use only the first N training scenes")
    p.add_argument("--limit-val", type=types.integer, help="use only the first N validation scenes")
    p.add_argument("--no-progress", dest="progress", action="store_const", const=False)
    p.add_argument("--train-only", action="append", metavar="PREFIX",
                   help="train only parameters under this name (repeatable; e.g. gmnet.decoders.metallic)")
    p.add_argument("--loss", action="append", metavar="KEY=VALUE", type=_loss_option,
                   help="a loss option (repeatable; e.g. metallic_loss=l2, sc_sigma=0.2)")
    p.add_argument("--reinit", action="append", metavar="MODULE",
                   help="re-initialise this module before training (repeatable)")


def _loss_option(text: str) -> tuple[str, object]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        return key, json.loads(value)
    except json.JSONDecodeError:
        return key, value  # a bare word: a string option such as metallic_loss=bce


def options(args: argparse.Namespace) -> dict:
    """Training options: the ``--config`` file's, overridden by the flags given."""
    from phyir.learn.train import load_config_file

    opts = load_config_file(args.config) if args.config else {}
    keys = ("data", "stage", "out", "model", "init", "epochs", "lr", "batch_size", "size", "probe_grid",
            "schedule", "seed", "workers", "device", "amp", "augment", "ldr_share", "val", "max_minutes",
            "max_steps", "ckpt_every", "cache", "limit_train", "limit_val", "progress", "train_only",
            "reinit")
    for k in keys:
        v = getattr(args, k, None)
        if v is not None:
            opts[k] = None if v == "native" else v
    if getattr(args, "loss", None):
        opts["loss"] = {**opts.get("loss", {}), **dict(args.loss)}
    return opts


def run(args: argparse.Namespace) -> int:
    from phyir.learn.distributed import teardown_dist
    from phyir.learn.train import TrainConfig, train

    try:
        result = train(TrainConfig.from_dict(options(args)))
    finally:
        teardown_dist()
    return 0 if result["status"] in ("done", "stopped") else 1
