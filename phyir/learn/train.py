"""Training of PhyIR in the four stages of supplement B.1 (see docs/training.md).

    gm     GMNet alone                      120 epochs, Adam lr 1e-4, batch 8
    light  LNet, GMNet frozen                90 epochs, Adam lr 1e-4, batch 4
    joint  GMNet + LNet fine-tuned           10 epochs, Adam lr 1e-5, batch 4
    gs     GSNet, GMNet and LNet frozen      80 epochs, Adam lr 5e-4, batch 16

One run directory holds one folder per stage (``<out>/<stage>/``) with ``checkpoint.pt`` (latest,
resumable), ``model.safetensors`` + ``model.json`` (exported when the stage finishes), ``log.jsonl``
(training loss per step), ``val.jsonl`` (validation metrics per epoch) and ``tb/`` (TensorBoard).
A stage starts from the previous stage's exported weights (or ``init``).

Multi-process training: launch with ``torchrun --nproc_per_node=N -m phyir.cli train ...``;
gloo on CPU, NCCL on CUDA, a DistributedSampler shards every global batch.  ``batch_size`` is the
global batch, split evenly across processes, and all losses are per-sample means, so N processes
follow the same loss curve as one process with the same global batch.

Resuming is exact: the checkpoint holds model, optimiser, scheduler, grad-scaler, every process's
RNG states and the position (epoch, batch within the epoch); data order and augmentations are
functions of (seed, epoch, index).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import os
import random
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch
import torch.distributed as dist
from torch import Tensor, nn

from phyir.errors import InputError, PhyIRError
from phyir.learn.losses import STAGE_WEIGHTS, LossOptions, LossWeights, pick_output, total_loss
from phyir.nets.model import ModelConfig, PhyIRModel
from phyir.scene import PanoScene

STAGE_ORDER = ("gm", "light", "joint", "gs")
CHECKPOINT = "checkpoint.pt"
EXPORT = "model.safetensors"
CKPT_FORMAT = "phyir-checkpoint-1"


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


# ---------------------------------------------------------------------------------------------
# distributed helpers


@dataclass
class Dist:
    rank: int = 0
    world: int = 1
    local_rank: int = 0
    device: torch.device = torch.device("cpu")

    @property
    def main(self) -> bool:
        return self.rank == 0

    def all_mean(self, x: Tensor) -> Tensor:
        if self.world > 1:
            x = x.clone()
            dist.all_reduce(x)
            x /= self.world
        return x

    def any(self, flag: bool) -> bool:
        if self.world == 1:
            return flag
        t = torch.tensor([float(flag)], device=self.device)
        dist.all_reduce(t, op=dist.ReduceOp.MAX)
        return bool(t.item())

    def barrier(self) -> None:
        if self.world > 1:
            dist.barrier()


def setup_dist(device: str) -> Dist:
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local = int(os.environ.get("LOCAL_RANK", "0"))
    cuda = torch.cuda.is_available() and device != "cpu"
    if device == "cuda" and not torch.cuda.is_available():
        raise PhyIRError("--device cuda: no CUDA device is available")
    dev = torch.device(f"cuda:{local}") if cuda else torch.device("cpu")
    if cuda:
        torch.cuda.set_device(dev)
    if world > 1 and not dist.is_initialized():
        dist.init_process_group("nccl" if cuda else "gloo")
    if world > 1 and not cuda:  # share the cores between the processes of this machine
        local_world = int(os.environ.get("LOCAL_WORLD_SIZE", world))
        torch.set_num_threads(max(1, (os.cpu_count() or 1) // local_world))
    return Dist(rank, world, local, dev)


# ---------------------------------------------------------------------------------------------
# data


class EpochBatches:
    """Global batches of an epoch, sharded over processes by a DistributedSampler.

    With the sampler's interleaved split, batch k of every process together is exactly
    ``perm[k*B : (k+1)*B]`` of the epoch's permutation: the same global batches as one process.
    ``batches(epoch, start)`` skips the first ``start`` batches (resume inside an epoch).
    """

    def __init__(self, n: int, global_batch: int, d: Dist, seed: int, shuffle: bool = True):
        from torch.utils.data import DistributedSampler

        if global_batch % d.world:
            raise PhyIRError(f"batch size {global_batch} is not divisible by the {d.world} processes")
        if n < global_batch:
            raise PhyIRError(f"the training split has {n} scenes, fewer than one batch ({global_batch})")
        self.per_rank = global_batch // d.world
        self.sampler = DistributedSampler(range(n), num_replicas=d.world, rank=d.rank, shuffle=shuffle,
                                          seed=seed, drop_last=True)
        self.steps = len(self.sampler) // self.per_rank

    def batches(self, epoch: int, start: int = 0) -> list[list[int]]:
        self.sampler.set_epoch(epoch)
        idx = list(self.sampler)
        b = self.per_rank
        return [idx[i * b:(i + 1) * b] for i in range(start, self.steps)]


def make_datasets(cfg: TrainConfig, need_probes: bool):
    from phyir.learn.datasets import Augment, SceneDataset

    if not cfg.data:
        raise PhyIRError("no dataset: pass --data DIR (a folder written by `phyir synth`)")
    aug = Augment() if cfg.augment else None
    kw = {"size": cfg.size, "probe_grid": cfg.probe_grid, "seed": cfg.seed}
    if cfg.cache:
        import hashlib

        def fmt(t):
            return "x".join(map(str, t)) if t else "native"
        src = hashlib.sha1(str(Path(cfg.data).resolve()).encode()).hexdigest()[:8]
        kw["cache_dir"] = Path(cfg.out) / "cache" / f"{src}_{fmt(cfg.size)}_{fmt(cfg.probe_grid)}"
    train = SceneDataset(cfg.data, "train", augment=aug, limit=cfg.limit_train, **kw)
    val = None
    if cfg.val:
        try:
            val = SceneDataset(cfg.data, "val", limit=cfg.limit_val, **kw)
        except InputError:
            val = None  # no validation split
    probe = train[0]
    missing = [k for k in ("depth", "normal", "albedo", "roughness", "metallic") if getattr(probe, k) is None]
    if need_probes and probe.probes is None:
        missing.append("probes")
    if missing:
        raise InputError(train.files[0], f"training scenes lack layers {', '.join(missing)}")
    return train, val


# ---------------------------------------------------------------------------------------------
# checkpoints


def _rng_state(device: torch.device) -> dict:
    st = {"torch": torch.get_rng_state(), "python": random.getstate()}
    if device.type == "cuda":
        st["cuda"] = torch.cuda.get_rng_state(device)
    return st


def _set_rng_state(st: dict, device: torch.device) -> None:
    torch.set_rng_state(st["torch"])
    random.setstate(_tuplify(st["python"]))
    if device.type == "cuda" and "cuda" in st:
        torch.cuda.set_rng_state(st["cuda"], device)


def _tuplify(x):
    return tuple(_tuplify(v) for v in x) if isinstance(x, (list, tuple)) else x


def save_checkpoint(path: Path, state: dict) -> None:
    from phyir.io import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as tmp:
        torch.save(state, tmp)


def load_checkpoint(path: Path) -> dict:
    """A checkpoint written by :func:`save_checkpoint` (restricted unpickler: tensors and plain data)."""
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise InputError(path, f"unreadable checkpoint ({str(e).strip().splitlines()[0]})") from None
    if not isinstance(ck, dict) or ck.get("format") != CKPT_FORMAT:
        raise InputError(path, "not a PhyIR training checkpoint")
    return ck


# ---------------------------------------------------------------------------------------------
# training


class StageForward(nn.Module):
    """What DDP wraps: the stage's forward pass of the whole model."""

    def __init__(self, model: PhyIRModel, stage: Stage):
        super().__init__()
        self.model, self.light, self.refine = model, stage.light, stage.refine

    def forward(self, image: Tensor, grid: tuple[int, int] | None) -> dict[str, Tensor]:
        return self.model.forward_parts(image, grid, light=self.light, refine=self.refine)


