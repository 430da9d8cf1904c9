"""Subcommands of the ``rmi`` CLI, one module each."""
