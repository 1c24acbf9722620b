"""Subcommands of the phyir CLI that need GL, registered through the ``phyir.commands`` entry point group."""