def _reinit(model: PhyIRModel, names: tuple[str, ...]) -> None:
    """Re-initialise the parameters of the named modules (their ``reset_parameters``)."""
    modules = dict(model.named_modules())
    for name in names:
        if name not in modules:
            raise PhyIRError(f"reinit: no module {name!r} in the model (e.g. gmnet.decoders.metallic.out)")
        for m in modules[name].modules():
            if hasattr(m, "reset_parameters"):
                m.reset_parameters()


def _restrict_training(model: PhyIRModel, prefixes: tuple[str, ...]) -> None:
    """Freeze every parameter whose name starts with none of ``prefixes`` (no-op when empty)."""
    if not prefixes:
        return
    def under(name, prefix):
        return name == prefix or name.startswith(prefix + ".")
    trainable = [n for n, p in model.named_parameters() if p.requires_grad]
    for prefix in prefixes:
        if not any(under(n, prefix) for n in trainable):
            raise PhyIRError(f"train_only: {prefix!r} names no trainable parameter of this stage "
                             f"(e.g. gmnet.decoders.metallic)")
    for n, p in model.named_parameters():
        if not any(under(n, q) for q in prefixes):
            p.requires_grad_(False)


def _lr_lambda(schedule: str, total_steps: int):
    if schedule == "constant":
        return lambda step: 1.0
    if schedule == "cosine":
        return lambda step: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(step, total_steps) / total_steps))
    raise PhyIRError(f"unknown schedule {schedule!r} (constant or cosine)")


