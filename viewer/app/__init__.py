"""``phyir-view``: the interactive panorama inspector (:class:`App` and the collaborators it owns,
one per module of this package; :func:`main`, the command line)."""

from viewer.app.cli import main
from viewer.app.core import App

__all__ = ["App", "main"]
