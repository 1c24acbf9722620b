"""What the parts of :class:`viewer.app.App` share: constants, small state records, the messages
and the decorator that makes the App's GL and imgui contexts current."""

from __future__ import annotations

import functools
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

UPLOAD_BUDGET_S = 0.004  # texture uploads per frame (seconds; at least one) so arriving layers don't stall
NEAREST_ZOOM = 1.0       # equirect zoom above which pixels are drawn as squares (nearest)
BACKGROUND = (0.11, 0.11, 0.12)


def gl_current(method):
    """Run a method with its object's GL (and imgui) contexts current: ``self.gl_context()`` (the
    App's, or the one it hands its parts; several Apps may coexist)."""
    @functools.wraps(method)
    def wrapper(self, *args, **kw):
        with self.gl_context():
            return method(self, *args, **kw)
    return wrapper


@dataclass
class Message:
    level: str  # info | warning | error
    text: str
    time: float = field(default_factory=time.monotonic)


@dataclass
class ScalarDisplay:
    colormap: str
    range: tuple[float, float]
    auto: bool = True  # range follows the data when new layers arrive


class Messages:
    """What the app says (the side panel's messages, the status bar's last one) and the error shown in
    a banner until dismissed or the next file opens; a sequence of :class:`Message`, oldest first."""

    def __init__(self, redraw: Callable[[int], None]):
        self._log: deque[Message] = deque(maxlen=50)
        self._redraw = redraw
        self.error: str | None = None

    def note(self, level: str, text: str) -> None:
        """Add a message (``level``: info, warning or error; an error is also the banner's)."""
        self._log.append(Message(level, text))
        if level == "error":
            self.error = text
        self._redraw(2)

    def __len__(self) -> int:
        return len(self._log)

    def __iter__(self) -> Iterator[Message]:
        return iter(self._log)

    def __getitem__(self, index: int) -> Message:
        return self._log[index]
