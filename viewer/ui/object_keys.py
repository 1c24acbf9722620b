"""The inserted objects' keys: one table, :data:`OBJECT_KEYS`, that the keyboard handling
(:func:`handle_object_keys`) and the help window (key H, ``viewer.ui.menu_bar``) both read, so a
binding cannot exist without its line in the help."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from phyir.errors import PhyIRError
from viewer.ui.widgets import imgui

if TYPE_CHECKING:
    from viewer.ui.objects_panel import ObjectsPanel

GIZMO_OPS = ("translate", "rotate", "scale")


@dataclass(frozen=True)
class ObjectKey:
    """A key of the objects: ``key`` is an ``imgui.Key`` name (``"a"``, ``"delete"``), pressed with
    exactly ``mods`` (``""``, ``"shift"`` or ``"ctrl"``) held; ``help`` is its line in the help window."""

    key: str
    help: str
    action: Callable[[ObjectsPanel], object]
    mods: str = ""

    @property
    def label(self) -> str:
        """How the help names it: ``Ctrl+Delete``, ``Shift+N``."""
        name = imgui.get_key_name(getattr(imgui.Key, self.key))
        return f"{self.mods.capitalize()}+{name}" if self.mods else name


def _add_sphere(panel: ObjectsPanel) -> None:
    panel.inserted.add("sphere")


def _select(panel: ObjectsPanel, step: int) -> None:
    ins = panel.inserted
    n = len(ins.objects)
    if n:
        current = ins.selected if ins.selected is not None else (-1 if step > 0 else 0)
        ins.selected = (current + step) % n


def _toggle_drop(panel: ObjectsPanel) -> None:
    panel.drop_mode = not panel.drop_mode


def _next_gizmo(panel: ObjectsPanel) -> None:
    panel.gizmo_op = GIZMO_OPS[(GIZMO_OPS.index(panel.gizmo_op) + 1) % len(GIZMO_OPS)]


def _toggle_shown(panel: ObjectsPanel) -> None:
    panel.inserted.hook.enabled = not panel.inserted.hook.enabled
    panel.inserted.redraw()


def _duplicate(panel: ObjectsPanel) -> None:
    if panel.inserted.selected is not None:
        panel.inserted.duplicate(panel.inserted.selected)


def _delete(panel: ObjectsPanel) -> None:
    if panel.inserted.selected is not None:
        panel.inserted.delete(panel.inserted.selected)


# Free keys only: the layers have the digits, the display E O R T C X, the views F Z V, the images
# [ ] D G and Shift+R, probes Backspace/Delete.
OBJECT_KEYS = (
    ObjectKey("a", "add a sphere (in front of the camera, on the floor)", _add_sphere),
    ObjectKey("n", "select the next object", lambda p: _select(p, 1)),
    ObjectKey("n", "select the previous object", lambda p: _select(p, -1), "shift"),
    ObjectKey("p", "click to drop: clicks place the selected object", _toggle_drop),
    ObjectKey("m", "gizmo: move, rotate, scale (perspective view)", _next_gizmo),
    ObjectKey("b", "show / hide the objects", _toggle_shown),
    ObjectKey("d", "duplicate the selected object", _duplicate, "ctrl"),
    ObjectKey("delete", "delete the selected object", _delete, "ctrl"),
)

# what the mouse does to objects (the help's lines before the keys)
OBJECT_MOUSE = (
    ("drag an object", "slide it over the surfaces (onto tables, walls)"),
    ("gizmo", "perspective view: move, rotate, scale the selected one"),
)


def handle_object_keys(panel: ObjectsPanel, shift: bool, ctrl: bool) -> None:
    """Run the action of every object key pressed this frame with exactly its modifiers; a refusal
    (no depth and probes yet) is a message, not an exception."""
    held = "ctrl" if ctrl else "shift" if shift else ""
    for k in OBJECT_KEYS:
        if k.mods == held and not (ctrl and shift) and imgui.is_key_pressed(getattr(imgui.Key, k.key), False):
            try:
                k.action(panel)
            except PhyIRError as e:
                panel.messages.note("error", str(e))
