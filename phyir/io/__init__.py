"""Reading and writing panoramas and scene files (format spec: docs/file-formats.md).

* ``load_panorama(path) -> Tensor[3,H,W]`` and ``load_scene(path) -> PanoScene`` read OpenEXR
  (plain or PhyIR scene files), Radiance ``.hdr`` and 8/16-bit PNG/JPEG (sRGB decoded to linear).
  The format is recognised by the file's signature, not its name.
* ``save_panorama(t, path)`` writes by extension: ``.exr``, ``.hdr``, ``.png`` (8 or 16 bit, sRGB),
  ``.jpg``; ``save_scene(scene, path)`` writes the multi-part scene ``.exr``.
* Every write is atomic (:func:`atomic_write`).
* Unusable input raises :class:`InputError` ("<file>: <problem>").  Repairable input (NaN/Inf,
  negative radiance, out-of-range layers) is repaired and reported with :class:`InputWarning`;
  a returned tensor never holds NaN or Inf.

This file is the package's facade; the code lives by topic: ``raw.py`` (what a file holds, before
repair: :func:`read_raw`), ``repairs.py``, ``loaders.py`` (``load_*``, :func:`read_scene`),
``writers.py`` (``save_*``), ``layout.py`` (the scene file's channel names), ``sniff.py`` (format
and size rules), ``files.py`` (atomic writes, input checks) and the format codecs ``exr.py``,
``rgbe.py``, ``ldr.py``.
"""

from __future__ import annotations

from phyir.errors import InputError
from phyir.io import exr, files, ldr, rgbe
from phyir.io.files import (
    AtomicSet,
    atomic_files,
    atomic_write,
    check_input,
    check_output,
    folder_files,
    is_temporary,
)
from phyir.io.layout import LAYER_CHANNELS, MASK_PREFIX, META_PREFIX
from phyir.io.loaders import load_panorama, load_scene, read_scene
from phyir.io.raw import RawFile, RawPart, read_raw
from phyir.io.repairs import InputWarning
from phyir.io.sniff import (
    ASPECT_TOL,
    MAX_SIZE,
    MIN_SIZE,
    check_expansion,
    check_panorama_size,
    check_size,
    header_size,
    sniff,
)
from phyir.io.writers import save_panorama, save_scene

__all__ = [
    "InputError", "InputWarning", "AtomicSet", "atomic_write", "atomic_files", "check_input", "check_output",
    "folder_files", "is_temporary", "load_panorama", "load_scene", "save_panorama",
    "save_scene", "read_raw", "read_scene", "check_panorama_size", "check_size", "header_size", "sniff",
    "LAYER_CHANNELS", "MIN_SIZE", "MAX_SIZE", "ASPECT_TOL",
    "MASK_PREFIX", "META_PREFIX", "RawFile", "RawPart", "check_expansion", "exr", "files", "ldr", "rgbe",
]
