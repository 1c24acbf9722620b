"""Training options: the four stages of supplement B.1 and :class:`TrainConfig` (docs/training.md)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from phyir.errors import InputError, PhyIRError
from phyir.learn.losses import STAGE_WEIGHTS, LossOptions, LossWeights

STAGE_ORDER = ("gm", "light", "joint", "gs")
CHECKPOINT = "checkpoint.pt"
EXPORT = "model.safetensors"


@dataclass(frozen=True)
class Stage:
    epochs: int
    lr: float
    batch_size: int
    train: tuple[str, ...]  # sub-networks optimised; the others are frozen
    light: bool  # run LNet
    refine: bool  # run GSNet (its outputs feed the material terms)


STAGES: dict[str, Stage] = {  # supplement B.1
    "gm": Stage(120, 1e-4, 8, ("gmnet",), light=False, refine=False),
    "light": Stage(90, 1e-4, 4, ("lnet",), light=True, refine=False),
    "joint": Stage(10, 1e-5, 4, ("gmnet", "lnet"), light=True, refine=False),
    "gs": Stage(80, 5e-4, 16, ("gsnet",), light=False, refine=True),
}


@dataclass
class TrainConfig:
    stage: str = "gm"
    data: str | None = None  # dataset folder (scene files + manifest)
    out: str = "runs/phyir"
    model: str = "lite"  # architecture size (ignored when resuming or initialising from weights)
    init: str | None = None  # weights to start from; None = previous stage's export; "scratch"
    epochs: int | None = None  # None = the stage's default (supplement B.1)
    lr: float | None = None
    batch_size: int | None = None  # global batch over all processes
    size: tuple[int, int] | None = (128, 256)  # training resolution; None = the files' own
    probe_grid: tuple[int, int] | None = (16, 32)  # ground-truth probes merged to this grid; None = as stored
    schedule: str = "constant"  # "constant" (paper) or "cosine"
    grad_clip: float = 10.0
    seed: int = 0
    augment: bool = True
    workers: int = 0
    device: str = "auto"  # auto | cpu | cuda
    amp: bool = True  # mixed precision (CUDA only)
    max_minutes: float | None = None  # stop (with a checkpoint) after this much wall time
    max_steps: int | None = None  # stop (with a checkpoint) at this global step
    ckpt_every: int = 200  # steps; a checkpoint is also written every epoch and on stop
    log_every: int = 10
    val: bool = True
    cache: bool = True  # keep resampled scenes in <out>/cache/ (float16) for the next epochs
    limit_train: int | None = None
    limit_val: int | None = None
    progress: bool = True
    loss: dict = field(default_factory=dict)  # LossOptions overrides
    # fine-tuning part of a stage's sub-networks: parameter-name prefixes that train (empty: all of
    # the stage's sub-networks), and modules re-initialised first (e.g. a dead output head)
    train_only: tuple[str, ...] = ()
    reinit: tuple[str, ...] = ()
    weights: dict = field(default_factory=dict)  # LossWeights overrides

    @staticmethod
    def from_dict(d: dict) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(TrainConfig)}
        bad = sorted(set(d) - known)
        if bad:
            raise PhyIRError(f"unknown training option(s): {', '.join(bad)}")
        d = dict(d)
        for k in ("size", "probe_grid", "train_only", "reinit"):
            if d.get(k) is not None:
                d[k] = tuple(d[k])
        return TrainConfig(**d)

    def resolved(self) -> tuple[Stage, LossWeights, LossOptions]:
        if self.stage not in STAGES:
            raise PhyIRError(f"unknown stage {self.stage!r} (choose from {', '.join(STAGE_ORDER)})")
        st = STAGES[self.stage]
        st = dataclasses.replace(st, epochs=self.epochs or st.epochs, lr=self.lr or st.lr,
                                 batch_size=self.batch_size or st.batch_size)
        try:
            w = dataclasses.replace(STAGE_WEIGHTS[self.stage], **self.weights)
            lo = dict(self.loss)
            if "render_size" in lo:
                lo["render_size"] = tuple(lo["render_size"])
            opts = dataclasses.replace(LossOptions(), **lo)
        except TypeError as e:
            raise PhyIRError(f"bad loss option: {e}") from None
        if opts.metallic_loss not in ("l2", "bce"):
            raise PhyIRError(f"bad loss option: metallic_loss must be 'l2' or 'bce', "
                             f"not {opts.metallic_loss!r}")
        return st, w, opts


def load_config_file(path: str | os.PathLike) -> dict:
    """Options from a JSON or TOML file (keys = :class:`TrainConfig` fields)."""
    p = Path(path)
    try:
        text = p.read_text()
    except OSError as e:
        raise InputError(p, f"cannot read config ({e.strerror})") from None
    try:
        if p.suffix == ".toml":
            import tomllib

            return tomllib.loads(text)
        return json.loads(text)
    except Exception as e:
        raise InputError(p, f"not a valid {p.suffix.lstrip('.') or 'JSON'} config ({e})") from None
