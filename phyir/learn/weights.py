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
from typing import TYPE_CHECKING

import torch

from phyir.errors import InputError

if TYPE_CHECKING:
    from phyir.nets.model import ModelConfig

FORMAT = "phyir-weights-1"
WEIGHTS_DIR = Path(__file__).resolve().parents[1] / "assets" / "weights"


def default_weights_path() -> Path:
    """The shipped model: ``phyir/assets/weights/phyir-effnet.safetensors`` (GMNet on the pretrained
    EfficientNet-Lite0 encoder, the lite LNet and GSNet)."""
    return WEIGHTS_DIR / "phyir-effnet.safetensors"


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

    from phyir.io.files import check_input

    path = Path(path)
    if not os.path.lexists(path):
        raise InputError(path, "weights file not found")
    check_input(path, "weights file")  # [issue 22] a FIFO, a device, a folder: said as such
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
    except RecursionError:
        raise InputError(path, "corrupt architecture metadata (nested too deeply)") from None
    return tensors, arch


# bounds of every architecture field a weights file may state (docs/robustness.md, "Weights
# metadata"): checked before anything is built, so a hostile value can't allocate a huge model
_WIDTH = (1 / 64, 4.0)  # channel multipliers (full = 1.0, lite = 0.5 / 0.25)
_INT_FIELDS = {"light_head_kernel": (1, 7), "light_scale": (1, 8), "probe_block": (1, 1024),
               "gs_width": (1, 256), "gs_radius": (0, 16)}
_CHOICES = {"norm": ("group", "batch"), "gm_encoder": ("resnet18", "efficientnet-lite0")}
GS_TARGETS = ("albedo", "roughness", "normal", "metallic")
MAX_PROBE_SIDE = 128
LOADABLE_DTYPES = (torch.float16, torch.bfloat16, torch.float32)


def _bad(path, key: str, value, expected: str) -> InputError:
    return InputError(path, f"architecture metadata {key} = {json.dumps(value)[:40]} is invalid "
                            f"(expected {expected})")


def _is_int(x) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _check_field(path, key: str, v) -> None:
    import math

    if key == "size":
        if not (isinstance(v, str) and 0 < len(v) <= 32):
            raise _bad(path, key, v, "a name such as 'lite'")
    elif key.endswith("_width") and key != "gs_width":
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and _WIDTH[0] <= v <= _WIDTH[1]):
            raise _bad(path, key, v, f"a number in {_WIDTH[0]:g}..{_WIDTH[1]:g}")
    elif key in _INT_FIELDS:
        lo, hi = _INT_FIELDS[key]
        if not (_is_int(v) and lo <= v <= hi):
            raise _bad(path, key, v, f"an integer in {lo}..{hi}")
        if key == "light_head_kernel" and v % 2 == 0:
            raise _bad(path, key, v, "an odd kernel size")
    elif key in _CHOICES:
        if v not in _CHOICES[key]:
            raise _bad(path, key, v, " or ".join(map(repr, _CHOICES[key])))
    elif key == "probe_size":
        if not (isinstance(v, list) and len(v) == 2 and all(_is_int(x) and 1 <= x <= MAX_PROBE_SIDE
                                                            for x in v)):
            raise _bad(path, key, v, f"[h, w], integers in 1..{MAX_PROBE_SIDE}")
    elif key == "gs_targets":
        if not (isinstance(v, list) and v and len(set(map(str, v))) == len(v)
                and all(t in GS_TARGETS for t in v)):
            raise _bad(path, key, v, f"a non-empty list of distinct {', '.join(GS_TARGETS)}")


def model_config(path: str | os.PathLike, arch) -> ModelConfig:
    """The :class:`ModelConfig` a weights file's architecture metadata states, every field checked
    against its bounds (type, range, allowed values); one-line InputError naming ``path``."""
    import dataclasses

    from phyir.nets.model import ModelConfig

    if not isinstance(arch, dict):
        raise InputError(path, f"corrupt architecture metadata (a {type(arch).__name__}, not an object)")
    known = {f.name for f in dataclasses.fields(ModelConfig)}
    unknown = sorted(set(arch) - known)
    if unknown:
        raise InputError(path, f"unknown architecture (fields {', '.join(unknown)[:80]})")
    for key, value in arch.items():
        _check_field(path, key, value)
    return ModelConfig.from_dict(arch)


