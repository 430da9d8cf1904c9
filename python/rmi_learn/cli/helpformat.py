"""The ``--help`` layout of the ``rmi`` commands: every option that has a default says it.

argparse's own ``ArgumentDefaultsHelpFormatter`` also prints ``(default: None)`` for
required options and ``(default: False)`` for flags; this one adds ``(default: X)`` only
where the default is a value the user could have typed. An option whose absence means
something that is not a value (``--threads``: every core) says so in its own help text,
which then names the default itself and is left as written.
"""

from __future__ import annotations

import argparse


def shown_default(default: object) -> str:
    """A default as it would be typed on the command line (a tuple as ``64,128,256``)."""
    if isinstance(default, (tuple, list)):
        return ",".join(str(v) for v in default)
    return str(default)


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to the help of each optional option with a value default."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help
        if text is None or text == argparse.SUPPRESS or "default" in text:
            return text
        default = action.default
        unset = default is None or default is False or default == [] or default == ()
        if action.required or not action.option_strings or unset:
            return text
        if default is argparse.SUPPRESS or isinstance(action, argparse._StoreConstAction):
            return text
        # argparse %-formats help strings: a literal % in a default must survive that.
        return f"{text} (default: {shown_default(default).replace('%', '%%')})"
