"""Dataset generation: one scene file per scene, resumable, shardable, with a split manifest.

Scene ``i`` of a dataset with seed ``S`` depends only on ``(S, i)``: the room is drawn from
``numpy.random.default_rng([S, i])`` and the tracer's sampler is seeded from the same pair, so any
shard of any machine produces the same file for it.  Shard ``k/n`` renders the scenes with
``i % n == k``.  The split (train/val/test) of scene ``i`` is a hash of ``(S, i)``, so it does not
depend on sharding either, and every shard writes the same ``manifest.json``.
"""

from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from phyir.errors import PhyIRError
from phyir.scene import PROBE_OFFSET, PanoScene
from phyir.synth.lights import AREA, PORTAL, SUN
from phyir.synth.rooms import generate_room
from phyir.synth.trace_settings import TraceSettings
from phyir.synth.tracer import trace

SPLITS = (("train", 0.8), ("val", 0.1), ("test", 0.1))
EXPOSURE_MEDIAN = 0.18  # median luminance of non-emissive pixels after normalisation (x 2^+-1)
HALF_MAX = 65000.0  # values are clipped here in half-float files
MANIFEST = "manifest.json"
# bounds of a dataset's settings (docs/robustness.md, "Numeric options"), checked before anything
# renders: the path tracer and the probe atlas grow with the pixel and probe-texel counts
MAX_SYNTH_SIZE = (1024, 2048)
MAX_PROBE_SIZE = (64, 128)
MAX_PROBE_TEXELS = 64 * 128 * 16 * 32 * 4  # grid cells x probe texels (4x the default's)
MAX_SPP = 65536
MAX_COUNT = 10_000_000


def scene_name(i: int) -> str:
    return f"scene_{i:06d}.exr"


def split_of(seed: int, i: int) -> str:
    """Deterministic split of scene ``i`` (independent of sharding)."""
    u = np.random.default_rng([seed, i, 0x5B1]).random()
    acc = 0.0
    for name, frac in SPLITS:
        acc += frac
        if u < acc:
            return name
    return SPLITS[-1][0]


def tiny_settings(size=(32, 64), probe_grid=(8, 16), probe_size=(8, 16), spp: int = 4) -> TraceSettings:
    """Cheap settings for tests: coarse light map, few samples."""
    return TraceSettings(size=tuple(size), probe_grid=None if probe_grid is None else tuple(probe_grid),
                         probe_size=tuple(probe_size), spp=spp, texel=0.25, lm_light_samples=8,
                         lm_gather=16, lm_iters=4, cov_budget=256, cov_max_sub=6, vis_rays=2,
                         sun_rays=2, max_depth=4)


