"""What a training run logs: ``log.jsonl`` per step, ``val.jsonl`` per epoch, TensorBoard when it is
installed, a progress bar; logs are cut back to the checkpoint a run resumes from."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from phyir.learn.config import TrainConfig
from phyir.learn.distributed import Dist


def progress_bar(cfg: TrainConfig, d: Dist, total: int, initial: int, desc: str):
    if not (cfg.progress and d.main):
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, leave=False, dynamic_ncols=True)


def tensorboard(path: Path, step: int):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard not installed: logs go to the jsonl files only
        return None
    return SummaryWriter(str(path), purge_step=step or None)


def truncate_log(path: Path, upto: int, key: str = "step") -> None:
    """Drop lines logged after the checkpoint we resume from (a killed run logged past it)."""
    if not path.is_file():
        return
    keep = [ln for ln in path.read_text().splitlines() if ln.strip() and json.loads(ln)[key] <= upto]
    path.write_text("".join(ln + "\n" for ln in keep))


def log_step(path: Path, writer, step: int, epoch: int, loss: float, terms: dict, lr: float,
              every: int) -> None:
    with open(path, "a") as f:
        f.write(json.dumps({"step": step, "epoch": epoch, "loss": loss, **terms, "lr": lr}) + "\n")
    if writer is not None and (step % every == 0 or step == 1):
        writer.add_scalar("train/loss", loss, step)
        for k, v in terms.items():
            writer.add_scalar(f"train/{k}", v, step)
        writer.add_scalar("train/lr", lr, step)


def log_val(path: Path, writer, epoch: int, step: int, m: dict) -> None:
    with open(path, "a") as f:
        f.write(json.dumps({"epoch": epoch, "step": step, **m}) + "\n")
    if writer is not None:
        for k, v in m.items():
            writer.add_scalar(f"val/{k}", v, step)
    print(f"  val epoch {epoch}: " + ", ".join(f"{k} {v:.4g}" for k, v in m.items()), file=sys.stderr)
