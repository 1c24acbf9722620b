"""Training data: a folder of scene files with a split manifest, input normalisation, augmentation.

Input handling (the same at training and inference time):
- LDR photographs are linearised by the loader (sRGB decode, :mod:`phyir.io.ldr`).
- Every input is **exposure-normalised**: multiplied by ``s = KEY / median luminance`` so that its
  median luminance is ``KEY``; ground-truth probes (and the re-rendering) live in the same units.
  :meth:`phyir.nets.PhyIRModel.predict` divides the predicted probes by ``s``, so they come back in
  the input's own radiometric units.

Augmentation (training split only; every random draw comes from a generator seeded by
(seed, epoch, index), so a sample is the same in every process and after a resume):
- exposure jitter: image and probes times 2^U(-a, a) (matters through the tone mapping below),
- light colour: image and probes times per-channel gains (red and blue 2^U(-c, c) against green):
  exact, since radiance is linear in the emitters' colour, and it covers what the generator's
  2700-6500 K lights do not (firelight, sodium lamps, unbalanced cameras),
- HDR -> LDR with probability ``p_ldr``: a random camera pipeline (:mod:`phyir.learn.camera`:
  white balance, ACES / Reinhard / clipping, sRGB, 8 bits, often JPEG), then the loader's sRGB
  decode, so the network also sees saturated, tinted, compressed photographs,
- yaw rotation by a random circular shift of whole columns (:func:`phyir.transforms.rotate_yaw`:
  normals and probes rotated with it),
- left-right mirror with probability 0.5 (:func:`phyir.transforms.mirror_lr`: x negated).
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from phyir.color import exposure_scale, luminance
from phyir.errors import InputError
from phyir.learn.camera import CameraPipeline, simulate_ldr
from phyir.pano import resize_area
from phyir.scene import PanoScene

MANIFEST_NAMES = ("manifest.json", "split.json", "splits.json")
SPLITS = ("train", "val", "test")


def normalize_scene(scene: PanoScene) -> PanoScene:
    """Scale image and probes by :func:`exposure_scale`; the factor is recorded in ``meta``."""
    s = float(exposure_scale(scene.image))
    out = scene.replace(image=scene.image * s, probes=None if scene.probes is None else scene.probes * s,
                        meta={**scene.meta, "exposure_scale": f"{s:.9g}"})
    return out


@dataclass(frozen=True)
class Augment:
    exposure_stops: float = 1.0  # jitter by 2^U(-a, a)
    light_colour_stops: float = 1.0  # red and blue gains 2^U(-c, c)
    p_ldr: float = 0.3
    ldr_exposure: tuple[float, float] = (0.5, 4.0)  # camera exposure before tone mapping, log-uniform
    rotate: bool = True
    mirror: bool = True
    camera: CameraPipeline = CameraPipeline()


def resize_scene(scene: PanoScene, H: int, W: int, grid: tuple[int, int] | None = None) -> PanoScene:
    """Area-resample the per-pixel layers to H x W (normals renormalised, masks re-thresholded) and,
    if ``grid`` is given, the probe grid to ``grid`` (neighbouring probes averaged: an approximation
    of the probe at the merged block's centre)."""
    out = scene.map(lambda t: t)  # copy the container
    if scene.size != (H, W):
        for name, t in scene.layers():
            if name.startswith("mask."):
                out.masks[name[5:]] = (resize_area(t, H, W) > 0.5).to(t.dtype)
            else:
                setattr(out, name, resize_area(t, H, W))
        if out.normal is not None:
            out.normal = F.normalize(out.normal, dim=-3, eps=1e-6)
    if grid is not None and scene.probes is not None and scene.probe_grid != tuple(grid):
        p = scene.probes  # [..., Hp, Wp, 3, h, w] -> grid axes last for resize_area
        q = resize_area(p.movedim((-5, -4), (-2, -1)).flatten(-5, -3), *grid)
        out.probes = q.unflatten(-3, p.shape[-3:]).movedim((-2, -1), (-5, -4)).contiguous()
    return out


def _exact_shift_step(scene: PanoScene) -> int:
    """Smallest column shift that moves the probe grid and the probe contents by whole texels (so
    ground-truth probes are rolled, not resampled); 1 when there are no probes or it doesn't exist."""
    W = scene.size[1]
    if scene.probes is None:
        return 1
    Wp, w = scene.probes.shape[-4], scene.probes.shape[-1]
    if W % Wp or W % w:
        return 1
    return math.lcm(W // Wp, W // w)


def augment_scene(scene: PanoScene, aug: Augment, gen: torch.Generator) -> PanoScene:
    """Random exposure, LDR simulation, yaw rotation and mirror of an unbatched scene."""
    from phyir.transforms import mirror_lr, rotate_yaw

    def u():
        return float(torch.rand((), generator=gen))
    if aug.rotate:
        step = _exact_shift_step(scene)
        scene = rotate_yaw(scene, step * int(torch.randint(scene.size[1] // step, (), generator=gen)))
    if aug.mirror and u() < 0.5:
        scene = mirror_lr(scene)
    gain = 2.0 ** (aug.exposure_stops * (2 * u() - 1))
    if aug.light_colour_stops:
        c = aug.light_colour_stops
        gain = gain * torch.tensor([2.0 ** (c * (2 * u() - 1)), 1.0, 2.0 ** (c * (2 * u() - 1))])
        gain = gain.to(scene.image)[:, None, None]
    scene = scene.replace(image=scene.image * gain,
                          probes=None if scene.probes is None else scene.probes * gain)
    if u() < aug.p_ldr:
        lo, hi = aug.ldr_exposure
        exposure = lo * (hi / lo) ** u() / max(float(luminance(scene.image).median()), 1e-8) * 0.18
        scene = scene.replace(image=simulate_ldr(scene.image, exposure, gen, aug.camera) / exposure,
                              meta={**scene.meta, "ldr": "1"})
    return scene


def read_manifest(root: str | os.PathLike) -> dict[str, list[str]]:
    """{split: [scene file relative to root]} from the folder's manifest."""
    root = Path(root)
    if not root.is_dir():  # [issue 22] a FIFO, a file, nothing: not "no manifest in the folder"
        raise InputError(root, "no such folder" if not os.path.lexists(root) else
                         "is not a folder (expected a dataset folder written by phyir synth)")
    for name in MANIFEST_NAMES:
        p = root / name
        if p.is_file():
            break
    else:
        raise InputError(root, f"no split manifest ({' or '.join(MANIFEST_NAMES)}) in the dataset folder")
    try:
        doc = json.loads(p.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise InputError(p, f"unreadable manifest ({e})") from e
    splits = doc.get("splits", doc) if isinstance(doc, dict) else None
    if not isinstance(splits, dict) or not any(k in splits for k in SPLITS):
        raise InputError(p, "manifest has no train/val/test lists")
    bad = [k for k in SPLITS if not (isinstance(splits.get(k, []), list)
                                     and all(isinstance(f, str) for f in splits.get(k, [])))]
    if bad:
        raise InputError(p, f"manifest split {bad[0]!r} is not a list of file names")
    return {k: list(splits.get(k, [])) for k in SPLITS}


def split_files(root: str | os.PathLike, split: str, limit: int | None = None) -> list[Path]:
    """The scene files of ``split`` that exist (the first ``limit``).

    A dataset still being generated (or one shard of it) lists scenes that don't exist yet: use those
    present, and warn how many are missing.
    """
    root = Path(root)
    files = read_manifest(root)[split]
    listed = len(files)
    if not files:
        raise InputError(root, f"split {split!r} of the manifest is empty")
    files = [f for f in files if (root / f).is_file()]
    if not files:
        raise InputError(root, f"none of the {listed} scene files of split {split!r} exist yet")
    if len(files) < listed:
        warnings.warn(f"{root}: {listed - len(files)} of {listed} {split} scenes listed in the manifest "
                      f"are missing (still being generated?); using the {len(files)} present", stacklevel=3)
    return [root / f for f in files[:limit]]


class _ScenesBase(Dataset):
    """Shared per-item processing: resize, seeded augmentation, exposure normalisation."""

    size: tuple[int, int] | None = None
    probe_grid: tuple[int, int] | None = None
    augment: Augment | None = None
    seed: int = 0
    epoch: int = 0

    def set_epoch(self, epoch: int) -> None:
        """Augmentations of epoch ``epoch`` (call before iterating, like DistributedSampler's)."""
        self.epoch = epoch

    def _prepare(self, scene: PanoScene, i: int) -> PanoScene:
        if self.size is not None or self.probe_grid is not None:
            scene = resize_scene(scene, *(self.size or scene.size), grid=self.probe_grid)
        if self.augment is not None:
            key = ((self.seed * 1_000_003 + self.epoch) * 1_000_033 + i) % 2**62
            gen = torch.Generator().manual_seed(key)
            scene = augment_scene(scene, self.augment, gen)
        return normalize_scene(scene)


class SceneDataset(_ScenesBase):
    """Scenes of one split of a dataset folder, normalised (and augmented when ``augment`` is set).

    ``size`` (H, W) resamples every scene (e.g. 128x256 training from 256x512 files), ``probe_grid``
    (Hp, Wp) merges probes into a coarser grid.  ``cache_dir`` keeps each resampled scene there as
    float16 safetensors (the scene files are float16 already), read instead of the scene file from
    the second epoch on.  Items are unbatched :class:`PanoScene` s; batch them with :func:`collate`.
    """

    def __init__(self, root: str | os.PathLike, split: str = "train", *, size: tuple[int, int] | None = None,
                 probe_grid: tuple[int, int] | None = None, augment: Augment | None = None, seed: int = 0,
                 limit: int | None = None, cache_dir: str | os.PathLike | None = None):
        self.root = Path(root)
        self.files = split_files(self.root, split, limit)
        self.split, self.size, self.augment, self.seed = split, size, augment, seed
        self.probe_grid = probe_grid

        self.cache_dir = None if cache_dir is None else Path(cache_dir)

    def __len__(self) -> int:
        return len(self.files)

    def __getitem__(self, i: int) -> PanoScene:
        return self._prepare(self._load(i), i)

    def _load(self, i: int) -> PanoScene:
        """The scene resampled to ``size``/``probe_grid`` (from the cache when there is one: decoding
        a 256x512 scene file with its probes costs ~0.45 s of CPU, the cached copy ~5 ms)."""
        from phyir.io import load_scene

        if self.cache_dir is None:
            return load_scene(self.files[i])
        path = self.cache_dir / (Path(self.files[i]).stem + ".safetensors")
        if path.is_file():
            return _read_cached(path)
        scene = load_scene(self.files[i])
        scene = resize_scene(scene, *(self.size or scene.size), grid=self.probe_grid)
        _write_cached(path, scene)
        return _read_cached(path)  # the same float16 values in the first epoch as in later ones


class TensorSceneDataset(_ScenesBase):
    """In-memory scenes (tests, tiny sets) with the same processing as :class:`SceneDataset`."""

    def __init__(self, scenes: list[PanoScene], *, size: tuple[int, int] | None = None,
                 probe_grid: tuple[int, int] | None = None, augment: Augment | None = None, seed: int = 0):
        self.scenes, self.size, self.augment, self.seed = scenes, size, augment, seed
        self.probe_grid = probe_grid

    def __len__(self) -> int:
        return len(self.scenes)

    def __getitem__(self, i: int) -> PanoScene:
        return self._prepare(self.scenes[i], i)


F16_MAX = 65504.0
CACHE_SCALE = "cache.exposure_scale"  # meta key of the factor the cached radiance carries


def _write_cached(path: Path, scene: PanoScene) -> None:
    from safetensors.torch import save

    from phyir.io import atomic_write

    # float16 spans 6e-8 .. 65504: radiance is stored exposure-normalised and scaled back on reading,
    # else a 1e6-bright scene overflows to Inf and a 1e-6-dark one loses its bits
    s = float(exposure_scale(scene.image))
    def f16(t):
        return t.clamp(-F16_MAX, F16_MAX).half().contiguous()
    tensors = {name: f16(t * s if name == "image" else t) for name, t in scene.layers()}
    if scene.probes is not None:
        tensors["probes"] = f16(scene.probes * s)
    meta = {**{k: str(v) for k, v in scene.meta.items()}, CACHE_SCALE: repr(s)}
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as tmp:
        Path(tmp).write_bytes(save(tensors, metadata=meta))


def _read_cached(path: Path) -> PanoScene:
    from safetensors import safe_open

    with safe_open(str(path), framework="pt") as f:
        t = {k: f.get_tensor(k).float() for k in f.keys()}
        meta = dict(f.metadata() or {})
    s = float(meta.pop(CACHE_SCALE, "1"))
    for k in ("image", "probes"):
        if k in t:
            t[k] = t[k] / s
    masks = {k[5:]: t.pop(k) for k in list(t) if k.startswith("mask.")}
    if "normal" in t:
        t["normal"] = F.normalize(t["normal"], dim=-3, eps=1e-6)
    return PanoScene(**t, masks=masks, meta=meta)


def collate(scenes: list[PanoScene]) -> PanoScene:
    return PanoScene.stack(scenes)
