"""The App's side of the control socket (``phyir-view --listen``): the commands that arrived are run
on the UI thread between frames (the App owns GL), and a loop that serves them without a window."""

from __future__ import annotations

import sys
import time
import traceback
from collections.abc import Callable

from viewer.app import remote_commands
from viewer.remote import Server, error


class Remote:
    """Part of :class:`viewer.app.App`: the control socket."""

    remote: Server | None = None
    quit_requested = False  # the ``quit`` command: the loops end

    def listen(self, host: str = "127.0.0.1", port: int = 0) -> tuple[str, int]:
        """Start the control socket on a loopback ``host``; returns the address (port 0: a free one)."""
        if self.remote is not None:
            self.remote.close()
        self.remote = Server(host, port, wake=getattr(self.surface, "wake", None))
        return self.remote.address

    def serve_remote(self) -> bool:
        """Run the commands that arrived and answer them; True if there were any.  Call between
        frames: ``screenshot`` draws its own frame."""
        if self.remote is None:
            return False
        requests = self.remote.pending()
        for r in requests:
            try:
                r.answer(remote_commands.execute(self, r.command))
            except Exception as e:  # noqa: BLE001 - a bug in a command: its client hears, the app goes on
                traceback.print_exc(file=sys.stderr)
                r.answer(error(f"{r.command.get('cmd')}: internal error: {type(e).__name__}: {e}"))
        if requests:
            self.request_redraw()
        return bool(requests)

    def step(self) -> float:
        """One turn of the event loop: commands, worker events, a frame if anything changed.  Returns
        how long the loop may then wait for events (s)."""
        changed = self.serve_remote()
        changed = self.poll() or changed
        animating = self.gui is not None and self.gui.animating()
        refining = self.objects.refining()
        if changed or self.redraw_pending or self.busy or self.pending_uploads or animating or refining:
            self.frame()
        if self.redraw_pending or self.pending_uploads:
            return 0.0
        if refining:
            return 0.01  # a background job's result shows in the next frame
        if self.busy or animating:
            return 0.1  # progress animation, slow: leaves the CPU to the model
        return 1.0  # idle: sleep until an event (the worker and the socket wake a window)

    def wait_events(self, timeout: float) -> None:
        """Sleep until input, the worker or a command, or ``timeout``; headless, the worker is polled
        at least every 20 ms."""
        if self.window is not None:
            self.surface.wait(timeout)
        elif self.remote is not None:
            self.remote.wait(min(timeout, 0.02))
        else:
            time.sleep(min(timeout, 0.02))

    def serve_until(self, done: Callable[[], bool], timeout: float | None = None) -> bool:
        """Run the event loop (commands, frames) until ``done()`` or ``timeout`` s (None: no limit);
        False on timeout.  What a headless ``--listen`` and the tests run."""
        end = None if timeout is None else time.monotonic() + timeout
        while not done():
            if end is not None and time.monotonic() > end:
                return False
            self.wait_events(self.step())
        return True

    def stop_remote(self) -> None:
        if self.remote is not None:
            self.remote.close()
            self.remote = None
