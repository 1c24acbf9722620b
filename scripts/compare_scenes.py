"""Compare the pixel data of every channel of two folders of scene EXRs, byte for byte.

    git worktree add /tmp/base <rev> && (cd /tmp/base && python -m phyir.cli predict PANOS -o /tmp/a)
    phyir predict PANOS -o /tmp/b && python scripts/compare_scenes.py /tmp/a /tmp/b
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import OpenEXR


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    a, b = map(Path, argv)
    differ = 0
    for fa in sorted(a.glob("*.exr")):
        parts_a, parts_b = OpenEXR.File(str(fa)).parts, OpenEXR.File(str(b / fa.name)).parts
        for pa, pb in zip(parts_a, parts_b):
            for name, ch in pa.channels.items():
                other = pb.channels.get(name)
                if other is None or other.pixels.dtype != ch.pixels.dtype \
                        or not np.array_equal(ch.pixels, other.pixels):
                    differ += 1
                    print(f"differs: {fa.name} part {pa.name()} channel {name}")
    print("identical" if differ == 0 else f"{differ} channels differ")
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