def generate_scene(seed: int, index: int, settings: TraceSettings | None = None, device=None,
                   sampler_seed: int | None = None) -> PanoScene:
    """Draw room ``(seed, index)``, trace it and return the exposure-normalised ``PanoScene``.

    ``sampler_seed`` overrides the tracer's seed (noise measurements); the room stays the same.
    """
    st = settings or TraceSettings()
    rng = np.random.default_rng([seed, index])
    room = generate_room(rng)
    exposure_jitter = float(2.0 ** rng.uniform(-1, 1))
    sc = room.build(device)
    t0 = time.perf_counter()
    rseed = int(np.random.default_rng([seed, index, 0x7ACE]).integers(2**31)) if sampler_seed is None \
        else int(sampler_seed)
    res = trace(sc, st, seed=rseed)
    seconds = time.perf_counter() - t0
    nonem = res.emission[0] < 0.5
    lum = (res.image * torch.tensor([0.2126, 0.7152, 0.0722], device=res.image.device)[:, None, None]).sum(0)
    med = float(lum[nonem].median()) if bool(nonem.any()) else 1.0
    k = EXPOSURE_MEDIAN * exposure_jitter / max(med, 1e-8)
    kinds = sc.lights.kind.tolist()
    lights = {"panels_and_lamps": kinds.count(AREA), "windows": kinds.count(PORTAL), "sun": kinds.count(SUN)}
    metal = float((res.metallic[0][nonem] > 0.5).float().mean()) if bool(nonem.any()) else 0.0
    L = sc.lights  # brightest source radiance (channel mean), whether or not a pixel shows it
    rad = L.radiance.mean(1)
    lamp = float(rad[L.kind == AREA].max()) if AREA in kinds else 0.0  # panels and lamps
    sky = float(torch.stack((L.zenith, L.horizon, L.ground)).mean(1).max()) if PORTAL in kinds else 0.0
    sun = float(rad[L.sun_index]) if L.has_sun else 0.0
    bright = max(lamp, sky, sun)
    d = res.depth[0]
    meta = {
        "source": "phyir synth",
        "seed": str(seed), "index": str(index), "sampler_seed": str(rseed),
        "exposure": f"{k:.6g}",
        "room": json.dumps(room.summary()),
        "lights": json.dumps(lights),
        "metal_fraction": f"{metal:.4f}",
        "brightest_source": f"{bright * k:.6g}",
        "source_radiance": json.dumps({"lamp": float(f"{lamp * k:.6g}"), "sky": float(f"{sky * k:.6g}"),
                                       "sun": float(f"{sun * k:.6g}")}),
        "depth_range": f"{float(d.min()):.4f} {float(d.max()):.4f}",
        "camera_height": f"{room.camera[1]:.4f}",
        "probe_offset": f"{PROBE_OFFSET:g}",
        "spp": str(st.spp),
        "render_seconds": f"{seconds:.2f}",
        "render_stats": json.dumps({k: round(v, 2) for k, v in res.stats.items()}),
    }
    scene = PanoScene(image=res.image * k, depth=res.depth, normal=res.normal, albedo=res.albedo,
                      roughness=res.roughness, metallic=res.metallic,
                      probes=None if res.probes is None else res.probes * k,
                      masks={"emission": res.emission}, meta=meta)
    return scene.to("cpu")