def check_tensors(path, tensors: dict[str, torch.Tensor], want: dict[str, torch.Tensor],
                  arch_name: str, model_name: str) -> None:
    """Refuse tensors that do not fit ``want`` (names, shapes), have a dtype the model can't take
    (float16/bfloat16/float32 for float tensors, the model's own for integer buffers) or hold
    NaN/Inf values: one line naming ``path`` and the first offending tensor."""
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
        raise InputError(path, f"weights of architecture {arch_name!r} do not fit the "
                               f"{model_name!r} model: " + "; ".join(parts))
    for k, t in tensors.items():
        ok = t.dtype in LOADABLE_DTYPES if want[k].is_floating_point() else t.dtype == want[k].dtype
        if not ok:
            raise InputError(path, f"tensor {k} is {str(t.dtype).removeprefix('torch.')}; expected "
                                   "float16, bfloat16 or float32 weights")
    for k, t in tensors.items():
        if t.is_floating_point() and not bool(torch.isfinite(t).all()):
            raise InputError(path, f"tensor {k} holds NaN or infinite values: the weights are corrupt "
                                   "(or come from a diverged training run)")


def load_into(model, path: str | os.PathLike, _read: tuple | None = None) -> None:
    """Load a weights file into an existing model, refusing any architecture mismatch."""
    tensors, arch = _read or read_weights(path)
    want = model.state_dict()
    name = arch.get("size", "?") if isinstance(arch, dict) else "?"
    check_tensors(path, tensors, want, str(name), model.config.size)
    _copy_in(model, tensors, want)


def _copy_in(model, tensors: dict[str, torch.Tensor], want: dict[str, torch.Tensor]) -> None:
    """Load checked ``tensors`` into ``model``, each cast to the dtype of ``want``'s."""
    model.load_state_dict({k: v.to(want[k].dtype) for k, v in tensors.items()})


def load_model(path: str | os.PathLike | None = None, device: str | torch.device = "cpu"):
    """A :class:`PhyIRModel` built from the architecture stored in ``path`` (default: the shipped
    weights) with its weights loaded, in eval mode.  The metadata and the tensors are checked
    (:func:`model_config`, :func:`check_tensors`) against the model built on the ``meta`` device,
    before it is given memory; every value then comes from the file."""
    from phyir.nets.model import PhyIRModel

    path = Path(path) if path is not None else default_weights_path()
    tensors, arch = read_weights(path)
    config = model_config(path, arch)
    with torch.device("meta"):
        model = PhyIRModel(config)
    want = model.state_dict()
    check_tensors(path, tensors, want, config.size, config.size)
    unloaded = {name for name, _ in model.named_buffers()} - set(want)
    if unloaded:  # (a buffer outside the state dict would stay uninitialised memory)
        raise RuntimeError(f"load_model: buffers outside the state dict: {sorted(unloaded)[:3]}")
    _copy_in(_materialize(model), tensors, want)
    return model.to(device).eval()


def _materialize(model: torch.nn.Module) -> torch.nn.Module:
    """A ``meta``-device model given uninitialised CPU memory, every tensor with its meta twin's
    shape, dtype and strides (the layout picks the kernels: the outputs are bit-identical to a model
    built on the CPU): no random initialisation for the weights to overwrite. (``Module.to_empty``
    does the same but imports sympy, 0.2 s.)"""
    for module in model.modules():
        for name, p in list(module.named_parameters(recurse=False)):
            setattr(module, name, torch.nn.Parameter(torch.empty_strided(p.shape, p.stride(), dtype=p.dtype),
                                                     p.requires_grad))
        for name, b in list(module.named_buffers(recurse=False)):
            setattr(module, name, torch.empty_strided(b.shape, b.stride(), dtype=b.dtype))
    return model


