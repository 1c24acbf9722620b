"""A Python client for ``phyir-view --listen PORT`` (docs/viewer.md, "Remote control"); no GL, no torch:
only the standard library.

    from viewer.client import Client

    with Client(5151) as view:
        view.open("room.exr")
        view.wait_idle()
        view.layer("albedo")
        view.screenshot("albedo.png")
        print(view.status()["images"])

Each method sends one command and returns the reply's fields; a ``{"ok": false}`` reply raises
:class:`RemoteError` with the viewer's one-line reason, no reply within ``timeout`` seconds raises
TimeoutError.  Paths are made absolute here, as the viewer may run in another directory.
"""

from __future__ import annotations

import json
import os
import socket
import time

Image = int | str  # an image: its 0-based index in the viewer's list, or its name or path


class RemoteError(Exception):
    """The viewer refused a command (``{"ok": false, "error": ...}``)."""

    def __init__(self, command: str, error: str):
        super().__init__(f"phyir-view refused {command!r}: {error}")
        self.command, self.error = command, error


class Client:
    """A connection to a viewer on ``host:port``, opened on the first command (or ``connect``)."""

    def __init__(self, port: int, host: str = "127.0.0.1", timeout: float = 30.0):
        self.host, self.port, self.timeout = host, int(port), float(timeout)
        self._sock: socket.socket | None = None
        self._lines = None

    # -- the connection -------------------------------------------------------------------------
    def connect(self) -> Client:
        if self._sock is None:
            try:
                self._sock = socket.create_connection((self.host, self.port), timeout=self.timeout)
            except ConnectionRefusedError:
                raise ConnectionRefusedError(f"no phyir-view listening on {self.host}:{self.port} "
                                             f"(start it with --listen {self.port})") from None
            self._lines = self._sock.makefile("rb")
        return self

    def close(self) -> None:
        """Disconnect (the viewer goes on; closing an image is ``close_image``)."""
        if self._sock is not None:
            self._lines.close()
            self._sock.close()
            self._sock = self._lines = None

    def __enter__(self) -> Client:
        return self.connect()

    def __exit__(self, *exc) -> None:
        self.close()

    def call(self, cmd: str, timeout: float | None = None, **args) -> dict:
        """Send ``{"cmd": cmd, **args}`` and return the reply; RemoteError if it is not ok."""
        limit = self.timeout if timeout is None else timeout
        self.connect()
        self._sock.settimeout(limit)
        try:
            self._sock.sendall(json.dumps({"cmd": cmd, **args}).encode() + b"\n")
            line = self._lines.readline()
        except TimeoutError:
            self.close()  # a late reply would answer the next command: start afresh
            raise TimeoutError(f"phyir-view did not answer {cmd!r} within {limit:g} s") from None
        if not line:
            self.close()
            raise ConnectionError(f"phyir-view closed the connection during {cmd!r}")
        reply = json.loads(line)
        if not reply.get("ok"):
            raise RemoteError(cmd, reply.get("error", "no reason given"))
        reply.pop("ok")
        return reply

    # -- the commands ---------------------------------------------------------------------------
    def open(self, path: str | os.PathLike, show: bool = True) -> dict:
        """Add a file to the open images (read in the background; ``wait_idle`` waits for it);
        ``show``: make it the current image.  Returns its ``index`` and ``name``."""
        return self.call("open", path=os.path.abspath(path), show=show)

    def close_image(self, image: Image | None = None) -> dict:
        """Close an image (default: the current one)."""
        return self.call("close", **({} if image is None else {"image": image}))

    def reload(self) -> dict:
        return self.call("reload")

    def layer(self, name: str) -> dict:
        return self.call("layer", name=name)

    def exposure(self, ev: float) -> dict:
        return self.call("exposure", ev=ev)

    def select(self, image: Image) -> dict:
        return self.call("select", image=image)

    def reference(self, image: Image | None) -> dict:
        """The image to compare with; None: none."""
        return self.call("reference", image=image)

    def compare(self, mode: str) -> dict:
        """diff, reldiff, sqerr, split or off."""
        return self.call("compare", mode=mode)

    def screenshot(self, path: str | os.PathLike) -> dict:
        """Write the view as PNG; returns once written (``path``, ``width``, ``height``)."""
        return self.call("screenshot", path=os.path.abspath(path))

    def status(self) -> dict:
        """current, name, layer, layers, images (index, name, path, loaded), reference, compare,
        exposure, busy, error."""
        return self.call("status")

    def quit(self) -> dict:
        """Close the viewer (it answers first)."""
        return self.call("quit")

    def wait_idle(self, timeout: float = 60.0, interval: float = 0.05) -> dict:
        """Poll ``status`` until the viewer has read its files and run the model; its last status."""
        end = time.monotonic() + timeout
        while True:
            s = self.status()
            if not s["busy"]:  # (the viewer starts the next file's job as one finishes)
                return s
            if time.monotonic() > end:
                raise TimeoutError(f"phyir-view still busy after {timeout:g} s")
            time.sleep(interval)
