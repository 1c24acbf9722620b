"""What the parts of :class:`viewer.app.App` share: constants, small state records and the
decorator that makes the App's GL and imgui contexts current."""

from __future__ import annotations

import functools
import time
from dataclasses import dataclass, field

UPLOAD_BUDGET_S = 0.004  # texture uploads per frame (seconds; at least one) so arriving layers don't stall
NEAREST_ZOOM = 1.0       # equirect zoom above which pixels are drawn as squares (nearest)
BACKGROUND = (0.11, 0.11, 0.12)


def gl_current(method):
    """Run an App method with the App's GL and imgui contexts current (several Apps may coexist)."""
    @functools.wraps(method)
    def wrapper(self, *args, **kw):
        with self.surface.current():
            if self.gui is not None:
                self.gui.make_current()
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
