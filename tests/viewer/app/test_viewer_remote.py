"""phyir-view's control socket (--listen, viewer.remote) driven by its Python client (viewer.client),
as tev's remote control: a real headless App serves between frames while the client talks from a
thread; bad commands get an error reply and the app goes on; only loopback hosts may listen."""

from __future__ import annotations

import json
import socket
import threading

import numpy as np
import pytest
import torch

from phyir.color import linear_to_srgb
from phyir.io import save_scene
from phyir.scene import PanoScene
from viewer.client import Client, RemoteError

pytestmark = pytest.mark.gl

H, W = 32, 64  # shown 1:1 in a 64x32 view without the interface
ALBEDO = {"a.exr": (0.2, 0.5, 0.8), "b.exr": (0.7, 0.3, 0.1)}


@pytest.fixture(scope="module")
def files(tmp_path_factory, egl):
    """Two panoramas with an image and a constant albedo each (read, no model)."""
    folder = tmp_path_factory.mktemp("remote")
    ramp = torch.linspace(0.1, 2.0, W).expand(3, H, W).contiguous()
    for k, (name, rgb) in enumerate(ALBEDO.items()):
        albedo = torch.tensor(rgb).view(3, 1, 1).expand(3, H, W).contiguous()
        save_scene(PanoScene(image=ramp * (k + 1), albedo=albedo), folder / name)
    return folder


@pytest.fixture()
def app(egl):
    from viewer.app import App

    a = App((W, H), headless=True, ui=False, recent=False, run_model=False)
    a.listen("127.0.0.1", 0)
    yield a
    a.close()


def drive(app, script, timeout: float = 30.0):
    """Run ``script(client)`` in a thread while the App serves commands and draws frames; its result,
    or the exception it raised."""
    out: dict = {}

    def talk():
        try:
            with Client(app.remote.address[1], timeout=10) as client:
                out["value"] = script(client)
        except BaseException as e:  # noqa: BLE001 - re-raised in the test's thread
            out["error"] = e

    thread = threading.Thread(target=talk, daemon=True)
    thread.start()
    assert app.serve_until(lambda: not thread.is_alive(), timeout), "the client did not finish in time"
    if "error" in out:
        raise out["error"]
    return out["value"]


def read_png(path) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(path).convert("RGB")).astype(np.float64)


def test_open_two_files_switch_set_a_layer_and_take_screenshots(app, files, tmp_path):
    def script(view: Client):
        first, second = view.open(files / "a.exr"), view.open(files / "b.exr")
        idle = view.wait_idle(20)
        view.select("a.exr")
        view.layer("albedo")
        shots = {"a": view.screenshot(tmp_path / "a.png")}
        view.select(1)
        shots["b"] = view.screenshot(tmp_path / "b.png")
        return first, second, idle, shots, view.status()

    first, second, idle, shots, status = drive(app, script)
    assert (first, second) == ({"index": 0, "name": "a.exr"}, {"index": 1, "name": "b.exr"})
    assert idle["current"] == 1 and [im["loaded"] for im in idle["images"]] == [True, True]
    for name, shot in shots.items():
        assert shot == {"path": str(tmp_path / f"{name}.png"), "width": W, "height": H}
        img = read_png(tmp_path / f"{name}.png")
        want = 255 * linear_to_srgb(np.array(ALBEDO[f"{name}.exr"]))
        assert img.shape == (H, W, 3) and np.abs(img - want).max() <= 1.5, name
    assert status["current"] == 1 and status["name"] == "b.exr" and status["layer"] == "albedo"
    assert status["layers"] == ["image", "albedo"]
    assert app.display.layer == "albedo" and app.images.current == 1
    assert [(im["name"], im["path"]) for im in status["images"]] == \
        [("a.exr", str(files / "a.exr")), ("b.exr", str(files / "b.exr"))]


