"""``phyir-view``: the interactive panorama inspector (:class:`App`, split by concern over this
package's modules; :func:`main`, the command line)."""

from viewer.app.cli import main
from viewer.app.core import App

__all__ = ["App", "main"]
