"""One call of a pipeline stage, described once: the library function behind an ``rmi``
command and its arguments, each argument with the words that say the same on the command
line. The command line a stage records (:attr:`Call.argv`) and the call it runs
(:meth:`Call.run`) are both derived from that one description, so they cannot disagree."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

#: How an argument reaches the library function: by position (in the order of the call's
#: arguments), by keyword, or not at all (an option the pipeline applies itself, such as the
#: thread count of torch).
ArgKind = Literal["positional", "keyword", "command line"]


@dataclass(frozen=True)
class Arg:
    """One argument of a call: ``words`` on the command line; ``value`` passed to the
    library function as ``kind`` says (``param``: its keyword)."""

    words: tuple[str, ...]
    kind: ArgKind
    value: Any = None
    param: str = ""


def flag_words(param: str, value: Any) -> tuple[str, ...]:
    """The command-line words of a keyword option: ``max_windows=4`` -> ``--max-windows 4``,
    ``debug=True`` -> ``--debug``, nothing for ``False`` and ``None``, a sequence joined by
    commas."""
    flag = "--" + param.replace("_", "-")
    if value is True:
        return (flag,)
    if value is False or value is None:
        return ()
    if isinstance(value, (tuple, list)):
        return flag, ",".join(str(v) for v in value)
    return flag, str(value)


def positional(flag: str, value: Any, words: Iterable[str] | None = None) -> Arg:
    """A positional argument, given as ``flag value`` on the command line unless ``words``."""
    spelled = (flag, str(value)) if words is None else tuple(words)
    return Arg(spelled, "positional", value)


def keyword(param: str, value: Any, words: Iterable[str] | None = None) -> Arg:
    """A keyword argument, spelled :func:`flag_words` on the command line unless ``words``."""
    spelled = flag_words(param, value) if words is None else tuple(words)
    return Arg(spelled, "keyword", value, param)


def command_line(*words: str) -> Arg:
    """Words of the command line that the call does not take (the pipeline does it)."""
    return Arg(words, "command line")


def call_only(param: str, value: Any) -> Arg:
    """A keyword argument that the command sets itself (e.g. where messages go)."""
    return Arg((), "keyword", value, param)


def options(given: Mapping[str, Any]) -> list[Arg]:
    """The keyword arguments of a preset's options for one stage, in the preset's order."""
    return [keyword(param, value) for param, value in given.items()]


@dataclass(frozen=True)
class Call:
    """One library call of a stage: ``function`` with ``args``; ``command`` names the ``rmi``
    command that does the same (``("dataset", "build")``)."""

    command: tuple[str, ...]
    function: Callable[..., object]
    args: tuple[Arg, ...]
    #: Whether the call runs torch (the pipeline's ``threads`` then set its CPU threads).
    torch: bool = False

    @property
    def argv(self) -> list[str]:
        """The ``rmi`` command line of the call (recorded in the stage's marker)."""
        return [*self.command, *(word for arg in self.args for word in arg.words)]

    def run(self) -> object:
        """Call the library function."""
        args = [a.value for a in self.args if a.kind == "positional"]
        kwargs = {a.param: a.value for a in self.args if a.kind == "keyword"}
        return self.function(*args, **kwargs)


def call(
    command: str | tuple[str, ...],
    function: Callable[..., object],
    *args: Arg | Iterable[Arg],
    torch: bool = False,
) -> Call:
    """A :class:`Call` of ``function`` with ``args`` (single arguments or lists of them)."""
    flat = [a for item in args for a in ((item,) if isinstance(item, Arg) else item)]
    name = (command,) if isinstance(command, str) else command
    return Call(name, function, tuple(flat), torch)
