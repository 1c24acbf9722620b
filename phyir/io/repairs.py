"""Repairs on load: each layer made finite and in range, reported once with :class:`InputWarning`."""

from __future__ import annotations

import warnings

import numpy as np

from phyir.io.layout import MASK_PREFIX
from phyir.pano import directions
from phyir.scene import NORMAL_TOL

_RANGES = {"image": (0.0, None), "probes": (0.0, None), "depth": (0.0, None), "albedo": (0.0, 1.0),
           "roughness": (0.0, 1.0), "metallic": (0.0, 1.0), "mask": (0.0, 1.0)}


class InputWarning(UserWarning):
    """Input that was usable after a repair (NaN/Inf replaced, negatives clamped, ...)."""


def repair(path: str, layer: str, a: np.ndarray) -> np.ndarray:
    """Make one layer finite and in range, warning once with the counts of what was changed.  Works
    in place on a contiguous float32 layer (the callers' raw arrays are theirs alone)."""
    a = np.ascontiguousarray(a, dtype=np.float32)
    notes = []
    bad = ~np.isfinite(a)
    if layer == "normal":
        return _repair_normals(path, a)
    if bad.any():
        n_nan = int(np.isnan(a).sum())
        fin = a[~bad]
        hi, lo = (float(fin.max()), float(fin.min())) if fin.size else (0.0, 0.0)
        np.nan_to_num(a, copy=False, nan=0.0, posinf=hi, neginf=lo)
        notes.append(f"replaced {n_nan} NaN (by 0) and {int(bad.sum()) - n_nan} Inf values "
                     "(by the largest/smallest finite value)")
    lo, hi = _RANGES["mask" if layer.startswith(MASK_PREFIX) else layer]
    if lo is not None and (below := int((a < lo).sum())):
        what = "negative radiance" if layer in ("image", "probes") else f"values below {lo:g}"
        notes.append(f"clamped {below} {what} to {lo:g}")
        np.maximum(a, lo, out=a)
    if hi is not None and (above := int((a > hi).sum())):
        notes.append(f"clamped {above} values above {hi:g}")
        np.minimum(a, hi, out=a)
    if notes:
        warnings.warn(f"{path}: {layer}: {'; '.join(notes)}", InputWarning, stacklevel=3)
    return a


def _repair_normals(path: str, n: np.ndarray) -> np.ndarray:
    """Non-finite or zero normals face the camera (-d); other non-unit normals are renormalised."""
    length = np.sqrt(np.nan_to_num(n * n, nan=0.0, posinf=np.inf).sum(0))
    broken = ~np.isfinite(n).all(0) | (length < 1e-6)
    off = ~broken & (np.abs(length - 1) > NORMAL_TOL)
    notes = []
    if broken.any():
        d = directions(*n.shape[1:]).numpy()
        n = np.where(broken[None], -d, n)
        notes.append(f"{int(broken.sum())} NaN/Inf/zero normals set to face the camera")
    if off.any():
        n = np.where(off[None], n / np.where(off, length, 1.0)[None], n)
        notes.append(f"renormalised {int(off.sum())} normals that were not unit length")
    if notes:
        warnings.warn(f"{path}: normal: {'; '.join(notes)}", InputWarning, stacklevel=4)
    return n.astype(np.float32)
