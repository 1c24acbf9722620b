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
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
import torch.distributed as dist
from torch import Tensor, nn

from phyir.errors import InputError, PhyIRError
from phyir.learn.checkpoints import (
    CKPT_FORMAT,
    jsonable,
    load_checkpoint,
    rng_state,
    save_checkpoint,
    set_rng_state,
)
from phyir.learn.config import (
    CHECKPOINT,
    EXPORT,
    STAGE_ORDER,
    STAGES,
    Stage,
    TrainConfig,
    load_config_file,
    resume_changes,
)
from phyir.learn.distributed import Dist, gather, setup_dist
from phyir.learn.logs import log_step, log_val, progress_bar, tensorboard, truncate_log
from phyir.learn.losses import LossOptions, LossWeights, pick_output, total_loss
from phyir.nets.model import ModelConfig, PhyIRModel
from phyir.scene import PanoScene

__all__ = ["STAGES", "STAGE_ORDER", "StageForward", "TrainConfig", "load_config_file", "make_datasets",
           "train", "validate"]

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
    aug = Augment(p_ldr=cfg.ldr_share) if cfg.augment else None
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
    for m in model.modules():  # a frozen batch norm keeps its (e.g. ImageNet) running statistics
        if isinstance(m, (nn.BatchNorm1d, nn.BatchNorm2d, nn.BatchNorm3d)) and \
                not any(p.requires_grad for p in m.parameters()):
            m.register_forward_pre_hook(_keep_eval)


def _keep_eval(module: nn.Module, args) -> None:
    module.training = False


def _lr_lambda(schedule: str, total_steps: int):
    if schedule == "constant":
        return lambda step: 1.0
    if schedule == "cosine":
        return lambda step: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(step, total_steps) / total_steps))
    raise PhyIRError(f"unknown schedule {schedule!r} (constant or cosine)")


def _initial_weights(cfg: TrainConfig, model: PhyIRModel) -> str | None:
    """Load the stage's starting weights into ``model``; returns where they came from."""
    from phyir.learn.weights import load_into

    if cfg.init == "scratch":
        return None
    if cfg.init is None and cfg.stage == "gm":  # a fresh start: a pretrained encoder starts pretrained
        return "imagenet encoder" if model.gmnet.load_pretrained() else None
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
    from phyir.learn.weights import model_config, read_weights

    src = cfg.init
    if src is None and cfg.stage != "gm":
        for prev in reversed(STAGE_ORDER[:STAGE_ORDER.index(cfg.stage)]):
            p = Path(cfg.out) / prev / EXPORT
            if p.is_file():
                src = str(p)
                break
    if src and src != "scratch":
        return model_config(src, read_weights(src)[1])
    return ModelConfig.named(cfg.model)


def _fit_probe_layout(mcfg: ModelConfig, scene: PanoScene) -> ModelConfig:
    """A fresh model predicts probes of the data's size, on the data's grid by default."""
    if scene.probes is None:
        return mcfg
    (H, W), (Hp, Wp) = scene.size, scene.probe_grid
    block = H // Hp if H % Hp == 0 and W % Wp == 0 and H // Hp == W // Wp else mcfg.probe_block
    return dataclasses.replace(mcfg, probe_size=scene.probe_size, probe_block=block)


@dataclass
class _Run:
    """One run of one stage: the model, its optimiser and where the loop stands."""

    cfg: TrainConfig
    stage: Stage
    weights: LossWeights
    loss_opts: LossOptions
    d: Dist
    t_start: float
    train_set: Any
    val_set: Any
    mcfg: ModelConfig
    model: PhyIRModel
    init_from: str | None
    params: list
    batches: EpochBatches
    opt: Any = None
    sched: Any = None
    scaler: Any = None
    amp_dtype: torch.dtype = torch.float16
    use_amp: bool = False
    net: nn.Module | None = None
    writer: Any = None
    epoch: int = 0
    start: int = 0
    step: int = 0
    seconds_before: float = 0.0
    skipped: int = 0
    step_time: float = 0.0
    losses: list[float] = field(default_factory=list)

    @property
    def stage_dir(self) -> Path:
        return Path(self.cfg.out) / self.cfg.stage

    @property
    def ckpt_path(self) -> Path:
        return self.stage_dir / CHECKPOINT

    @property
    def log_file(self) -> Path:
        return self.stage_dir / "log.jsonl"


