"""Shared fixtures: the capabilities tests need, each declared once here and skipping with its reason
where the machine lacks it (``egl``/``ctx``: a headless OpenGL 3.3 context, ``display``: an X display,
``cuda``: a CUDA device, ``panos_dir``: the real panoramas), and ``one_thread`` for the modules of
tiny networks (``pytestmark = pytest.mark.usefixtures("one_thread")``).  Builders (the box room, tiny
scenes, the fake model) are in ``tests/support/``.

Slow tests run by default (CI runs everything); skip them locally with ``pytest -m "not slow"``."""

from __future__ import annotations

import os

# Idle OpenMP threads must sleep, not spin: on a loaded 2-core machine spinning makes torch ~10x slower.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
import shutil
import subprocess

import pytest
import torch
from support.paths import PANOS


@pytest.fixture(scope="session", autouse=True)
def _torch_threads():
    # Two cores on CI; more threads than cores only adds contention.
    torch.set_num_threads(min(2, os.cpu_count() or 1))


@pytest.fixture(scope="module")
def one_thread():
    """Run the module with one torch thread (tiny networks gain nothing from two, and a busy 2-core
    machine makes two threads wait on each other), then restore."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="session")
def panos_dir():
    """The real indoor HDR panoramas (../shared/panos); tests using them skip when absent."""
    if not PANOS.is_dir() or not any(PANOS.glob("*.hdr")):
        pytest.skip("real panoramas not available (../shared/panos)")
    return PANOS


@pytest.fixture()
def rng() -> torch.Generator:
    return torch.Generator().manual_seed(1234)


@pytest.fixture(scope="session")
def cuda() -> torch.device:
    """A CUDA device; skips where there is none."""
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    return torch.device("cuda")


@pytest.fixture(scope="session")
def egl():
    """Whether a headless (EGL) OpenGL 3.3 context can be created, probed once per session: the tests
    and fixtures that make their own contexts (the app, the commands) request it; skips with the reason
    where none can (pytest keeps a session fixture's skip for every later request)."""
    moderngl = pytest.importorskip("moderngl")
    try:
        moderngl.create_standalone_context(backend="egl", require=330).release()
    except Exception as e:  # noqa: BLE001
        pytest.skip(f"no EGL OpenGL 3.3 context: {e}")


@pytest.fixture(scope="module")
def ctx(egl):
    """A headless (EGL) OpenGL 3.3 context for GL tests, one per module; skips where none can be created."""
    import moderngl

    c = moderngl.create_standalone_context(backend="egl", require=330)
    yield c
    c.release()


@pytest.fixture(scope="module")
def display():
    """A display for windows: $DISPLAY, else a private Xvfb (for the module), else skip."""
    if os.environ.get("DISPLAY"):
        yield os.environ["DISPLAY"]
        return
    xvfb = shutil.which("Xvfb")
    if xvfb is None:
        pytest.skip("no display and no Xvfb")
    r, w = os.pipe()
    proc = subprocess.Popen([xvfb, "-displayfd", str(w), "-screen", "0", "1600x1000x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as f:
        num = f.readline().strip()
    if not num:
        proc.kill()
        pytest.skip("Xvfb did not start")
    os.environ["DISPLAY"] = f":{num}"
    try:
        yield os.environ["DISPLAY"]
    finally:
        del os.environ["DISPLAY"]
        proc.terminate()
        proc.wait(10)
