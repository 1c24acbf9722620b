"""Training options: the four stages of supplement B.1 and :class:`TrainConfig` (docs/training.md)."""

from __future__ import annotations

import dataclasses
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

from phyir.errors import InputError, PhyIRError
from phyir.learn.losses import STAGE_WEIGHTS, LossOptions, LossWeights
from phyir.shading.render import METHODS as RENDER_METHODS

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


# bounds of the numeric options (docs/robustness.md, "train"): name -> (lo, hi, integer); checked
# by TrainConfig.check whether they come from flags or a --config file
BOUNDS: dict[str, tuple[float, float, bool]] = {
    "epochs": (1, 1_000_000, True), "lr": (1e-12, 10.0, False), "batch_size": (1, 65536, True),
    "grad_clip": (0.0, 1e9, False), "seed": (0, 2**63 - 1, True), "workers": (0, 256, True),
    "max_minutes": (1e-3, 1e8, False), "max_steps": (1, 10**12, True), "ckpt_every": (1, 10**12, True),
    "log_every": (1, 10**12, True), "limit_train": (1, 10**12, True), "limit_val": (1, 10**12, True),
    "ldr_share": (0.0, 1.0, False),
}
MAX_TRAIN_SIZE = (1024, 2048)  # training resolution (multiples of 32, the encoder's stride)
MAX_TRAIN_SIDE = 4096  # probe grid, per side
# numeric loss options (--loss KEY=VALUE): key -> (lo, hi, integer); every loss weight is in 0..1e6
LOSS_BOUNDS = {"si_lambda": (0.0, 1.0, False), "sc_sigma": (1e-6, 1e3, False), "render_spp": (1, 4096, True)}
LOSS_CHOICES = {"depth_mode": ("l2", "scale_invariant"), "render_method": RENDER_METHODS,
                "metallic_loss": ("l2", "bce")}
CHOICES = {"schedule": ("constant", "cosine"), "device": ("auto", "cpu", "cuda"),
           "model": ("lite", "full", "effnet")}
# options that change what a resumed run computes: resuming with other values is refused
# (epochs may grow: a stage can be continued)
RESUME_FIXED = ("stage", "model", "init", "lr", "batch_size", "size", "probe_grid", "schedule",
                "grad_clip", "seed", "augment", "ldr_share", "limit_train", "loss", "train_only", "reinit",
                "weights")


_STRINGS = ("data", "stage", "out", "model", "init", "schedule", "device")  # TrainConfig's text fields


def option_name(key: str) -> str:
    return "--" + key.replace("_", "-")


def _check_number(key: str, v, bounds: tuple[float, float, bool] | None = None, name: str = "") -> None:
    import math

    lo, hi, integer = bounds or BOUNDS[key]
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and lo <= v <= hi
    if not ok or (integer and v != int(v)):
        kind = "an integer" if integer else "a number"
        raise InputError(name or option_name(key), f"expected {kind} in {lo:g}..{hi:g}, got {v!r}")


def _check_pair(key: str, v, hi: tuple[int, int] = (MAX_TRAIN_SIDE, MAX_TRAIN_SIDE), multiple: int = 1,
                name: str = "") -> None:
    ok = isinstance(v, (tuple, list)) and len(v) == 2 and all(
        isinstance(x, int) and not isinstance(x, bool) and 1 <= x <= m and x % multiple == 0
        for x, m in zip(v, hi))
    if not ok:
        extra = f", multiples of {multiple}" if multiple > 1 else ""
        raise InputError(name or option_name(key), f"expected HxW, integers up to {hi[0]}x{hi[1]}{extra}, "
                                                   f"got {v!r}")


