"""Recently opened files, kept in a small JSON file in the user's config folder."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from phyir.errors import PhyIRError

LIMIT = 10


def config_dir() -> Path:
    """``$XDG_CONFIG_HOME/phyir`` (``~/.config/phyir``), ``%APPDATA%\\phyir`` on Windows."""
    if sys.platform == "win32" and os.environ.get("APPDATA"):
        return Path(os.environ["APPDATA"]) / "phyir"
    base = os.environ.get("XDG_CONFIG_HOME") or os.path.join(os.path.expanduser("~"), ".config")
    return Path(base) / "phyir"


class RecentFiles:
    def __init__(self, path: str | os.PathLike | None = None, limit: int = LIMIT):
        self.path = Path(path) if path is not None else config_dir() / "recent.json"
        self.limit = limit
        self.problem: str | None = None  # why the list could not be read or written, if it couldn't
        self.files: list[str] = self._read()

    def _read(self) -> list[str]:
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return []
        except (OSError, ValueError) as e:
            self.problem = f"{self.path}: unreadable recent-files list ({e}); starting a new one"
            return []
        files = data.get("files") if isinstance(data, dict) else None
        return [f for f in files if isinstance(f, str)][: self.limit] if isinstance(files, list) else []

    def add(self, path: str | os.PathLike) -> None:
        """Move ``path`` (absolute) to the front and save the list atomically."""
        p = os.path.abspath(os.fspath(path))
        self.files = [p, *(f for f in self.files if f != p)][: self.limit]
        self.save()

    def save(self) -> None:
        """Write the list atomically; a failure (read-only config dir) is kept in ``problem``."""
        from phyir.io import atomic_write

        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_write(self.path) as tmp, open(tmp, "w", encoding="utf-8") as f:
                json.dump({"files": self.files}, f, indent=1)
        except (OSError, PhyIRError) as e:
            self.problem = f"cannot save the recent-files list: {e}"
