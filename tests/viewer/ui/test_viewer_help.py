"""The help window (key H) and the side panel laid out headlessly at 1394x556, the smallest window a
user reported: every line fits, and every key binding of the inserted objects is listed."""

from __future__ import annotations

import pytest

from viewer.gl import window as _surfaces

_surfaces.prefer_egl()  # imgui's renderer (PyOpenGL) must talk EGL: before OpenGL is imported

from support.viewer import box_room_app, press  # noqa: E402

pytestmark = pytest.mark.gl

SIZE = (1394, 556)


@pytest.fixture(scope="module")
def app(egl):
    a = box_room_app(SIZE)
    yield a
    a.close()


def imgui_window(app, name: str):
    from imgui_bundle import imgui

    app.gui.make_current()
    return imgui.internal.find_window_by_name(name)


def test_help_fits_the_window_and_lists_every_object_key(app):
    from imgui_bundle import imgui

    from viewer.ui.object_keys import OBJECT_KEYS

    press(app, imgui.Key.h)
    for _ in range(3):  # an auto-resized window takes a frame or two to settle
        app.frame()
    assert app.gui.menu.show_help
    win = imgui_window(app, "Keys and mouse")
    x0, y0 = win.pos.x, win.pos.y
    x1, y1 = x0 + win.size.x, y0 + win.size.y
    W, H = SIZE
    assert 0 <= x0 and x1 <= W and 0 <= y0 and y1 <= H, (x0, y0, x1, y1)
    right, bottom = x1 - win.window_padding.x, y1 - win.window_padding.y / 2
    assert win.content_size.x <= win.size.x - 2 * win.window_padding.x, "the help is cut at the right"
    assert not win.scrollbar_y, "the help is cut at the bottom"
    lines = app.gui.menu.help_lines
    assert len(lines) > 30
    for text, x, y in lines:
        size = imgui.calc_text_size(text)
        assert x + size.x <= right and y + size.y <= bottom, f"cut: {text!r} ({x + size.x:.0f} > {right:.0f})"
    # every object binding, from the table the keyboard handling runs: its key (named as imgui names
    # it, with its modifier) on a line, followed by a line of what it does
    texts = [t for t, _, _ in lines]
    for k in OBJECT_KEYS:
        name = imgui.get_key_name(getattr(imgui.Key, k.key))
        label = f"{k.mods.capitalize()}+{name}" if k.mods else name
        rows = [i for i, t in enumerate(texts) if t == label and i + 1 < len(texts)
                and texts[i + 1] == k.help and k.help.strip()]
        assert rows, f"the object key {label} is not in the help"
    press(app, imgui.Key.h)
    assert not app.gui.menu.show_help


def test_object_keys_do_what_the_help_says(app):
    """Each binding of the table acts when pressed (with exactly its modifier) and not without it."""
    from imgui_bundle import imgui

    from viewer.ui.object_keys import OBJECT_KEYS

    panel, inserted = app.gui.objects_panel, app.objects
    keys = {(k.key, k.mods): k for k in OBJECT_KEYS}

    def hit(key: str, mods: str = "") -> None:
        io = app.gui.io
        mod = {"shift": imgui.Key.mod_shift, "ctrl": imgui.Key.mod_ctrl}.get(mods)
        if mod is not None:
            io.add_key_event(mod, True)
        press(app, getattr(imgui.Key, key))
        if mod is not None:
            io.add_key_event(mod, False)
            app.frame()

    assert ("a", "") in keys
    hit("a")
    hit("a")
    assert len(inserted.objects) == 2 and inserted.selected == 1
    hit("n")
    assert inserted.selected == 0
    hit("n", "shift")
    assert inserted.selected == 1
    hit("d", "ctrl")
    assert len(inserted.objects) == 3 and inserted.selected == 2
    hit("delete", "ctrl")
    assert len(inserted.objects) == 2
    gizmo = panel.gizmo_op
    hit("m")
    assert panel.gizmo_op != gizmo
    hit("p")
    assert panel.drop_mode
    hit("p")
    assert not panel.drop_mode
    hit("b")
    assert not inserted.hook.enabled
    hit("b")
    assert inserted.hook.enabled
    hit("d")  # D alone is the comparison's key, not duplicate
    assert len(inserted.objects) == 2
    tested = {("a", ""), ("n", ""), ("n", "shift"), ("d", "ctrl"), ("delete", "ctrl"), ("m", ""), ("p", ""),
              ("b", "")}
    assert set(keys) == tested, "a new object key: test what it does here"
    while inserted.objects:
        inserted.delete(0)


def test_side_panel_lines_fit_its_width(app):
    """A pinned probe's grid-cell line, the read-out and the file name wrap instead of running off
    the panel's right edge: the panel's content is no wider than the room inside it."""
    app.pins.pin_probe(100.0, 40.0)
    x, y, w, h = app.view_rect()
    s = app.surface.scale
    app.gui.io.add_mouse_pos_event((x + w / 2) / s, (y + h / 2) / s)  # the read-out shows that pixel
    for _ in range(3):
        app.frame()
    assert app.camera.hover is not None and app.pins[0].block is not None
    panel = imgui_window(app, "##panel")
    room = panel.inner_rect.max.x - panel.inner_rect.min.x - 2 * panel.window_padding.x
    assert panel.content_size.x <= room + 0.5, (panel.content_size.x, room)
    app.gui.io.add_mouse_pos_event(-3.4e38, -3.4e38)
    app.pins.unpin()
