"""docs/img/export_mitsuba.png: the demo scene exported with ``phyir export`` (two spheres inserted)
and rendered by Mitsuba 3 from the exported file (room emission from the EXR, no lights).

    python -m benchmarks.export_mitsuba [--out docs/img/export_mitsuba.png] [--spp 64]
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time

from PIL import Image

from phyir.color import to_srgb8
from phyir.commands import export as export_cmd
from phyir.export import mitsuba as emi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="docs/img/export_mitsuba.png")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--size", default="384x256")
    args = ap.parse_args()
    w, h = (int(x) for x in args.size.split("x"))
    with tempfile.TemporaryDirectory() as tmp:
        glb = f"{tmp}/demo.glb"
        parser = argparse.ArgumentParser()
        export_cmd.add_arguments(parser)
        export_cmd.run(parser.parse_args([
            "phyir/assets/demo.exr", "--gltf", glb, "--object", "sphere", "--at", "470,400", "--object",
            "sphere", "--at", "560,400", "--scale", "0.25", "--material", "diffuse", "--material",
            "matte-silver"]))
        t0 = time.perf_counter()
        scene = emi.scene_dict(glb, emission="exr", lights=False)
        img = emi.render_view(scene, 0.0, math.radians(-25), 60, (w, h), args.spp, max_depth=4)
    print(f"rendered {w}x{h} at {args.spp} spp in {time.perf_counter() - t0:.1f} s")
    Image.fromarray(to_srgb8(img, exposure=1.2)).save(args.out, optimize=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