def _build_run(cfg: TrainConfig, datasets, resume: dict | None) -> _Run:
    """The model (architecture, starting weights, what trains) and its optimiser, not yet resumed."""
    stage, weights, loss_opts = cfg.resolved()
    d = setup_dist(cfg.device)
    t_start = time.monotonic()
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
    run = _Run(cfg, stage, weights, loss_opts, d, t_start, train_set, val_set, mcfg, model, init_from,
               params, batches)
    run.opt = torch.optim.Adam(params, lr=stage.lr)
    total_steps = stage.epochs * batches.steps
    run.sched = torch.optim.lr_scheduler.LambdaLR(run.opt, _lr_lambda(cfg.schedule, total_steps))
    cuda = d.device.type == "cuda"
    run.amp_dtype = torch.bfloat16 if cuda and torch.cuda.is_bf16_supported() else torch.float16
    run.use_amp = cfg.amp and cuda
    run.scaler = torch.amp.GradScaler("cuda", enabled=run.use_amp and run.amp_dtype == torch.float16)
    return run


def _restore(run: _Run, resume: dict | None) -> None:
    """Resume from a checkpoint (state, position, RNG), or seed a fresh run; wrap for DDP."""
    d = run.d
    if resume:
        run.model.load_state_dict(resume["model"])
        run.opt.load_state_dict(resume["optimizer"])
        run.sched.load_state_dict(resume["scheduler"])
        run.scaler.load_state_dict(resume["scaler"])
        run.epoch, run.start, run.step = resume["epoch"], resume["batch"], resume["step"]
        run.seconds_before = float(resume.get("seconds", 0.0))
        rngs = resume["rng"]
        set_rng_state(rngs[d.rank] if d.rank < len(rngs) else rngs[0], d.device)
    else:
        torch.manual_seed(run.cfg.seed * 7919 + 1 + d.rank)  # per-process stream (e.g. Monte Carlo render)
    run.net = StageForward(run.model, run.stage)
    if d.world > 1:
        cuda = d.device.type == "cuda"
        run.net = nn.parallel.DistributedDataParallel(run.net, device_ids=[d.local_rank] if cuda else None)


def _open_logs(run: _Run, resumed: bool) -> None:
    if not run.d.main:
        return
    cfg, stage = run.cfg, run.stage
    run.stage_dir.mkdir(parents=True, exist_ok=True)
    truncate_log(run.log_file, run.step)
    truncate_log(run.stage_dir / "val.jsonl", run.epoch, key="epoch")
    run.writer = tensorboard(run.stage_dir / "tb", run.step)
    msg = f"resuming at epoch {run.epoch}, batch {run.start} (step {run.step})" if resumed else \
        f"starting from {run.init_from or 'random weights'}"
    print(f"phyir train {cfg.stage}: {msg}; {len(run.train_set)} scenes, {run.batches.steps} steps/epoch, "
          f"{stage.epochs} epochs, global batch {stage.batch_size} x {run.d.world} process(es), "
          f"lr {stage.lr:g}, device {run.d.device}", file=sys.stderr, flush=True)


def _checkpoint(run: _Run, epoch: int, batch: int) -> None:
    rngs = gather(rng_state(run.d.device), run.d)
    if run.d.main:
        save_checkpoint(run.ckpt_path, {
            "format": CKPT_FORMAT, "config": jsonable(dataclasses.asdict(run.cfg)),
            "model_config": run.mcfg.to_dict(), "model": run.model.state_dict(),
            "optimizer": run.opt.state_dict(), "scheduler": run.sched.state_dict(),
            "scaler": run.scaler.state_dict(), "rng": rngs, "epoch": epoch, "batch": batch,
            "step": run.step, "seconds": run.seconds_before + time.monotonic() - run.t_start})
    run.d.barrier()