def test_status_round_trips_reference_compare_exposure_and_close(app, files):
    def script(view: Client):
        view.open(files / "a.exr")
        view.open(files / "b.exr", show=False)
        view.wait_idle(20)
        view.reference("b.exr")
        view.compare("diff")
        view.exposure(1.5)
        during = view.status()
        view.compare("off")
        view.reference(None)
        after = view.status()
        closed = view.close_image("a.exr")
        return during, after, closed, view.status()

    during, after, closed, last = drive(app, script)
    assert (during["current"], during["reference"], during["compare"]) == (0, 1, "diff")
    assert during["exposure"] == 1.5
    assert app.display.hdr.exposure == 1.5
    assert (after["reference"], after["compare"]) == (None, None)
    assert closed == {"images": 1} and [im["name"] for im in last["images"]] == ["b.exr"]
    assert last["current"] == 0 and last["name"] == "b.exr" and app.doc.name == "b.exr"


BAD = [(b"this is not json\n", "bad JSON"),
       (b'[1, 2]\n', 'a JSON object with a "cmd"'),
       (b'{"cmd": "fly"}\n', "unknown command 'fly'"),
       (b'{"cmd": "layer"}\n', "layer: missing a required argument: 'name'"),
       (b'{"cmd": "layer", "name": "sheen"}\n', "unknown layer 'sheen'"),
       (b'{"cmd": "layer", "name": "depth"}\n', "has no depth layer (have: image, albedo)"),
       (b'{"cmd": "status", "verbose": true}\n', "unexpected keyword argument 'verbose'"),
       (b'{"cmd": "select", "image": 7}\n', "no image 7 (open: 0..0)"),
       (b'{"cmd": "select", "image": "c.exr"}\n', "no image named 'c.exr' (open: a.exr)"),
       (b'{"cmd": "exposure", "ev": "high"}\n', "ev must be a finite number"),
       (b'{"cmd": "compare", "mode": "ratio"}\n', "unknown comparison 'ratio'"),
       (b'{"cmd": "compare", "mode": "diff"}\n', "no reference image"),
       (b'{"cmd": "open", "path": "/no/such/file.exr"}\n', "no such file: /no/such/file.exr"),
       (b'{"cmd": "screenshot", "path": "/no/such/dir/s.png"}\n', "screenshot: "),
       (b'{"cmd": "status", "id": 7}\n', None)]


def test_bad_commands_get_one_line_errors_and_the_app_keeps_serving(app, files, tmp_path):
    def script(view: Client):
        view.open(files / "a.exr")
        view.wait_idle(20)
        replies = []
        with socket.create_connection(("127.0.0.1", view.port), timeout=10) as raw, raw.makefile("rb") as f:
            for line, _ in BAD:
                raw.sendall(line)
                replies.append(f.readline())
        with socket.create_connection(("127.0.0.1", view.port), timeout=10) as gone:
            # a client that leaves mid-command: its reply has nowhere to go, and a half line is all it sent
            gone.sendall(json.dumps({"cmd": "screenshot", "path": str(tmp_path / "unread.png")}).encode() +
                         b'\n{"cmd": "sta')
        with pytest.raises(RemoteError, match="refused 'layer': layer: unknown layer 'sheen'"):
            view.layer("sheen")
        return replies, view.status()

    replies, status = drive(app, script)
    for raw, (line, says) in zip(replies, BAD):
        assert raw.endswith(b"\n") and raw.count(b"\n") == 1, line
        reply = json.loads(raw)
        if says is None:
            assert reply["ok"] is True and reply["id"] == 7 and reply["name"] == "a.exr"
        else:
            assert reply["ok"] is False and says in reply["error"], (line, reply)
    assert status["name"] == "a.exr" and status["layer"] == "image" and status["error"] is None
    # the command whose client left still ran (its thread may read it after the others' replies)
    assert app.serve_until(lambda: (tmp_path / "unread.png").is_file(), 10) and app.doc.name == "a.exr"


@pytest.mark.parametrize("value,says", [("0.0.0.0:5151", "only a loopback host may listen"),
                                        ("192.168.1.4:80", "not '192.168.1.4'"),
                                        ("example.com:5151", "only a loopback host"),
                                        ("localhost:99999", "port 99999 out of range"),
                                        ("5151x", "expected [HOST:]PORT")])