def _initial_weights(cfg: TrainConfig, model: PhyIRModel) -> str | None:
    """Load the stage's starting weights into ``model``; returns where they came from."""
    from phyir.learn.weights import load_into

    if cfg.init == "scratch" or (cfg.init is None and cfg.stage == "gm"):
        return None
    if cfg.init is not None:
        load_into(model, cfg.init)
        return cfg.init
    earlier = STAGE_ORDER[:STAGE_ORDER.index(cfg.stage)]
    for prev in reversed(earlier):
        p = Path(cfg.out) / prev / EXPORT
        if p.is_file():
            load_into(model, p)
            return str(p)
    raise PhyIRError(f"stage {cfg.stage!r} starts from the weights of an earlier stage, but none of "
                     f"{', '.join(str(Path(cfg.out) / s / EXPORT) for s in earlier)} exists: run "
                     f"--stage {earlier[-1]} first, or pass --init FILE (or --init scratch)")


def _model_config(cfg: TrainConfig) -> ModelConfig:
    """Architecture: from the starting weights when there are any, else the named size."""
    from phyir.learn.weights import read_weights

    src = cfg.init
    if src is None and cfg.stage != "gm":
        for prev in reversed(STAGE_ORDER[:STAGE_ORDER.index(cfg.stage)]):
            p = Path(cfg.out) / prev / EXPORT
            if p.is_file():
                src = str(p)
                break
    if src and src != "scratch":
        return ModelConfig.from_dict(read_weights(src)[1])
    return ModelConfig.named(cfg.model)


def _fit_probe_layout(mcfg: ModelConfig, scene: PanoScene) -> ModelConfig:
    """A fresh model predicts probes of the data's size, on the data's grid by default."""
    if scene.probes is None:
        return mcfg
    (H, W), (Hp, Wp) = scene.size, scene.probe_grid
    block = H // Hp if H % Hp == 0 and W % Wp == 0 and H // Hp == W // Wp else mcfg.probe_block
    return dataclasses.replace(mcfg, probe_size=scene.probe_size, probe_block=block)


