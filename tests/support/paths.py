"""Where things are: the repository root and the real panoramas (``../shared/panos``, optional)."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PANOS = REPO.parent / "shared" / "panos"
