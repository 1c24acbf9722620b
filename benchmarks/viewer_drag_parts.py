"""Where a dragging frame of phyir-view goes with objects in the scene: the insertion's ``prepare``
(lighting, impostors, shadow maps) and its composite passes, each ended by ``ctx.finish()``, while
the first object is dragged in the perspective view (``viewer.app.cli.bench_drag``).  Still frames
are drawn in one piece here (``InsertionPass.progressive = False``): the frame after the release is
the full-quality work the viewer otherwise spreads over frames (``viewer.refinement``), and so is every
frame of the camera turning and the exposure dragged after it (``viewer.app.cli.bench_moves``).

    .venv/bin/python -m benchmarks.viewer_drag_parts [SCENE] [--mesh vase.glb] [--frames 30]

Default: the demo scene with two spheres and a 20k-triangle vase (``benchmarks.insert_gallery.vase``).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", nargs="?", default=str(REPO / "phyir/assets/demo.exr"))
    ap.add_argument("--mesh", help="the third object (default: a 20k-triangle vase, made here)")
    ap.add_argument("--frames", type=int, default=30)
    args = ap.parse_args(argv)
    from viewer.gl import window as surfaces

    surfaces.prefer_egl()
    from viewer.app.cli import apply_args, bench_drag, bench_moves, parser
    from viewer.app.core import App

    mesh = args.mesh
    if mesh is None:
        from benchmarks.insert_gallery import vase

        mesh = str(Path(tempfile.mkdtemp()) / "vase.glb")
        vase(mesh)
    opts = parser().parse_args([args.scene, "--no-model", "--object", "sphere", "--at", "560,400",
                                "--object", "sphere", "--at", "470,390", "--material", "matte-silver",
                                "--object", mesh, "--at", "520,380"])
    app = App((1394, 556), headless=True, recent=False, run_model=False)
    try:
        app.open(opts.path[0])
        app.wait_idle(120)
        apply_args(app, opts, wait=True)
        ins = app.objects.insertion
        app.objects.hook.progressive = False
        times = {"prepare": [], "composite passes": []}  # (frame number, seconds) per call
        frame_no = [0]

        def timed(name, fn):
            def run(*a, **k):
                ins.ctx.finish()
                t = time.perf_counter()
                out = fn(*a, **k)
                ins.ctx.finish()
                times[name].append((frame_no[0], time.perf_counter() - t))
                return out
            return run

        def counted(fn):
            def run(*a, **k):
                frame_no[0] += 1
                return fn(*a, **k)
            return run

        ins.prepare = timed("prepare", ins.prepare)
        ins.draw_fullscreen = timed("composite passes", ins.draw_fullscreen)
        app.frame = counted(app.frame)
        bench_drag(app, args.frames, moves=False)
        last = frame_no[0]
        for name, t in times.items():  # three still frames first, the full-quality one after release last
            # composite: the receivers at 1/4 (every other frame), over the layer, the objects over
            # their outline; the number of passes varies from frame to frame
            frames = [[s for f, s in t if f == n] for n in range(4, last)]
            total = 1000 * np.median([sum(c) for c in frames])
            longest = 1000 * np.median([max(c or [0]) for c in frames])
            after = 1000 * sum(s for f, s in t if f == last)
            print(f"{name}: median {total:.1f} ms a dragging frame ({args.frames} frames, "
                  f"{sum(map(len, frames)) / args.frames:.1f} calls a frame, the longest {longest:.1f} ms); "
                  f"{after:.0f} ms in the full-quality frame after release")
        bench_moves(app, args.frames // 2)  # every frame a full-quality one, as before viewer.refinement
    finally:
        app.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