def trace_probes_at(scene: PanoScene, points: torch.Tensor, probe_size: tuple[int, int] = (16, 32),
                    settings: TraceSettings | None = None, seed: int = 0, device=None) -> torch.Tensor:
    """Path-traced probes ``[N,3,h,w]`` at camera-frame ``points [N,3]`` of the room a
    :func:`generate_scene` file came from (its ``seed``/``index`` meta), in the file's units (its
    ``exposure``): the ground truth of the light anywhere in the room, not just at the probe grid.

    The room is drawn again, so it must come from this generator: its camera rays are checked
    against the file's depth (a file from another generator version is refused, naming it)."""
    from phyir.pano import directions
    from phyir.synth import geometry as G
    from phyir.synth.paths import build_lightmap
    from phyir.synth.tracer import render_probes_at

    meta = scene.meta
    if not all(k in meta for k in ("seed", "index", "exposure")):
        raise PhyIRError("trace_probes_at: the scene has no synthetic room (no seed/index/exposure meta)")
    room = generate_room(np.random.default_rng([int(meta["seed"]), int(meta["index"])]))
    sc = room.build(device)
    H, W = scene.size
    rows, cols = slice(None, None, max(1, H // 16)), slice(None, None, max(1, W // 32))  # 16x32 rays
    d = directions(H, W)[:, rows, cols].reshape(3, -1).T.contiguous().to(sc.device)
    t, _ = G.intersect(sc.prims, torch.zeros_like(d), d)
    want = scene.depth[:, rows, cols].reshape(-1).float()
    if float(((t.cpu() - want).abs() / want.clamp_min(1e-3)).median()) > 0.02:
        raise PhyIRError(f"trace_probes_at: room {meta['seed']}/{meta['index']} drawn again does not match "
                         "the scene's depth (made by another version of the generator)")
    st = replace(settings or TraceSettings(), probe_size=tuple(probe_size))
    gen = torch.Generator(device=sc.device).manual_seed(int(seed))
    lm = build_lightmap(sc, st, gen)
    return (render_probes_at(sc, lm, points, st, gen) * float(meta["exposure"])).cpu()


@dataclass
class DatasetConfig:
    seed: int = 0
    count: int = 1
    size: tuple = (256, 512)
    probe_grid: tuple | None = (64, 128)
    probe_size: tuple = (16, 32)
    spp: int = 16
    half: bool = True

    def check(self) -> None:
        """Refuse settings outside the bounds above, naming the option (``--size`` ...)."""
        H, W = self.size
        if not (8 <= H <= MAX_SYNTH_SIZE[0] and W == 2 * H):
            raise PhyIRError(f"--size: {H}x{W} is not possible: need W = 2H and H from 8 to "
                             f"{MAX_SYNTH_SIZE[0]} (at most {MAX_SYNTH_SIZE[0]}x{MAX_SYNTH_SIZE[1]})")
        h, w = self.probe_size
        if not (4 <= h <= MAX_PROBE_SIZE[0] and w == 2 * h):
            raise PhyIRError(f"--probe-size: {h}x{w} is not possible: need w = 2h and h from 4 to "
                             f"{MAX_PROBE_SIZE[0]} (at most {MAX_PROBE_SIZE[0]}x{MAX_PROBE_SIZE[1]})")
        if self.probe_grid is not None:
            gh, gw = self.probe_grid
            if gh * gw * h * w > MAX_PROBE_TEXELS:
                raise PhyIRError(f"--probe-grid: {gh}x{gw} probes of {h}x{w} are {gh * gw * h * w:,} "
                                 f"texels, more than the limit of {MAX_PROBE_TEXELS:,}")
        if not 1 <= self.spp <= MAX_SPP:
            raise PhyIRError(f"--spp: expected 1..{MAX_SPP}, got {self.spp}")
        if not 1 <= self.count <= MAX_COUNT:
            raise PhyIRError(f"--count: expected 1..{MAX_COUNT:,}, got {self.count}")

    def settings(self) -> TraceSettings:
        # light-map resolution follows the image: 12000 texels at 256x512
        H, W = self.size
        texels = int(min(max(12000 * math.sqrt(H * W / (256 * 512)), 2000), 30000))
        return TraceSettings(size=tuple(self.size), probe_grid=None if self.probe_grid is None else
                             tuple(self.probe_grid), probe_size=tuple(self.probe_size), spp=self.spp,
                             lm_max_texels=texels)

    def key(self) -> dict:
        """What must match for files in a folder to belong to this dataset."""
        d = asdict(self)
        d.pop("count")
        return json.loads(json.dumps(d))


def write_manifest(out: Path, cfg: DatasetConfig) -> Path:
    from phyir.io import atomic_write

    splits = {name: [] for name, _ in SPLITS}
    for i in range(cfg.count):
        splits[split_of(cfg.seed, i)].append(scene_name(i))
    data = {"generator": "phyir synth", "config": cfg.key(), "count": cfg.count, "splits": splits}
    path = out / MANIFEST
    with atomic_write(path) as tmp, open(tmp, "w") as f:
        json.dump(data, f, indent=1)
    return path


def check_manifest(out: Path, cfg: DatasetConfig) -> None:
    """Refuse to mix scenes of different settings in one folder."""
    path = out / MANIFEST
    if not path.exists():
        return
    try:
        old = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise PhyIRError(f"{path}: unreadable manifest ({e}); remove it to start over") from None
    if old.get("config") != cfg.key():
        raise PhyIRError(f"{path}: folder holds a dataset made with other settings "
                         f"({old.get('config')}); use another --out folder")


def shard_indices(count: int, shard: tuple[int, int]) -> list[int]:
    k, n = shard
    return [i for i in range(count) if i % n == k]


def generate_dataset(out: str | os.PathLike, cfg: DatasetConfig, shard: tuple[int, int] = (0, 1),
                     device=None, settings: TraceSettings | None = None, progress: bool = True) -> dict:
    """Render the shard's missing scenes into ``out``; returns counts and timing."""
    from tqdm import tqdm

    from phyir.io import save_scene

    cfg.check()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_manifest(out, cfg)
    write_manifest(out, cfg)
    todo = [i for i in shard_indices(cfg.count, shard) if not (out / scene_name(i)).exists()]
    st = settings or cfg.settings()
    done, t0 = 0, time.perf_counter()
    bar = tqdm(todo, desc=f"synth {shard[0]}/{shard[1]}", unit="scene", disable=not progress)
    for i in bar:
        scene = generate_scene(cfg.seed, i, st, device)
        if cfg.half:
            scene = scene.replace(image=scene.image.clamp(max=HALF_MAX),
                                  probes=None if scene.probes is None else scene.probes.clamp(max=HALF_MAX))
        save_scene(scene, out / scene_name(i), half=cfg.half)
        done += 1
        bar.set_postfix(s_per_scene=f"{(time.perf_counter() - t0) / done:.1f}")
    return {"written": done, "skipped": len(shard_indices(cfg.count, shard)) - len(todo),
            "seconds": time.perf_counter() - t0}


def make_tiny_dataset(out: str | os.PathLike, count: int = 4, size=(32, 64), seed: int = 0,
                      probe_grid=(8, 16), probe_size=(8, 16), spp: int = 4) -> list[Path]:
    """A small dataset for tests, in seconds: ``count`` scenes at ``size`` with a coarse tracer."""
    cfg = DatasetConfig(seed=seed, count=count, size=tuple(size),
                        probe_grid=None if probe_grid is None else tuple(probe_grid),
                        probe_size=tuple(probe_size), spp=spp, half=False)
    generate_dataset(out, cfg, settings=tiny_settings(size, probe_grid, probe_size, spp), progress=False)
    return [Path(out) / scene_name(i) for i in range(count)]


def parse_size(text: str, what: str) -> tuple[int, int]:
    try:
        a, b = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise PhyIRError(f"{what}: expected AxB (e.g. 256x512), got {text!r}") from None
    if a <= 0 or b <= 0:
        raise PhyIRError(f"{what}: sizes must be positive, got {text!r}")
    return a, b


def parse_shard(text: str) -> tuple[int, int]:
    try:
        k, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise PhyIRError(f"--shard: expected i/n (e.g. 0/4), got {text!r}") from None
    if n < 1 or not 0 <= k < n:
        raise PhyIRError(f"--shard: need 0 <= i < n, got {text!r}")
    return k, n


# ---------------------------------------------------------------------------------------------
# the demo scene

DEMO_SEED, DEMO_INDEX = 2022, 14  # sun through three windows, a ceiling panel, two mirrors, a lamp
DEMO_SETTINGS = dict(size=(512, 1024), probe_grid=(32, 64), probe_size=(16, 32), spp=24,
                     lm_max_texels=30000, lm_gather=128)


def demo_settings() -> TraceSettings:
    return TraceSettings(**DEMO_SETTINGS)


def demo_scene_path() -> Path:
    """The demo scene: ``phyir/assets/demo.exr`` if shipped, else rendered once into the user cache.

    Regeneration is deterministic (seed ``DEMO_SEED``, scene ``DEMO_INDEX``, ``DEMO_SETTINGS``)
    and takes minutes on a CPU.
    """
    shipped = Path(__file__).resolve().parents[1] / "assets" / "demo.exr"
    if shipped.exists():
        return shipped
    cache = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "phyir" / "demo.exr"
    if not cache.exists():
        write_demo(cache)
    return cache


def write_demo(path: str | os.PathLike, device=None) -> Path:
    from phyir.io import save_scene

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    scene = generate_scene(DEMO_SEED, DEMO_INDEX, demo_settings(), device)
    scene = scene.replace(image=scene.image.clamp(max=HALF_MAX), probes=scene.probes.clamp(max=HALF_MAX))
    save_scene(scene, path, half=True)
    return path