def _train_step(run: _Run, scene: PanoScene) -> Tensor:
    """One optimiser step (skipped on a non-finite loss); returns the global mean [loss, *terms]."""
    d = run.d
    scene = scene.to(d.device)
    with torch.autocast(d.device.type, dtype=run.amp_dtype, enabled=run.use_amp):
        pred = run.net(scene.image, scene.probe_grid)
    pred = {k: v.float() for k, v in pred.items()}
    loss, terms = total_loss(pred, scene, run.weights, run.loss_opts, refined=run.stage.refine)
    if not d.any(not bool(torch.isfinite(loss))):
        run.opt.zero_grad(set_to_none=True)
        run.scaler.scale(loss).backward()
        if run.cfg.grad_clip:
            run.scaler.unscale_(run.opt)
            nn.utils.clip_grad_norm_(run.params, run.cfg.grad_clip)
        run.scaler.step(run.opt)
        run.scaler.update()
    else:
        run.skipped += 1
        if d.main:
            print(f"phyir train: non-finite loss at step {run.step}, batch skipped", file=sys.stderr)
        if run.skipped > 20:
            raise PhyIRError("training diverged: more than 20 batches with a non-finite loss")
    run.sched.step()
    run.step += 1
    mean = d.all_mean(torch.stack([loss.detach(), *terms.values()]).float())
    if d.main:
        log_step(run.log_file, run.writer, run.step, run.epoch, float(mean[0]),
                 dict(zip(terms, mean[1:].tolist())), run.sched.get_last_lr()[0], run.cfg.log_every)
    return mean


def _train_epoch(run: _Run) -> tuple[bool, bool]:
    """The rest of the current epoch; returns (stopped inside it, stop requested)."""
    cfg, d, batches = run.cfg, run.d, run.batches
    run.train_set.set_epoch(run.epoch)
    loader = _loader(run.train_set, batches.batches(run.epoch, run.start), cfg.workers,
                     cfg.seed * 100_003 + run.epoch)
    desc = f"{cfg.stage} epoch {run.epoch + 1}/{run.stage.epochs}"
    bar = progress_bar(cfg, d, batches.steps, run.start, desc)
    stop = stopped = False
    for b, scene in enumerate(loader, start=run.start):
        if isinstance(scene, WorkerError):
            raise PhyIRError(scene.message)
        t0 = time.monotonic()
        mean = _train_step(run, scene)
        run.losses.append(float(mean[0]))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(loss=f"{float(mean[0]):.4g}")
        dt = time.monotonic() - t0
        run.step_time = 0.8 * run.step_time + 0.2 * dt if run.step_time else dt
        done_epoch = b + 1 == batches.steps
        over = cfg.max_minutes is not None and \
            time.monotonic() - run.t_start + run.step_time > 60 * cfg.max_minutes
        stop = d.any((cfg.max_steps is not None and run.step >= cfg.max_steps) or over)
        if stop and not done_epoch:
            _checkpoint(run, run.epoch, b + 1)
            stopped = True
            break
        if run.step % cfg.ckpt_every == 0 and not done_epoch:
            _checkpoint(run, run.epoch, b + 1)
    if bar is not None:
        bar.close()
    return stopped, stop


