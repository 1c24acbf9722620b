"""Subcommands of the phyir CLI (see phyir.cli)."""
