"""Time projection-based probes (phyir.lighting.projection) for a probe grid on a real panorama.

The radiance is a real HDR panorama (../shared/panos, or --pano); the depth is that of a box room
around the camera (the timing depends on the number of rays and marching steps, not on the content).

    .venv/bin/python -m benchmarks.projection_timing --grid 64x128 --probe 16x32 --threads 2
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from phyir import pano
from phyir.io import load_panorama
from phyir.lighting.projection import DepthSurface, probe_positions, project_probes
from phyir.scene import PanoScene
from phyir.synth.analytic import box_room

PANOS = Path(__file__).resolve().parents[2] / "shared" / "panos"


# the box room around the camera whose depth the probes march (phyir.synth.analytic.box_room)
ROOM_LO, ROOM_HI = (-2.0, -1.5, -3.0), (3.0, 1.3, 2.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pano", type=Path, default=None,
                    help="HDR panorama (default: the first in ../shared/panos)")
    ap.add_argument("--size", default="512x1024", help="panorama size used (HxW)")
    ap.add_argument("--grid", default="64x128")
    ap.add_argument("--probe", default="16x32")
    ap.add_argument("--supersample", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeat", type=int, default=1)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    H, W = (int(x) for x in a.size.split("x"))
    grid = tuple(int(x) for x in a.grid.split("x"))
    probe = tuple(int(x) for x in a.probe.split("x"))
    path = a.pano or sorted(PANOS.glob("*.hdr"))[0]
    img = pano.resize_area(load_panorama(path), H, W)
    scene = PanoScene(image=img, depth=box_room(H, W, ROOM_LO, ROOM_HI)[0].float()).to(a.device)
    for _ in range(a.repeat):
        sync = torch.cuda.synchronize if a.device.startswith("cuda") else (lambda: None)
        t0 = time.perf_counter()
        surf = DepthSurface.from_scene(scene)
        pos = probe_positions(scene.depth, scene.normal, grid).reshape(-1, 3)
        sync()
        t1 = time.perf_counter()
        probes, vis = project_probes(surf, pos, probe, supersample=a.supersample)
        sync()
        t2 = time.perf_counter()
        rays = pos.shape[0] * probe[0] * probe[1] * a.supersample**2
        print(f"{path.name} {H}x{W}, grid {grid[0]}x{grid[1]} of {probe[0]}x{probe[1]} probes, "
              f"supersample {a.supersample}, {a.threads} threads, {a.device}: set-up {t1 - t0:.2f} s, "
              f"probes {t2 - t1:.2f} s ({rays / (t2 - t1) / 1e6:.2f} M rays/s), "
              f"{len(surf.sources) if surf.sources is not None else 0} bright sources, "
              f"visible share {float(vis.mean()):.3f}")


if __name__ == "__main__":
    main()