def train(cfg: TrainConfig, datasets=None) -> dict:
    """Run (or resume) one stage.  ``datasets`` = (train, val) overrides ``cfg.data`` (tests).

    Returns a summary: ``status`` ("done" or "stopped"), ``step``, ``epoch``, ``losses`` (the global
    mean loss of each step of this run), ``val`` (last validation metrics), ``checkpoint``.
    """
    stage, weights, loss_opts = cfg.resolved()
    d = setup_dist(cfg.device)
    t_start = time.monotonic()
    stage_dir = Path(cfg.out) / cfg.stage
    ckpt_path = stage_dir / CHECKPOINT
    resume = load_checkpoint(ckpt_path) if ckpt_path.is_file() else None

    train_set, val_set = datasets if datasets is not None else make_datasets(cfg, stage.light)

    torch.manual_seed(cfg.seed)  # identical initialisation in every process
    mcfg = ModelConfig.from_dict(resume["model_config"]) if resume else _model_config(cfg)
    if not resume and (cfg.init is None and cfg.stage == "gm" or cfg.init == "scratch"):
        mcfg = _fit_probe_layout(mcfg, train_set[0])
    model = PhyIRModel(mcfg)
    init_from = None if resume else _initial_weights(cfg, model)
    model.to(d.device)
    for name in ("gmnet", "lnet", "gsnet"):
        trainable = name in stage.train
        getattr(model, name).requires_grad_(trainable)
        getattr(model, name).train(trainable)
    if not resume:
        _reinit(model, cfg.reinit)
    _restrict_training(model, cfg.train_only)
    params = [p for p in model.parameters() if p.requires_grad]

    batches = EpochBatches(len(train_set), stage.batch_size, d, cfg.seed)
    total_steps = stage.epochs * batches.steps
    opt = torch.optim.Adam(params, lr=stage.lr)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, _lr_lambda(cfg.schedule, total_steps))
    cuda = d.device.type == "cuda"
    amp_dtype = torch.bfloat16 if cuda and torch.cuda.is_bf16_supported() else torch.float16
    use_amp = cfg.amp and cuda
    scaler = torch.amp.GradScaler("cuda", enabled=use_amp and amp_dtype == torch.float16)

    epoch, start, step, seconds_before = 0, 0, 0, 0.0
    if resume:
        model.load_state_dict(resume["model"])
        opt.load_state_dict(resume["optimizer"])
        sched.load_state_dict(resume["scheduler"])
        scaler.load_state_dict(resume["scaler"])
        epoch, start, step = resume["epoch"], resume["batch"], resume["step"]
        seconds_before = float(resume.get("seconds", 0.0))
        rngs = resume["rng"]
        _set_rng_state(rngs[d.rank] if d.rank < len(rngs) else rngs[0], d.device)
    else:
        torch.manual_seed(cfg.seed * 7919 + 1 + d.rank)  # per-process stream (e.g. Monte Carlo render)

    net = StageForward(model, stage)
    if d.world > 1:
        net = nn.parallel.DistributedDataParallel(net, device_ids=[d.local_rank] if cuda else None)

    writer = None
    log_file = stage_dir / "log.jsonl"
    if d.main:
        stage_dir.mkdir(parents=True, exist_ok=True)
        _truncate_log(log_file, step)
        _truncate_log(stage_dir / "val.jsonl", epoch, key="epoch")
        writer = _tensorboard(stage_dir / "tb", step)
        msg = f"resuming at epoch {epoch}, batch {start} (step {step})" if resume else \
            f"starting from {init_from or 'random weights'}"
        print(f"phyir train {cfg.stage}: {msg}; {len(train_set)} scenes, {batches.steps} steps/epoch, "
              f"{stage.epochs} epochs, global batch {stage.batch_size} x {d.world} process(es), "
              f"lr {stage.lr:g}, device {d.device}", file=sys.stderr, flush=True)

    def checkpoint(ep: int, batch: int) -> None:
        rngs = _gather(_rng_state(d.device), d)
        if d.main:
            save_checkpoint(ckpt_path, {
                "format": CKPT_FORMAT, "config": _jsonable(dataclasses.asdict(cfg)),
                "model_config": mcfg.to_dict(), "model": model.state_dict(), "optimizer": opt.state_dict(),
                "scheduler": sched.state_dict(), "scaler": scaler.state_dict(), "rng": rngs,
                "epoch": ep, "batch": batch, "step": step,
                "seconds": seconds_before + time.monotonic() - t_start})
        d.barrier()

    losses: list[float] = []
    val_metrics: dict = {}
    status = "done"
    already_done = epoch >= stage.epochs and (stage_dir / EXPORT).is_file()
    skipped, step_time, stop = 0, 0.0, False
    while epoch < stage.epochs:
        train_set.set_epoch(epoch)
        loader = _loader(train_set, batches.batches(epoch, start), cfg.workers, cfg.seed * 100_003 + epoch)
        bar = _progress(cfg, d, batches.steps, start, f"{cfg.stage} epoch {epoch + 1}/{stage.epochs}")
        for b, scene in enumerate(loader, start=start):
            t0 = time.monotonic()
            scene = scene.to(d.device)
            grid = scene.probe_grid
            with torch.autocast(d.device.type, dtype=amp_dtype, enabled=use_amp):
                pred = net(scene.image, grid)
            pred = {k: v.float() for k, v in pred.items()}
            loss, terms = total_loss(pred, scene, weights, loss_opts, refined=stage.refine)
            if not d.any(not bool(torch.isfinite(loss))):
                opt.zero_grad(set_to_none=True)
                scaler.scale(loss).backward()
                if cfg.grad_clip:
                    scaler.unscale_(opt)
                    nn.utils.clip_grad_norm_(params, cfg.grad_clip)
                scaler.step(opt)
                scaler.update()
            else:
                skipped += 1
                if d.main:
                    print(f"phyir train: non-finite loss at step {step}, batch skipped", file=sys.stderr)
                if skipped > 20:
                    raise PhyIRError("training diverged: more than 20 batches with a non-finite loss")
            sched.step()
            step += 1
            mean = d.all_mean(torch.stack([loss.detach(), *terms.values()]).float())
            losses.append(float(mean[0]))
            if d.main:
                _log_step(log_file, writer, step, epoch, float(mean[0]), dict(zip(terms, mean[1:].tolist())),
                          sched.get_last_lr()[0], cfg.log_every)
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(loss=f"{float(mean[0]):.4g}")
            dt = time.monotonic() - t0
            step_time = 0.8 * step_time + 0.2 * dt if step_time else dt
            done_epoch = b + 1 == batches.steps
            over = cfg.max_minutes is not None and \
                time.monotonic() - t_start + step_time > 60 * cfg.max_minutes
            stop = d.any((cfg.max_steps is not None and step >= cfg.max_steps) or over)
            if stop and not done_epoch:
                checkpoint(epoch, b + 1)
                status = "stopped"
                break
            if step % cfg.ckpt_every == 0 and not done_epoch:
                checkpoint(epoch, b + 1)
        if bar is not None:
            bar.close()
        if status == "stopped":
            break
        if val_set is not None:
            val_metrics = validate(model, stage, val_set, d)
            if d.main:
                _log_val(stage_dir / "val.jsonl", writer, epoch + 1, step, val_metrics)
        epoch, start = epoch + 1, 0
        checkpoint(epoch, 0)
        if stop and epoch < stage.epochs:
            status = "stopped"
            break

    if d.main:
        if status == "done" and not already_done:
            _export(model, stage_dir / EXPORT, cfg, stage, train_set, step, val_metrics, init_from,
                    seconds_before + time.monotonic() - t_start)
        print(f"phyir train {cfg.stage}: {status} at epoch {epoch}, step {step}"
              + ("; run the same command again to resume" if status == "stopped" else
                 f"; weights in {stage_dir / EXPORT}"), file=sys.stderr, flush=True)
        if writer is not None:
            writer.close()
    d.barrier()
    return {"status": status, "step": step, "epoch": epoch, "losses": losses, "val": val_metrics,
            "checkpoint": str(ckpt_path), "model": model}


