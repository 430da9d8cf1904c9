"""Subcommands of the ``rmi`` CLI, one module each."""


class InputError(Exception):
    """Raised by a command when the user's input is wrong (an option, a file, a directory
    of the wrong kind): the ``rmi`` entry point prints ``rmi COMMAND: message`` and exits
    with status 2, the same as for the input errors it recognises by type."""