def train(cfg: TrainConfig, datasets=None) -> dict:
    """Run (or resume) one stage.  ``datasets`` = (train, val) overrides ``cfg.data`` (tests).

    Returns a summary: ``status`` ("done" or "stopped"), ``step``, ``epoch``, ``losses`` (the global
    mean loss of each step of this run), ``val`` (last validation metrics), ``checkpoint``.
    """
    cfg.check()
    ckpt_path = Path(cfg.out) / cfg.stage / CHECKPOINT
    resume = load_checkpoint(ckpt_path) if ckpt_path.is_file() else None
    changed = resume_changes(resume.get("config") or {}, cfg) if resume else []
    if changed:  # the checkpoint's run would silently go on with other settings
        raise InputError(ckpt_path, "resuming with options other than the checkpoint's: "
                                    f"{', '.join(changed)}; rerun with the checkpoint's values, or start "
                                    "a new run (another --out, or delete this checkpoint)")
    run = _build_run(cfg, datasets, resume)
    _restore(run, resume)
    _open_logs(run, resume is not None)
    stage, d = run.stage, run.d
    val_metrics: dict = {}
    status = "done"
    already_done = run.epoch >= stage.epochs and (run.stage_dir / EXPORT).is_file()
    while run.epoch < stage.epochs:
        stopped, stop = _train_epoch(run)
        if stopped:
            status = "stopped"
            break
        if run.val_set is not None:
            val_metrics = validate(run.model, stage, run.val_set, d)
            if d.main:
                log_val(run.stage_dir / "val.jsonl", run.writer, run.epoch + 1, run.step, val_metrics)
        run.epoch, run.start = run.epoch + 1, 0
        _checkpoint(run, run.epoch, 0)
        if stop and run.epoch < stage.epochs:
            status = "stopped"
            break
    if d.main:
        if status == "done" and not already_done:
            _export(run.model, run.stage_dir / EXPORT, cfg, stage, run.train_set, run.step, val_metrics,
                    run.init_from, run.seconds_before + time.monotonic() - run.t_start)
        print(f"phyir train {cfg.stage}: {status} at epoch {run.epoch}, step {run.step}"
              + ("; run the same command again to resume" if status == "stopped" else
                 f"; weights in {run.stage_dir / EXPORT}"), file=sys.stderr, flush=True)
        if run.writer is not None:
            run.writer.close()
    d.barrier()
    return {"status": status, "step": run.step, "epoch": run.epoch, "losses": run.losses, "val": val_metrics,
            "checkpoint": str(ckpt_path), "model": run.model}


@torch.no_grad()
def validate(model: PhyIRModel, stage: Stage, val_set, d: Dist, batch_size: int = 4) -> dict[str, float]:
    """Mean validation metrics (phyir.evaluation.metrics) over the val split, sharded over processes."""
    from phyir.evaluation import metrics

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
        keys = gather(keys, d)[0]
        dist.all_reduce(t)
    for n, w in was.items():
        getattr(model, n).train(w)
    return {k: float(v) / max(float(t[-1]), 1.0) for k, v in zip(keys, t[:-1])}


# ---------------------------------------------------------------------------------------------
# small helpers


@dataclass
class WorkerError:
    """A user error (a corrupt scene file ...) met in a data-loading worker process, carried to the
    training process as a value: raised there, it would arrive wrapped in the worker's traceback."""

    message: str


class _Guarded(torch.utils.data.Dataset):
    """``dataset`` whose items are :class:`WorkerError` where reading them raised a PhyIRError."""

    def __init__(self, dataset):
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, i):
        try:
            return self.dataset[i]
        except PhyIRError as e:
            return WorkerError(str(e))


def _collate_guarded(items: list):
    from phyir.learn.datasets import collate

    failed = next((x for x in items if isinstance(x, WorkerError)), None)
    return failed if failed is not None else collate(items)


def _loader(dataset, batches: list[list[int]], workers: int, seed: int):
    from torch.utils.data import DataLoader

    from phyir.learn.datasets import collate

    if workers:  # errors in worker processes come back as values (WorkerError), raised here
        dataset, collate = _Guarded(dataset), _collate_guarded
    # a private generator: creating the iterator draws worker seeds from it, not from the global RNG
    # (which would then depend on how often the run was resumed)
    return DataLoader(dataset, batch_sampler=batches, collate_fn=collate, num_workers=workers,
                      persistent_workers=False, generator=torch.Generator().manual_seed(seed))


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
            info[k] = jsonable(getattr(cfg, k))
    save_weights(model, path, info)
