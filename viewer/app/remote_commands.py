"""The control socket's commands (``phyir-view --listen``, docs/viewer.md): each takes the App and the
command's arguments and returns the reply's fields, calling the same methods of the App's
collaborators (``app.images``, ``app.display``, ...) as the menus and keys; run on the UI thread
between frames (``viewer.app.remote``).  A bad argument raises PhyIRError, which becomes
``{"ok": false, "error": ...}``."""

from __future__ import annotations

import inspect
import math
import os
from collections.abc import Callable

from phyir.errors import PhyIRError
from viewer.compare import MODES
from viewer.layers import LAYERS
from viewer.remote import error

Image = int | str  # an image: its 0-based index in the list, or its name or path


def execute(app, command: dict) -> dict:
    """Run one command; the reply, ``{"ok": true, ...}`` or ``{"ok": false, "error": "one line"}``."""
    args = {k: v for k, v in command.items() if k not in ("cmd", "id")}
    name = command.get("cmd")
    fn = COMMANDS.get(name)
    if fn is None:
        return error(f"unknown command {name!r} (commands: {', '.join(COMMANDS)})")
    try:
        inspect.signature(fn).bind(app, **args)
    except TypeError as e:  # a missing or unexpected argument
        params = list(inspect.signature(fn).parameters)[1:]
        return error(f"{name}: {e} (arguments: {', '.join(params) or 'none'})")
    try:
        return {"ok": True, **(fn(app, **args) or {})}
    except (PhyIRError, OSError) as e:
        return error(f"{name}: {e}")


def _image(app, image: Image) -> int:
    """The index of an image given by index, name or path."""
    n = len(app.images)
    if isinstance(image, int) and not isinstance(image, bool):
        if not 0 <= image < n:
            raise PhyIRError(f"no image {image} (open: 0..{n - 1})")
        return image
    if not isinstance(image, str):
        raise PhyIRError(f"an image is an index or a name, not {image!r}")
    named = [k for k, e in enumerate(app.images) if app.images.label(e) == image]
    if len(named) > 1:
        raise PhyIRError(f"{len(named)} images are named {image!r}: give the index or the path")
    found = named[0] if named else _by_path(app, image)
    if found is None:
        labels = ", ".join(app.images.label(e) for e in app.images)
        raise PhyIRError(f"no image named {image!r} (open: {labels})")
    return found


def _by_path(app, path: str) -> int | None:
    e = app.images.find(path)
    return None if e is None else app.images.index(e)


def _string(value, what: str) -> str:
    if not isinstance(value, str) or not value:
        raise PhyIRError(f"{what} must be a non-empty string, got {value!r}")
    return value


# -- the commands -------------------------------------------------------------------------------
def open_(app, path: str, show: bool = True) -> dict:
    """Add a file to the open images (read in the background); ``show``: make it the current one."""
    path = _string(path, "path")
    if not os.path.isfile(path):
        raise PhyIRError(f"no such file: {path}")
    e = app.images.add(path) if show else app.images.queue(path)
    return {"index": app.images.index(e), "name": app.images.label(e)}


def close(app, image: Image | None = None) -> dict:
    app.images.close(None if image is None else _image(app, image))
    return {"images": len(app.images)}


def reload(app) -> None:
    app.images.reload()


def layer(app, name: str) -> None:
    if name not in LAYERS:
        raise PhyIRError(f"unknown layer {name!r} (choose from {', '.join(LAYERS)})")
    have = app.doc.available()
    if name not in have and not app.loader.busy:  # (while busy the model may still add it)
        raise PhyIRError(f"{app.doc.name or 'the image'} has no {name} layer "
                         f"(have: {', '.join(have) or 'none'})")
    app.display.set_layer(name)


def exposure(app, ev: float) -> None:
    if isinstance(ev, bool) or not isinstance(ev, int | float) or not (math.isfinite(ev) and -64 <= ev <= 64):
        raise PhyIRError(f"ev must be a finite number in [-64, 64], got {ev!r}")
    app.display.set_exposure(ev)


def select(app, image: Image) -> None:
    app.images.select(_image(app, image))


def reference(app, image: Image | None) -> None:
    app.images.set_reference(None if image is None else _image(app, image))


def compare(app, mode: str) -> None:
    if mode not in (*MODES, "off"):
        raise PhyIRError(f"unknown comparison {mode!r} (choose from {', '.join(MODES)}, off)")
    app.comparison.set_mode(None if mode == "off" else mode)


def screenshot(app, path: str) -> dict:
    """Draw a frame and write it as PNG; the reply comes once it is written."""
    path = os.path.abspath(_string(path, "path"))
    img = app.screenshot(path)
    return {"path": path, "width": int(img.shape[1]), "height": int(img.shape[0])}


def status(app) -> dict:
    def describe(k: int, e) -> dict:
        path = e.doc.path or (e.source if isinstance(e.source, str) else None)
        return {"index": k, "name": app.images.label(e), "path": path, "loaded": e.loaded}

    return {"current": app.images.current, "name": app.doc.name, "layer": app.display.layer,
            "layers": app.doc.available(), "images": [describe(k, e) for k, e in enumerate(app.images)],
            "reference": app.images.reference_index,
            "compare": app.comparison.mode, "exposure": app.display.hdr.exposure,
            "busy": bool(app.loader.busy or app.doc.pending_uploads),
            "error": app.messages.error}


def quit_(app) -> None:
    """Close the viewer once the reply is sent (the window's loop and a headless --listen end)."""
    app.quit_requested = True


COMMANDS: dict[str, Callable[..., dict | None]] = {
    "open": open_, "close": close, "reload": reload, "layer": layer, "exposure": exposure,
    "select": select, "reference": reference, "compare": compare, "screenshot": screenshot,
    "status": status, "quit": quit_}
