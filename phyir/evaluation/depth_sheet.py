"""The real-scan benchmark's contact sheet: per room the input, the true depth, ours (median-aligned,
on the truth's colour scale) and the relative error, with a legend."""

from __future__ import annotations

import os

import numpy as np
from torch import Tensor

from phyir import pano
from phyir.color import linear_to_srgb
from phyir.sheets import ramp_colours

TILE = (128, 256)
ERROR_MAX = 0.5  # relative error shown white at this and above; 0 is black
HOLE = (255, 0, 255)  # no ground truth


def _small(x: Tensor) -> np.ndarray:
    return pano.resize_area(x.float(), *TILE).numpy()


def depth_tiles(image: Tensor, truth: Tensor, ours: Tensor, error: Tensor) -> list[tuple[str, np.ndarray]]:
    """uint8 tiles [h,w,3]: both depths in log depth between the truth's 2nd and 98th percentiles."""
    valid = _small((truth > 0).float())[0] > 0.5
    t_log = np.log(np.maximum(_small(truth)[0], 1e-3))
    lo, hi = np.percentile(t_log[valid], (2, 98)) if valid.any() else (0.0, 1.0)
    def colours(d: Tensor) -> np.ndarray:
        out = ramp_colours((np.log(np.maximum(_small(d)[0], 1e-3)) - lo) / max(hi - lo, 1e-6))
        out[~valid] = HOLE
        return out
    err = (np.clip(_small(error)[0] / ERROR_MAX, 0, 1) * 255 + 0.5).astype(np.uint8)
    err = np.repeat(err[..., None], 3, -1)
    err[~valid] = HOLE
    img = linear_to_srgb(np.clip(_small(image).transpose(1, 2, 0), 0, 1))
    return [("input", (img * 255 + 0.5).astype(np.uint8)), ("truth", colours(truth)),
            ("ours (aligned)", colours(ours)), (f"|error| / truth (white: {ERROR_MAX:g})", err)]


def save_depth_sheet(rooms: list[tuple[str, dict[str, Tensor]]], path: str | os.PathLike) -> None:
    """One row per room (``rooms``: name and :func:`phyir.evaluation.real_depth.evaluate_scan`'s
    tensors), written atomically as PNG."""
    from phyir.sheets import save_sheet

    rows = [(name, depth_tiles(t["image"], t["truth"], t["ours"], t["error"])) for name, t in rooms]
    save_sheet(path, [(name, [tile for _, tile in tiles]) for name, tiles in rows],
               [label for label, _ in rows[0][1]],
               "depth: log scale, near red to far blue; magenta: no ground truth")
