"""Model weights as safetensors (never pickle) with a JSON sidecar.

``<name>.safetensors`` holds the tensors and, in its metadata, the architecture
(``phyir.config``: :class:`phyir.nets.ModelConfig` as JSON).  ``<name>.json`` beside it records
what the weights were trained on and how well they do (free-form; written by the trainer).
Unreadable files and weights of another architecture raise a one-line :class:`InputError`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import torch

from phyir.errors import InputError

FORMAT = "phyir-weights-1"
WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "assets" / "weights"


def default_weights_path() -> Path:
    """The shipped lite model: ``phyir/assets/weights/phyir-lite.safetensors``."""
    return WEIGHTS_DIR / "phyir-lite.safetensors"


def sidecar_path(path: str | os.PathLike) -> Path:
    return Path(path).with_suffix(".json")


def _atomic_write_bytes(path: Path, data: bytes) -> None:
    from phyir.io import atomic_write

    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_write(path) as tmp:
        Path(tmp).write_bytes(data)


def save_weights(model, path: str | os.PathLike, info: dict | None = None, *, half: bool = False) -> Path:
    """Write ``model``'s weights (a :class:`PhyIRModel`) and, if ``info`` is given, the sidecar JSON.

    ``half`` stores float16 (half the size; loading casts back to float32).
    """
    from safetensors.torch import save

    path = Path(path)
    state = {k: (v.half() if half and v.is_floating_point() else v).detach().cpu().contiguous()
             for k, v in model.state_dict().items()}
    meta = {"format": FORMAT, "phyir.config": json.dumps(model.config.to_dict())}
    _atomic_write_bytes(path, save(state, metadata=meta))
    if info is not None:
        doc = {"architecture": model.config.to_dict(), **info}
        _atomic_write_bytes(sidecar_path(path), (json.dumps(doc, indent=1) + "\n").encode())
    return path


def read_weights(path: str | os.PathLike) -> tuple[dict[str, torch.Tensor], dict]:
    """(tensors, architecture dict) of a weights file; InputError if it is not one."""
    from safetensors import safe_open

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "weights file not found")
    try:
        with safe_open(str(path), framework="pt", device="cpu") as f:
            meta = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except Exception as e:  # safetensors raises several types for truncated/garbage files
        problem = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        raise InputError(path, f"not a readable safetensors weights file ({problem})") from e
    if meta.get("format") != FORMAT or "phyir.config" not in meta:
        raise InputError(path, f"not a PhyIR weights file (metadata format {meta.get('format')!r})")
    try:
        arch = json.loads(meta["phyir.config"])
    except json.JSONDecodeError as e:
        raise InputError(path, f"corrupt architecture metadata ({e.msg})") from e
    return tensors, arch


def load_into(model, path: str | os.PathLike, _read: tuple | None = None) -> None:
    """Load a weights file into an existing model, refusing any architecture mismatch."""
    tensors, arch = _read or read_weights(path)
    want = model.state_dict()
    missing = [k for k in want if k not in tensors]
    extra = [k for k in tensors if k not in want]
    shape = [k for k in want if k in tensors and tensors[k].shape != want[k].shape]
    if missing or extra or shape:
        parts = []
        if missing:
            parts.append(f"{len(missing)} tensors missing (e.g. {missing[0]})")
        if extra:
            parts.append(f"{len(extra)} unexpected (e.g. {extra[0]})")
        if shape:
            k = shape[0]
            parts.append(f"{len(shape)} of wrong shape (e.g. {k}: file {list(tensors[k].shape)}, "
                         f"model {list(want[k].shape)})")
        name = arch.get("size", "?") if isinstance(arch, dict) else "?"
        raise InputError(path, f"weights of architecture {name!r} do not fit the "
                               f"{model.config.size!r} model: " + "; ".join(parts))
    model.load_state_dict({k: v.to(want[k].dtype) for k, v in tensors.items()})


def load_model(path: str | os.PathLike | None = None, device: str | torch.device = "cpu"):
    """A :class:`PhyIRModel` built from the architecture stored in ``path`` (default: the shipped
    lite weights) with its weights loaded, in eval mode."""
    from phyir.nets.model import ModelConfig, PhyIRModel

    path = Path(path) if path is not None else default_weights_path()
    read = read_weights(path)
    try:
        config = ModelConfig.from_dict(read[1])
    except (TypeError, ValueError) as e:
        raise InputError(path, f"unknown architecture ({e})") from e
    model = PhyIRModel(config)
    load_into(model, path, read)
    return model.to(device).eval()


def ship(src: str | os.PathLike, dst: str | os.PathLike, extra: dict | None = None) -> Path:
    """Store a trained export ``src`` as release weights ``dst``: float16 tensors (half the size; the
    loader casts back) and ``src``'s sidecar with ``extra`` merged in."""
    model = load_model(src)
    info: dict = {}
    if sidecar_path(src).is_file():
        info = json.loads(sidecar_path(src).read_text())
        info.pop("architecture", None)
    info |= {"stored_as": "float16", "shipped_from": str(src)} | (extra or {})
    return save_weights(model, dst, info, half=True)


if __name__ == "__main__":  # python -m phyir.learn.weights ship SRC DST
    import sys

    if len(sys.argv) != 4 or sys.argv[1] != "ship":
        sys.exit("usage: python -m phyir.learn.weights ship SRC.safetensors DST.safetensors")
    print(ship(sys.argv[2], sys.argv[3]))
