"""Shared test fixtures. Slow tests run by default (CI runs everything); skip them locally with
``pytest -m "not slow"``."""

from __future__ import annotations

import os

# Idle OpenMP threads must sleep, not spin: on a loaded 2-core machine spinning makes torch ~10x slower.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parents[1]
PANOS = REPO.parent / "shared" / "panos"


@pytest.fixture(scope="session", autouse=True)
def _torch_threads():
    # Two cores on CI; more threads than cores only adds contention.
    torch.set_num_threads(min(2, os.cpu_count() or 1))


@pytest.fixture(scope="session")
def panos_dir() -> Path:
    """The real indoor HDR panoramas (../shared/panos); tests using them skip when absent."""
    if not PANOS.is_dir() or not any(PANOS.glob("*.hdr")):
        pytest.skip("real panoramas not available (../shared/panos)")
    return PANOS


@pytest.fixture()
def rng() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


@pytest.fixture(scope="module")
def ctx():
    """A headless (EGL) OpenGL 3.3 context for GL tests; skips where none can be created."""
    import moderngl

    try:
        c = moderngl.create_standalone_context(backend="egl", require=330)
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")
    yield c
    c.release()
