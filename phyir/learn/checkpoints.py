"""Resumable training checkpoints: every process's RNG states and an atomic, restricted-unpickler
checkpoint file (docs/training.md, "Resuming")."""

from __future__ import annotations

import io
import json
import random
from pathlib import Path

import torch

from phyir.errors import InputError

CKPT_FORMAT = "phyir-checkpoint-1"


def rng_state(device: torch.device) -> dict:
    st = {"torch": torch.get_rng_state(), "python": random.getstate()}
    if device.type == "cuda":
        st["cuda"] = torch.cuda.get_rng_state(device)
    return st


def set_rng_state(st: dict, device: torch.device) -> None:
    torch.set_rng_state(st["torch"])
    random.setstate(_tuplify(st["python"]))
    if device.type == "cuda" and "cuda" in st:
        torch.cuda.set_rng_state(st["cuda"], device)


def _tuplify(x):
    return tuple(_tuplify(v) for v in x) if isinstance(x, (list, tuple)) else x


def save_checkpoint(path: Path, state: dict) -> None:
    from phyir.io import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()
    torch.save(state, buf)  # serialised first: torch.save to a file hides a full disk's ENOSPC
    with atomic_write(path) as tmp:
        Path(tmp).write_bytes(buf.getbuffer())


def load_checkpoint(path: Path) -> dict:
    """A checkpoint written by :func:`save_checkpoint` (restricted unpickler: tensors and plain data)."""
    try:
        ck = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:
        raise InputError(path, f"unreadable checkpoint ({str(e).strip().splitlines()[0]})") from None
    if not isinstance(ck, dict) or ck.get("format") != CKPT_FORMAT:
        raise InputError(path, "not a PhyIR training checkpoint")
    return ck


def jsonable(x):
    return json.loads(json.dumps(x, default=str))
