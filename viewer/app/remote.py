"""The control socket's side in the app (:class:`RemoteControl`, ``phyir-view --listen``): the
commands that arrived are run on the UI thread between frames (the App owns GL)."""

from __future__ import annotations

import sys
import traceback
from collections.abc import Callable

from viewer.app import remote_commands
from viewer.remote import Server, error


class RemoteControl:
    """Owns the :class:`~viewer.remote.Server` while listening; ``wake`` wakes a window's event loop."""

    def __init__(self, wake: Callable[[], None] | None):
        self.wake = wake
        self.server: Server | None = None

    @property
    def listening(self) -> bool:
        return self.server is not None

    @property
    def address(self) -> tuple[str, int] | None:
        return None if self.server is None else self.server.address

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start the control socket on a loopback ``host``; returns the address (port 0: a free one)."""
        if self.server is not None:
            self.server.close()
        self.server = Server(host, port, wake=self.wake)
        return self.server.address

    def serve(self, app) -> bool:
        """Run the commands that arrived on ``app`` and answer them; True if there were any.  Call
        between frames: ``screenshot`` draws its own frame."""
        if self.server is None:
            return False
        requests = self.server.pending()
        for r in requests:
            try:
                r.answer(remote_commands.execute(app, r.command))
            except Exception as e:  # noqa: BLE001 - a bug in a command: its client hears, the app goes on
                traceback.print_exc(file=sys.stderr)
                r.answer(error(f"{r.command.get('cmd')}: internal error: {type(e).__name__}: {e}"))
        return bool(requests)

    def wait(self, timeout: float) -> None:
        """Sleep until a command arrives or ``timeout`` s."""
        self.server.wait(timeout)

    def close(self) -> None:
        if self.server is not None:
            self.server.close()
            self.server = None