@torch.no_grad()
def validate(model: PhyIRModel, stage: Stage, val_set, d: Dist, batch_size: int = 4) -> dict[str, float]:
    """Mean validation metrics (phyir.metrics) over the val split, sharded over processes."""
    from phyir import metrics

    was = {n: getattr(model, n).training for n in ("gmnet", "lnet", "gsnet")}
    model.eval()
    sums: dict[str, float] = {}
    count = 0
    idx = list(range(d.rank, len(val_set), d.world))
    for i in range(0, len(idx), batch_size):
        scene = PanoScene.stack([val_set[j] for j in idx[i:i + batch_size]]).to(d.device)
        p = model.forward_parts(scene.image, scene.probe_grid, light=stage.light, refine=stage.refine)
        pick = functools.partial(pick_output, p, refined=stage.refine)
        m = {}
        dm = metrics.depth_metrics(p["depth"], scene.depth)
        m.update({f"depth_{k}": dm[k] for k in ("abs_rel", "rmse", "delta1")})
        m["normal_mean_deg"] = metrics.normal_metrics(pick("normal"), scene.normal)["mean"]
        m.update(metrics.material_metrics(pick("albedo"), scene.albedo, pick("roughness"), scene.roughness,
                                          pick("metallic"), scene.metallic))
        if stage.light and scene.probes is not None:
            m["probe_log_mse"] = metrics.probe_log_mse(p["probes"], scene.probes)
        n = scene.image.shape[0]
        for k, v in m.items():
            sums[k] = sums.get(k, 0.0) + v * n
        count += n
    keys = sorted(sums)
    t = torch.tensor([sums[k] for k in keys] + [count], dtype=torch.float64, device=d.device)
    if d.world > 1:
        keys = _gather(keys, d)[0]
        dist.all_reduce(t)
    for n, w in was.items():
        getattr(model, n).train(w)
    return {k: float(v) / max(float(t[-1]), 1.0) for k, v in zip(keys, t[:-1])}


