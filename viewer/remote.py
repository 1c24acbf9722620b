"""``phyir-view --listen``'s control socket: a TCP server on the loopback interface that reads
newline-delimited JSON commands and hands them to the UI thread, which answers each with one JSON line.

No GL and no App here: a thread accepts connections and one thread per connection reads its lines;
each command becomes a :class:`Request` in a queue that the App empties between frames
(``viewer.app.remote``), and the connection's thread waits for the answer and writes it.  So socket
I/O never runs on the UI thread and GL never runs on these threads.  Lines that are not a JSON object
with a ``"cmd"`` are answered here, without the UI thread.
"""

from __future__ import annotations

import ipaddress
import json
import queue
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

MAX_LINE = 1 << 20  # bytes: a longer line is an error and ends the connection (no unbounded buffering)
LOOPBACK = ("127.0.0.1", "localhost")


def loopback_host(host: str) -> str:
    """The IPv4 address to bind for ``host``; ValueError unless it is a loopback host (anyone who can
    reach the socket can open files and write screenshots: there is no authentication)."""
    if host == "localhost":
        return "127.0.0.1"
    try:
        ip = ipaddress.ip_address(host)
    except ValueError:
        ip = None
    if ip is None or ip.version != 4 or not ip.is_loopback:
        raise ValueError(f"only a loopback host may listen ({', '.join(LOOPBACK)}), not {host!r}: "
                         "the socket has no authentication")
    return host


@dataclass(eq=False)
class Request:
    """One command from a client, answered once (by the UI thread, or by ``Server.close``)."""

    command: dict
    reply: dict | None = None
    _done: threading.Event = field(default_factory=threading.Event)

    def answer(self, reply: dict) -> None:
        if not self._done.is_set():
            self.reply = reply
            self._done.set()

    def wait(self, timeout: float) -> bool:
        return self._done.wait(timeout)


def error(text: str) -> dict:
    """An error reply: one line."""
    return {"ok": False, "error": " ".join(str(text).split()) or "error"}


class Server:
    """Listens on ``host:port`` (port 0: any free port, see ``address``); ``wake`` (thread-safe) is
    called when a command arrives, so that a UI thread asleep in its event wait runs it promptly."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, wake: Callable[[], None] | None = None):
        self._sock = socket.create_server((loopback_host(host), port))
        self._sock.settimeout(0.2)  # accept() checks for close() this often
        self.address: tuple[str, int] = self._sock.getsockname()[:2]
        self._wake = wake
        self._queue: queue.SimpleQueue[Request] = queue.SimpleQueue()
        self._early: list[Request] = []  # taken from the queue by wait(), UI thread only
        self._closed = threading.Event()
        self._lock = threading.Lock()
        self._conns: dict[socket.socket, threading.Thread] = {}
        self._thread = threading.Thread(target=self._accept, name="phyir-view remote", daemon=True)
        self._thread.start()

    # -- the UI thread's side -------------------------------------------------------------------
    def pending(self) -> list[Request]:
        """The commands that arrived since the last call, oldest first."""
        out, self._early = self._early, []
        while True:
            try:
                out.append(self._queue.get_nowait())
            except queue.Empty:
                return out

    def wait(self, timeout: float) -> None:
        """Sleep until a command arrives or ``timeout`` s pass (a loop without a window to wait on)."""
        if self._early:
            return
        try:
            self._early.append(self._queue.get(timeout=max(timeout, 0.0)))
        except queue.Empty:
            pass

    def close(self, grace: float = 1.0) -> None:
        """Stop listening, answer what was never run and end the connections, after the replies
        already given are sent (within ``grace`` s: ``quit``'s own reply is one)."""
        self._closed.set()
        self._thread.join(2.0)
        self._sock.close()
        for r in self.pending():
            r.answer(error("phyir-view is closing"))
        with self._lock:
            conns = dict(self._conns)
        for conn in conns:
            _stop_reading(conn)
        end = time.monotonic() + grace
        for thread in conns.values():
            thread.join(max(0.0, end - time.monotonic()))

    # -- the socket threads ---------------------------------------------------------------------
    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            conn.settimeout(None)
            thread = threading.Thread(target=self._serve, args=(conn,), name="phyir-view remote client",
                                      daemon=True)
            with self._lock:
                self._conns[conn] = thread
            thread.start()

    def _serve(self, conn: socket.socket) -> None:
        """One client: each line read, answered in turn, until it disconnects or we close."""
        try:
            with conn, conn.makefile("rb") as lines:
                while not self._closed.is_set():
                    line = lines.readline(MAX_LINE + 1)
                    if not line:
                        return
                    if len(line) > MAX_LINE:
                        _send(conn, error(f"line longer than {MAX_LINE} bytes"))
                        return
                    if line.strip():
                        _send(conn, self._answer(line))
        except OSError:  # the client went away mid-command, or close() shut the connection
            pass
        finally:
            with self._lock:
                self._conns.pop(conn, None)

    def _answer(self, line: bytes) -> dict:
        try:
            command = json.loads(line)
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            return error(f"bad JSON: {e}")
        if not isinstance(command, dict):
            return error('expected a JSON object with a "cmd", e.g. {"cmd": "status"}')
        reply = self._run(command) if isinstance(command.get("cmd"), str) else \
            error('expected a "cmd" string, e.g. {"cmd": "status"}')
        return {**reply, "id": command["id"]} if "id" in command else reply  # the client's tag, echoed

    def _run(self, command: dict) -> dict:
        """Queue the command for the UI thread and wait for its answer."""
        if self._closed.is_set():  # (and don't wake a window that may be gone)
            return error("phyir-view is closing")
        request = Request(command)
        self._queue.put(request)
        if self._wake is not None:
            self._wake()
        while not request.wait(0.5):
            if self._closed.is_set():
                return error("phyir-view is closing")
        return request.reply


def _send(conn: socket.socket, reply: dict) -> None:
    try:
        text = json.dumps(reply, allow_nan=False, default=str)
    except ValueError as e:  # NaN or infinity: not JSON
        text = json.dumps(error(f"the reply cannot be sent as JSON: {e}"))
    conn.sendall(text.encode() + b"\n")


def _stop_reading(conn: socket.socket) -> None:
    """Wake the connection's thread from its read (it sees the end of the stream); writes still go."""
    try:
        conn.shutdown(socket.SHUT_RD)
    except OSError:
        pass
