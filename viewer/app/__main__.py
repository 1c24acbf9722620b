"""``python -m viewer.app``: the ``phyir-view`` command."""

import sys

from viewer.app.cli import main

sys.exit(main())
