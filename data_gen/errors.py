"""One-line user errors shared by every command of the project.

Everything a user can get wrong (a missing file, a bad parameter, a degenerate view) raises
:class:`InputError`. The command-line entry points catch it and print ``error: <message>`` on one
line, exit with status 2 and show no traceback (see :func:`cli_errors`).
"""
from __future__ import annotations

import functools
import sys
from typing import Callable, TypeVar

F = TypeVar("F", bound=Callable)


class InputError(ValueError):
    """Bad user input: names the offending parameter or file and what was expected.

    Subclasses ``ValueError`` so library users can catch either.
    """

    def __init__(self, message: str):
        # one line, always: the CLI prints it verbatim
        super().__init__(" ".join(str(message).split()))


def cli_errors(fn: F) -> F:
    """Decorator for a command's main function: turn :class:`InputError` into a one-line exit.

    Put it *inside* ``@hydra.main`` so that Hydra never sees the exception (it would print a
    traceback).
    """

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except InputError as err:
            print(f"error: {err}", file=sys.stderr, flush=True)
            sys.exit(2)

    return wrapper  # type: ignore[return-value]