def model_from_checkpoint(path: str | os.PathLike, _loaded: dict | None = None):
    """The model of a training checkpoint (``<run>/<stage>/checkpoint.pt``) in eval mode: the weights
    of a run stopped by ``--max-minutes``/``--max-steps``, which exports nothing itself."""
    from phyir.learn.checkpoints import load_checkpoint
    from phyir.nets.model import ModelConfig, PhyIRModel

    ck = _loaded if _loaded is not None else load_checkpoint(Path(path))
    try:
        model = PhyIRModel(ModelConfig.from_dict(ck["model_config"]))
        model.load_state_dict(ck["model"])
    except (KeyError, TypeError, RuntimeError) as e:
        raise InputError(path, f"checkpoint without a loadable model ({str(e).splitlines()[0]})") from None
    return model.eval()


def ship(src: str | os.PathLike, dst: str | os.PathLike, extra: dict | None = None) -> Path:
    """Store a trained export ``src`` (weights, or a training checkpoint ``.pt``) as release weights
    ``dst``: float16 tensors (half the size; the loader casts back) and ``src``'s sidecar with ``extra``
    merged in (a checkpoint's own run options and position when it has no sidecar)."""
    info: dict = {}
    if Path(src).suffix == ".pt":
        from phyir.learn.checkpoints import load_checkpoint

        ck = load_checkpoint(Path(src))  # read once: model, run options and position
        model = model_from_checkpoint(src, ck)
        info = {"from_checkpoint": {k: ck.get(k) for k in ("epoch", "batch", "step", "seconds")},
                "config": ck.get("config")}
        size = (ck.get("config") or {}).get("size")
        if size:  # predict runs the networks at the resolution they were trained at
            info["data"] = {"resolution": f"{size[0]}x{size[1]}"}
    else:
        model = load_model(src)
        if sidecar_path(src).is_file():
            info = json.loads(sidecar_path(src).read_text())
            info.pop("architecture", None)
    info |= {"stored_as": "float16", "shipped_from": str(src)} | (extra or {})
    return save_weights(model, dst, info, half=True)


# the architecture fields that belong to each sub-network (how it is run, not only its tensors: LNet
# trained on a 16x32 probe grid at 128x256 keeps its probe_block)
NETWORK_FIELDS = {"lnet": ("light_width", "light_head_kernel", "light_scale", "probe_size", "probe_block"),
                  "gsnet": ("gs_width", "gs_radius", "gs_targets")}


def with_networks_of(model, other: str | os.PathLike, names: tuple[str, ...] = ("lnet", "gsnet")):
    """``model`` with its sub-networks ``names`` replaced by those of the weights file ``other`` (a
    geometry-only run's model given the shipped LNet and GSNet, which its stage left untrained), and
    with ``other``'s architecture fields for them (:data:`NETWORK_FIELDS`); the two architectures
    must agree on those sub-networks' tensors."""
    import dataclasses

    tensors, arch = read_weights(other)
    theirs = model_config(other, arch)
    fields = {f: getattr(theirs, f) for n in names for f in NETWORK_FIELDS.get(n, ())}
    want = model.state_dict()
    part = {k: v for k, v in tensors.items() if k.split(".", 1)[0] in names}
    check_tensors(other, part, {k: v for k, v in want.items() if k.split(".", 1)[0] in names},
                  str(arch.get("size", "?")), model.config.size)
    model.load_state_dict({**want, **{k: v.to(want[k].dtype) for k, v in part.items()}})
    model.config = dataclasses.replace(model.config, **fields)
    return model


if __name__ == "__main__":  # python -m phyir.learn.weights ship SRC DST [--rest FILE]
    import sys

    args = sys.argv[1:]
    if len(args) not in (3, 5) or args[0] != "ship" or (len(args) == 5 and args[3] != "--rest"):
        sys.exit("usage: python -m phyir.learn.weights ship SRC.safetensors|CHECKPOINT.pt DST.safetensors "
                 "[--rest WEIGHTS: LNet and GSNet from these]")
    out = ship(args[1], args[2])
    if len(args) == 5:
        model = with_networks_of(load_model(out), args[4])
        info = json.loads(sidecar_path(out).read_text()) | {"lnet_gsnet_from": args[4]}
        info.pop("architecture", None)
        save_weights(model, out, info, half=True)
    print(out)