def _check_loss(w: LossWeights, opts: LossOptions) -> None:
    """Loss weights finite in 0..1e6; loss options in their bounds and choices (``--loss KEY``)."""
    for key, v in dataclasses.asdict(w).items():
        _check_number(key, v, (0.0, 1e6, False), f"weights.{key}")
    for key, bounds in LOSS_BOUNDS.items():
        _check_number(key, getattr(opts, key), bounds, f"--loss {key}")
    for key, allowed in LOSS_CHOICES.items():
        if getattr(opts, key) not in allowed:
            raise InputError(f"--loss {key}", f"{key} must be {' or '.join(map(repr, allowed))}, "
                                              f"not {getattr(opts, key)!r}")
    _check_pair("render_size", list(opts.render_size), MAX_TRAIN_SIZE, name="--loss render_size")


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
    ldr_share: float = 0.3  # share of training images photographed by a random camera (8-bit LDR)
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
        # [issue 22, class 8] a config file's values of the wrong type: one line naming the option
        # (``"data": 5`` was a TypeError traceback, ``"train_only": "gmnet"`` five one-letter prefixes)
        for k in _STRINGS:
            if d.get(k) is not None and not isinstance(d[k], str):
                raise InputError(option_name(k), f"expected a string, got {json.dumps(d[k])[:40]}")
        for k in ("size", "probe_grid", "train_only", "reinit"):
            if d.get(k) is not None:
                if not isinstance(d[k], (list, tuple)):
                    raise InputError(option_name(k), f"expected a list, got {json.dumps(d[k])[:40]}")
                d[k] = tuple(d[k])
        for k in ("train_only", "reinit"):
            if d.get(k) is not None and not all(isinstance(x, str) for x in d[k]):
                raise InputError(option_name(k), f"expected module names, got {json.dumps(d[k])[:40]}")
        for k in ("loss", "weights"):
            if d.get(k) is not None and not isinstance(d[k], dict):
                raise InputError(option_name(k), f"expected a table of KEY = VALUE, got "
                                                 f"{json.dumps(d[k])[:40]}")
        return TrainConfig(**d)

    def check(self) -> None:
        """Refuse out-of-range or non-finite numbers and unknown choices, naming the option (one
        line); 0 is never read as "the default" (``--batch-size 0`` used to become 8)."""
        for key in BOUNDS:
            v = getattr(self, key)
            if v is not None:
                _check_number(key, v)
        if self.size is not None:
            _check_pair("size", self.size, MAX_TRAIN_SIZE, multiple=32)
        if self.probe_grid is not None:
            _check_pair("probe_grid", self.probe_grid)
        for key, allowed in CHOICES.items():
            if getattr(self, key) not in allowed:
                raise InputError(option_name(key), f"expected one of {', '.join(allowed)}, "
                                                   f"got {getattr(self, key)!r}")

    def resolved(self) -> tuple[Stage, LossWeights, LossOptions]:
        if self.stage not in STAGES:
            raise PhyIRError(f"unknown stage {self.stage!r} (choose from {', '.join(STAGE_ORDER)})")
        self.check()
        st = STAGES[self.stage]
        pick = {k: getattr(self, k) for k in ("epochs", "lr", "batch_size") if getattr(self, k) is not None}
        st = dataclasses.replace(st, **pick)
        try:
            w = dataclasses.replace(STAGE_WEIGHTS[self.stage], **self.weights)
            lo = dict(self.loss)
            if "render_size" in lo:
                lo["render_size"] = tuple(lo["render_size"])
            opts = dataclasses.replace(LossOptions(), **lo)
        except TypeError as e:
            raise PhyIRError(f"bad loss option: {e}") from None
        _check_loss(w, opts)
        return st, w, opts


def resume_changes(stored: dict, cfg: TrainConfig) -> list[str]:
    """``--option value (checkpoint: value)`` for each :data:`RESUME_FIXED` option whose value
    differs from the one a checkpoint's run was started with (``stored``: its ``config``)."""
    from phyir.learn.checkpoints import jsonable

    now = jsonable(dataclasses.asdict(cfg))
    out = []
    for key in RESUME_FIXED:
        if key in stored and stored[key] != now[key]:
            out.append(f"{option_name(key)} {_shown(now[key])} (checkpoint: {_shown(stored[key])})")
    return out


def _shown(v) -> str:
    if v is None:
        return "default"
    if isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) for x in v):
        return f"{v[0]}x{v[1]}"
    return json.dumps(v) if not isinstance(v, str) else v


MAX_CONFIG_BYTES = 1 << 20  # a training config is a few hundred bytes; more is not a config


def load_config_file(path: str | os.PathLike) -> dict:
    """Options from a JSON or TOML file (keys = :class:`TrainConfig` fields).  [issue 22] The file
    must be a regular file (a FIFO would block, ``/dev/zero`` never end) of at most
    :data:`MAX_CONFIG_BYTES`, holding one object (a table)."""
    from phyir.io.files import open_input

    p = Path(path)
    try:
        with open_input(p, "config file") as f:
            data = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as e:
        raise InputError(p, f"cannot read config ({e.strerror})") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise InputError(p, f"not a config file (larger than {MAX_CONFIG_BYTES >> 20} MiB)")
    kind = p.suffix.lstrip(".") or "JSON"
    try:
        text = data.decode("utf-8-sig")  # a UTF-8 byte-order mark is allowed
        if p.suffix == ".toml":
            import tomllib

            doc = tomllib.loads(text)
        else:
            doc = json.loads(text)
    except RecursionError:
        raise InputError(p, f"not a valid {kind} config (nested too deeply)") from None
    except Exception as e:
        problem = str(e).splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(p, f"not a valid {kind} config ({problem})") from None
    if not isinstance(doc, dict):
        raise InputError(p, f"not a valid {kind} config (a {type(doc).__name__}, not an object of options)")
    return doc
