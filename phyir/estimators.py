"""The estimators :func:`phyir.predict` chooses from by name: lighting methods and geometry networks.

Each estimator is a module that registers itself here at import (:func:`register_lighting`,
:func:`register_geometry`) and is declared in an entry-point group (``phyir.lighting_methods``,
``phyir.geometry_networks``), the library's own as well as other packages'.  The registries load their
group once, on the first query; ``predict``, the commands' ``choices`` and ``--help``, and the docs
read them, so a new method is one module (and its entry point).  This module is torch-free at import
so that ``phyir --help`` stays fast; an estimator imports torch inside its functions.
"""

from __future__ import annotations

import importlib.metadata
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from phyir.errors import PhyIRError

if TYPE_CHECKING:
    from torch import Tensor

DEFAULT_LIGHTING = "fused"  # the best on the synthetic split and the real panoramas (README, "The model")
DEFAULT_GEOMETRY = "gmnet"


@dataclass(frozen=True)
class LightingMethod:
    """How predict's probes are made.  ``estimate(lnet, projected)`` returns the probes (a grid
    [Hp,Wp,3,h,w] or probes at points [N,3,h,w], as ``lnet``) from LNet's and ``projected()``, the
    panorama re-read along the predicted depth (:mod:`phyir.lighting.projection`, LNet where the
    camera did not see).  Only a method that ``projects`` may call ``projected``; predict then keeps
    the depth and normals the projection needs."""

    name: str
    summary: str  # one line: what --help, the docs and menus show
    projects: bool
    estimate: Callable[[Tensor, Callable[[], Tensor]], Tensor]


@dataclass(frozen=True)
class GeometryNetwork:
    """The network that predicts depth, normals and materials.  ``load(model, device)`` returns a
    function from the exposure-normalised network input ``xn [1,3,H,W]`` to the five layers
    ``depth [1,1,H,W]``, ``normal [1,3,H,W]``, ``albedo [1,3,H,W]``, ``roughness`` and ``metallic``
    ``[1,1,H,W]`` at the input's resolution; ``model`` is the loaded :class:`phyir.nets.PhyIRModel`
    (a network with weights of its own loads them itself)."""

    name: str
    summary: str  # one line: what --help, the docs and menus show
    load: Callable[[Any, Any], Callable[[Tensor], dict[str, Tensor]]]


E = TypeVar("E", LightingMethod, GeometryNetwork)


class Registry(Generic[E]):
    """Estimators of one kind by name, in the order they registered; the entry-point ``group``'s
    modules are imported (and so register themselves) once, on the first query."""

    def __init__(self, kind: str, group: str):
        self.kind, self.group = kind, group
        self._entries: dict[str, E] = {}
        self._loaded = False
        self._lock = threading.RLock()

    def register(self, entry: E) -> E:
        """Add ``entry`` under its name and return it; an equal entry again returns the first, another
        one under the same name is a PhyIRError."""
        with self._lock:
            old = self._entries.setdefault(entry.name, entry)
            if old != entry:
                raise PhyIRError(f"{self.kind} {entry.name!r} is already registered ({old.summary})")
        return old

    def unregister(self, name: str) -> None:
        with self._lock:
            self._entries.pop(name, None)

    def _load(self) -> None:
        with self._lock:
            if self._loaded:
                return
            self._loaded = True
            for ep in sorted(importlib.metadata.entry_points(group=self.group), key=lambda e: e.name):
                ep.load()  # the module registers itself

    def get(self, name: str) -> E:
        """The entry named ``name``; a one-line PhyIRError listing the choices for any other name."""
        self._load()
        entry = self._entries.get(name) if isinstance(name, str) else None
        if entry is None:
            known = ", ".join(self.names()) or f"none: is phyir installed? (entry points {self.group})"
            raise PhyIRError(f"unknown {self.kind} {name!r} (choose from {known})")
        return entry

    def names(self) -> tuple[str, ...]:
        self._load()
        return tuple(self._entries)

    def items(self) -> list[tuple[str, E]]:
        self._load()
        return list(self._entries.items())

    def __iter__(self) -> Iterator[E]:
        return iter([e for _, e in self.items()])

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._entries

    def describe(self, default: str) -> str:
        """``name: summary`` of every entry, ``;``-separated, the default marked (for --help)."""
        return "; ".join(f"{n}: {e.summary}{' (default)' if n == default else ''}" for n, e in self.items())


_LIGHTING: Registry[LightingMethod] = Registry("lighting method", "phyir.lighting_methods")
_GEOMETRY: Registry[GeometryNetwork] = Registry("geometry network", "phyir.geometry_networks")


def lighting_methods() -> Registry[LightingMethod]:
    return _LIGHTING


def geometry_networks() -> Registry[GeometryNetwork]:
    return _GEOMETRY


def register_lighting(name: str, summary: str, estimate: Callable[[Tensor, Callable[[], Tensor]], Tensor],
                      projects: bool) -> LightingMethod:
    return _LIGHTING.register(LightingMethod(name, summary, projects, estimate))


def register_geometry(name: str, summary: str,
                      load: Callable[[Any, Any], Callable[[Tensor], dict[str, Tensor]]]) -> GeometryNetwork:
    return _GEOMETRY.register(GeometryNetwork(name, summary, load))
