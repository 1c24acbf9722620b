"""README tables of ``phyir eval --real`` (geometry facts and lighting at a point) or of ``phyir eval
--ldr-light`` (the recovery of an 8-bit copy's light, method by method), from its JSON.

    phyir eval --real ../shared/panos --json real.json --sheet docs/img/real_eval_sheet.png
    python -m benchmarks.real_tables real.json
    phyir eval --ldr-light HDR... --clipnet checkpoints/clipnet.safetensors --json ldr.json
    python -m benchmarks.real_tables ldr.json
"""

from __future__ import annotations

import json
import statistics
import sys

GEOMETRY = ("nadir_up", "zenith_down", "floor_planarity", "consistency_deg", "yaw.depth", "yaw.normal_deg",
            "ldr.depth", "ldr.normal_deg", "confidence")


def geometry_table(geo: dict) -> list[str]:
    rooms = sorted(r for r in geo if r != "median")
    rows = [(r.replace("_1k", ""), geo[r], " (flagged)" if geo[r]["flagged"] else "") for r in rooms]
    rows.append(("median", {k: statistics.median(float(geo[r][k]) for r in rooms) for k in GEOMETRY}, ""))
    out = ["| panorama | nadir up | zenith down | floor planarity | normals vs depth | yaw: depth / normals "
           "| LDR vs HDR: depth / normals | confidence |",
           "| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, g, flag in rows:
        out.append(f"| {name} | {g['nadir_up']:.2f} | {g['zenith_down']:.2f} "
                   f"| {100 * g['floor_planarity']:.1f} % | {g['consistency_deg']:.1f}° "
                   f"| {100 * g['yaw.depth']:.1g} % / {g['yaw.normal_deg']:.1g}° "
                   f"| {100 * g['ldr.depth']:.1f} % / {g['ldr.normal_deg']:.1f}° "
                   f"| {g['confidence']:.2f}{flag} |")
    return out


def room_rows(light: dict, inp: str) -> list[tuple[str, dict]]:
    """(room, metrics) of every panorama's ``inp`` ("hdr"/"ldr") lighting row, then their median."""
    keys = sorted(k for k in light if k.endswith("/" + inp) and not k.startswith("median"))
    rows = [(k.split("/")[0].replace("_1k", ""), light[k]) for k in keys]
    return rows + [("median", {m: statistics.median(light[k][m] for k in keys) for m in light[keys[0]]})]


def lighting_table(light: dict) -> list[str]:
    out = ["| panorama | input | diffuse rel L1: ours / probe grid / naive LDR | diffuse intensity ratio "
           "| diffuse colour error | matte silver rel L1: ours / naive LDR |",
           "| --- | --- | ---: | ---: | ---: | ---: |"]
    for inp in ("hdr", "ldr"):
        for name, v in room_rows(light, inp):
            out.append(f"| {name} | {inp} | {v['light_at.diffuse.rel_l1']:.3f} "
                       f"/ {v['probe_field.diffuse.rel_l1']:.3f} / {v['naive.diffuse.rel_l1']:.3f} "
                       f"| {v['light_at.diffuse.ratio']:.2f} "
                       f"| {v['light_at.diffuse.colour_deg']:.1f}° | {v['light_at.matte_silver.rel_l1']:.3f}"
                       f" / {v['naive.matte_silver.rel_l1']:.3f} |")
    return out


def recovery_table(light: dict) -> list[str]:
    """The LDR copy's light at the camera (no parallax: the recovery of its clipped light alone, against
    the exact light there) beside the same at the protocol's point and the naive LDR."""
    out = ["| panorama | diffuse rel L1: at the camera / at the point / naive LDR "
           "| diffuse intensity ratio at the camera "
           "| matte silver rel L1: at the camera / at the point / naive LDR |",
           "| --- | ---: | ---: | ---: |"]
    for name, v in room_rows(light, "ldr"):
        cells = [" / ".join(f"{v[f'{m}.{mat}.rel_l1']:.3f}" for m in ("light_at_camera", "light_at", "naive"))
                 for mat in ("diffuse", "matte_silver")]
        out.append(f"| {name} | {cells[0]} | {v['light_at_camera.diffuse.ratio']:.2f} | {cells[1]} |")
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    doc = json.loads(open(argv[0]).read())
    if "lighting" not in doc:
        from phyir.evaluation.ldr_light import room_table

        print("\n".join(room_table(doc)))
        return 0
    print("\n".join(geometry_table(doc["geometry"]) + [""] + lighting_table(doc["lighting"]) + [""]
                    + recovery_table(doc["lighting"])))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
