"""``phyir``: one command with subcommands.

Each subcommand lives in ``phyir/commands/<name>.py`` with ``HELP`` (one line),
``add_arguments(parser)`` and ``run(args) -> int``.  Command modules import heavy dependencies inside
``run`` so ``phyir --help`` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import os
import sys

# Idle OpenMP threads sleep instead of spinning (set before torch loads; matters on busy small CPUs).
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

from phyir import __version__
from phyir.errors import PhyIRError

# Display order of subcommands; a name whose module doesn't exist yet is left out.
COMMANDS = ("info", "synth", "train", "predict", "eval", "insert", "bench")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="phyir",
        description="Physics-based inverse rendering of indoor 360° panoramas (PhyIR).",
    )
    parser.add_argument("--version", action="version", version=f"phyir {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMANDS:
        modname = f"phyir.commands.{name}"
        if importlib.util.find_spec(modname) is None:
            continue
        mod = importlib.import_module(modname)
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except PhyIRError as e:
        print(f"phyir {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"phyir {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
