"""Subcommands of the `liverinv` command line."""