# ---------------------------------------------------------------------------------------------
# small helpers


def _loader(dataset, batches: list[list[int]], workers: int, seed: int):
    from torch.utils.data import DataLoader

    from phyir.learn.datasets import collate

    # a private generator: creating the iterator draws worker seeds from it, not from the global RNG
    # (which would then depend on how often the run was resumed)
    return DataLoader(dataset, batch_sampler=batches, collate_fn=collate, num_workers=workers,
                      persistent_workers=False, generator=torch.Generator().manual_seed(seed))


def _gather(obj, d: Dist) -> list:
    if d.world == 1:
        return [obj]
    out = [None] * d.world
    dist.all_gather_object(out, obj)
    return out


def _progress(cfg: TrainConfig, d: Dist, total: int, initial: int, desc: str):
    if not (cfg.progress and d.main):
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, leave=False, dynamic_ncols=True)


def _tensorboard(path: Path, step: int):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:  # tensorboard not installed: logs go to the jsonl files only
        return None
    return SummaryWriter(str(path), purge_step=step or None)


def _truncate_log(path: Path, upto: int, key: str = "step") -> None:
    """Drop lines logged after the checkpoint we resume from (a killed run logged past it)."""
    if not path.is_file():
        return
    keep = [ln for ln in path.read_text().splitlines() if ln.strip() and json.loads(ln)[key] <= upto]
    path.write_text("".join(ln + "\n" for ln in keep))


def _log_step(path: Path, writer, step: int, epoch: int, loss: float, terms: dict, lr: float,
              every: int) -> None:
    with open(path, "a") as f:
        f.write(json.dumps({"step": step, "epoch": epoch, "loss": loss, **terms, "lr": lr}) + "\n")
    if writer is not None and (step % every == 0 or step == 1):
        writer.add_scalar("train/loss", loss, step)
        for k, v in terms.items():
            writer.add_scalar(f"train/{k}", v, step)
        writer.add_scalar("train/lr", lr, step)


def _log_val(path: Path, writer, epoch: int, step: int, m: dict) -> None:
    with open(path, "a") as f:
        f.write(json.dumps({"epoch": epoch, "step": step, **m}) + "\n")
    if writer is not None:
        for k, v in m.items():
            writer.add_scalar(f"val/{k}", v, step)
    print(f"  val epoch {epoch}: " + ", ".join(f"{k} {v:.4g}" for k, v in m.items()), file=sys.stderr)


def _jsonable(x):
    return json.loads(json.dumps(x, default=str))


def _export(model, path: Path, cfg: TrainConfig, stage: Stage, train_set, step: int, val: dict,
            init_from: str | None, seconds: float) -> None:
    from phyir.learn.weights import save_weights

    H, W = cfg.size or train_set[0].size
    data = {"root": cfg.data, "train_scenes": len(train_set), "resolution": f"{H}x{W}",
            "probe_grid": "x".join(map(str, cfg.probe_grid)) if cfg.probe_grid else "native"}
    if cfg.data and (Path(cfg.data) / "manifest.json").is_file():
        # the generator's settings (seed, size, count) as `phyir synth` recorded them
        doc = json.loads((Path(cfg.data) / "manifest.json").read_text())
        data["generator"] = {k: doc[k] for k in ("generator", "config", "count") if k in doc}
    info = {"stage": cfg.stage, "init": init_from, "steps": step, "epochs": stage.epochs, "lr": stage.lr,
            "batch_size": stage.batch_size, "schedule": cfg.schedule, "seed": cfg.seed,
            "train_seconds": round(seconds, 1), "data": data, "val": val}
    for k in ("train_only", "reinit", "loss", "weights"):
        if getattr(cfg, k):
            info[k] = _jsonable(getattr(cfg, k))
    save_weights(model, path, info)
