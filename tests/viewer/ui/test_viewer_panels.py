"""A side-panel section added the way docs/architecture.md ("How to add a viewer panel") says: a
class with ``title``, ``default_open`` and ``draw()``, handed the collaborator it reads, registered
with ``Gui.add_section`` -- and the side panel draws it every frame, after the built-in sections."""

from __future__ import annotations

import pytest

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.viewer import box_room_app  # noqa: E402

pytestmark = pytest.mark.gl


class PinCount:
    """A tiny panel: how many probes the shown image has pinned (it reads ``app.pins``)."""

    default_open = True

    def __init__(self, pins):
        self.pins = pins
        self.drawn: list[int] = []

    @property
    def title(self) -> str:
        return f"Pin count ({len(self.pins)})###pin-count"

    def draw(self) -> None:
        from viewer.ui.widgets import imgui

        imgui.text(f"{len(self.pins)} probes pinned")
        self.drawn.append(len(self.pins))


def test_a_registered_panel_is_listed_and_drawn_each_frame(egl):
    app = box_room_app((1100, 640))
    try:
        panel = PinCount(app.pins)
        app.gui.add_section(panel)
        assert app.gui.sections[-1] is panel and app.gui.sections[0] is app.gui.objects_panel
        app.frame()
        assert panel.drawn == [0]
        app.pins.pin_probe(40.5, 30.5)
        app.frame()
        assert panel.drawn == [0, 1] and panel.title.startswith("Pin count (1)")
    finally:
        app.close()