def test_a_non_loopback_or_bad_listen_is_refused_in_one_line(value, says, capsys):
    from viewer.app.cli import parser

    with pytest.raises(SystemExit) as e:
        parser().parse_args(["a.exr", "--listen", value])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("phyir-view: error: argument --listen: ") and says in err[0]
    assert parser().parse_args(["--listen", "5151"]).listen == ("127.0.0.1", 5151)
    assert parser().parse_args(["--listen", "localhost:0"]).listen == ("127.0.0.1", 0)


def test_the_server_refuses_a_non_loopback_host_itself():
    from viewer.remote import Server

    with pytest.raises(ValueError, match="only a loopback host"):
        Server("0.0.0.0", 0)


def test_the_client_times_out_and_names_a_missing_viewer():
    """No GL: a server nobody serves (a viewer stuck in a long frame) and a port nobody listens on."""
    from viewer.remote import Server

    server = Server("127.0.0.1", 0)
    port = server.address[1]
    try:
        with Client(port, timeout=0.3) as view:
            with pytest.raises(TimeoutError, match="did not answer 'status' within 0.3 s"):
                view.status()
        assert view._sock is None  # dropped: the late reply can't answer the next command
        assert len(server.pending()) == 1
    finally:
        server.close()
    with pytest.raises(ConnectionRefusedError, match=f"no phyir-view listening on 127.0.0.1:{port}"):
        Client(port, timeout=1).status()


def test_headless_listen_serves_until_quit(files, tmp_path):
    """The command line's own loop (--headless --listen), run in a thread here: quit ends it."""
    from viewer.app.cli import main

    with socket.socket() as s:  # a free port (main prints the one it got; the test can't read it yet)
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rc: list[int] = []
    viewer = threading.Thread(target=lambda: rc.append(main(
        [str(files / "a.exr"), "--no-model", "--headless", "--no-ui", "--size", "96x64",
         "--listen", str(port)])), daemon=True)
    viewer.start()
    view = Client(port, timeout=10)
    for _ in range(400):  # until it listens (the App starts in a few seconds)
        try:
            view.connect()
            break
        except ConnectionRefusedError:
            viewer.join(0.05)
            assert viewer.is_alive(), f"phyir-view exited with {rc}"
    status = view.wait_idle(20)
    shot = view.screenshot(tmp_path / "s.png")
    assert view.quit() == {}
    viewer.join(20)
    view.close()
    assert rc == [0] and status["name"] == "a.exr" and status["layers"] == ["image", "albedo"]
    assert (shot["width"], shot["height"]) == (96, 64) and (tmp_path / "s.png").stat().st_size > 0


@pytest.mark.window
def test_a_window_wakes_for_commands_and_quit_ends_its_loop(display, files, tmp_path):
    """In a window (Xvfb) run()'s idle wait (1 s) ends as a command arrives: the socket wakes GLFW."""
    import time

    from viewer.app import App
    from viewer.gl import window as surfaces

    surfaces.prefer_egl()  # as the window tests: GLFW makes EGL contexts in this process
    try:
        app = App((640, 400), recent=False, run_model=False)
    except RuntimeError as e:
        pytest.skip(f"cannot open a window: {e}")
    port = app.listen()[1]
    out: dict = {}

    def talk():
        with Client(port, timeout=10) as view:
            view.open(files / "a.exr")
            view.wait_idle(20)
            waited = []
            for _ in range(2):  # each reply is followed by a few frames, then the idle wait (1 s)
                time.sleep(0.3)
                t0 = time.monotonic()
                out["status"] = view.status()
                waited.append(time.monotonic() - t0)
            out["waited"] = max(waited)  # without the wake: ~0.7 s, the rest of the idle wait
            out["shot"] = view.screenshot(tmp_path / "w.png")
            view.quit()

    thread = threading.Thread(target=talk, daemon=True)
    thread.start()
    try:
        app.run()  # returns on quit
    finally:
        app.close()
    thread.join(10)
    assert out["status"]["name"] == "a.exr" and out["waited"] < 0.35, out
    assert (out["shot"]["width"], out["shot"]["height"]) == (640, 400)
    assert read_png(tmp_path / "w.png").std() > 1  # the interface and the panorama, not a blank frame
