"""Builders shared by the tests (scene factories, stand-ins for the model and the renderer, the
corrupt-corpus runner); tests import them as ``from support.scenes import box_room``
(``pythonpath = ["tests"]`` in pyproject.toml).  Capabilities (EGL, a display, the real panoramas,
one torch thread) are fixtures in ``tests/conftest.py``, not here; no test module imports another."""
