"""One-line user errors shared by every command of the project.

Everything a user can get wrong (a missing file, a bad parameter, a degenerate view) raises
:class:`InputError`. The command-line entry points catch it and print ``error: <message>`` on one
line, exit with status 2 and show no traceback (see :func:`cli_errors`).
"""
from __future__ import annotations

import contextlib
import functools
import math
import re
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, Sequence, TypeVar

from .overrides import quote_override_value

F = TypeVar("F", bound=Callable)


class InputError(ValueError):
    """Bad user input: names the offending parameter or file and what was expected.

    Subclasses ``ValueError`` so library users can catch either.
    """

    def __init__(self, message: str):
        # one line, always: the CLI prints it verbatim
        super().__init__(" ".join(str(message).split()))


def finite_number(value: Any, key: str, what: str) -> float:
    """``value`` as a finite float, else an :class:`InputError` ``key=value: expected what``.

    A bool is refused (``True`` is not a number here), as are NaN and infinities.

    Example:
        >>> finite_number("0.5", "model.mean", "a number in (0, 1]")
        0.5
    """
    try:
        if isinstance(value, bool):
            raise TypeError
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{key}={value!r}: expected {what}") from None
    if not math.isfinite(x):
        raise InputError(f"{key}={value!r}: expected {what}")
    return x


def boolean(value: Any, key: str) -> bool:
    """``value`` as a bool: ``True``/``False`` or the strings ``true``/``false`` (any case), else an
    :class:`InputError` ``key=value: expected true or false``."""
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise InputError(f"{key}={value!r}: expected true or false")


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


def check_group_choices(config_dir: str | Path, argv: Sequence[str]) -> None:
    """Check the config-group choices of a command line (``scene=NAME``, ``data=NAME``, ...) against
    the ``.yaml`` files of ``config_dir/<group>/``: an unknown one raises :class:`InputError` listing
    the choices there are (Hydra would print a 15-line message)."""
    root = Path(config_dir)
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+")
        if not key or "." in key or "@" in key or "/" in key or key.startswith("~"):
            continue
        group = root / key
        if not group.is_dir():
            continue
        if any(c in value for c in "()[]{}$*"):  # sweep functions, interpolations: Hydra's business
            continue
        choices = sorted(p.stem for p in group.glob("*.yaml"))
        for v in value.split(","):  # a multirun sweep: scene=tiny,flame
            v = v.strip()
            if v in ("", "null") or v in choices:
                continue
            raise InputError(f"{key}={v}: no such {key}; expected one of {', '.join(choices)}")


_HYDRA_SPECIAL = set("[]{}(),'\"$\\=")


def quote_non_ascii(argv: Sequence[str]) -> list[str]:
    """Hydra's override parser takes non-ASCII characters only inside quotes: quote the value of
    ``key=value`` when it has some (``scene.volume.path=/data/volumes_é/x.raw`` ->
    ``scene.volume.path='/data/volumes_é/x.raw'``, :func:`~data_gen.overrides.quote_override_value`). A value that also holds Hydra's own syntax
    (lists, sweeps, quotes, interpolations) is not guessed at: one-line :class:`InputError` showing
    how to quote it."""
    out = []
    for arg in argv:
        if arg.startswith("-") or "=" not in arg or arg.isascii():
            out.append(arg)
            continue
        key, value = arg.split("=", 1)
        if not key.isascii():
            raise InputError(f"{key}: config keys are ASCII names; check the spelling")
        if value.isascii() or (len(value) >= 2 and value[0] in "'\"" and value[-1] == value[0]):  # quoted already
            out.append(arg)
        elif set(value) & _HYDRA_SPECIAL:
            raise InputError(f"{arg}: Hydra reads non-ASCII characters only inside quotes; quote each string that holds them, "
                             f"e.g. '{key}=[\"/data/volumes_é/a.raw\", ...]' (single quotes around it all, for the shell)")
        else:
            out.append(f"{key}={quote_override_value(value)}")
    return out


def checked_command_line(config_dir: str | Path) -> Callable[[F], F]:
    """Decorator for a Hydra command, put *outside* ``@hydra.main``, that fixes or refuses in one
    line what Hydra would answer with a long message or a traceback, before Hydra composes
    anything: an unknown config-group choice (``scene=no_such_scene``: the ``error:`` line lists the
    choices there are) and values with non-ASCII characters (quoted, see :func:`quote_non_ascii`).
    Errors exit with status 2."""

    def wrap(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                sys.argv[1:] = quote_non_ascii(sys.argv[1:])
                check_group_choices(config_dir, sys.argv[1:])
            except InputError as err:
                print(f"error: {err}", file=sys.stderr, flush=True)
                sys.exit(2)
            return fn(*args, **kwargs)

        return wrapper  # type: ignore[return-value]

    return wrap


@contextlib.contextmanager
def config_keys(keys: Mapping[str, str]) -> Iterator[None]:
    """Name the user's key in errors of code that knows only its own argument names: an
    :class:`InputError` raised inside that starts with ``name=`` for a ``name`` in ``keys``
    (``depth=0: ...``) becomes ``keys[name]=...`` (``model.depth=0: ...``).

    Example:
        >>> with config_keys({"depth": "model.depth"}):       # doctest: +SKIP
        ...     IMLNet(16, P, depth=0)
        InputError: model.depth=0: expected an integer >= 1 (number of U-Net resolution levels)
    """
    try:
        yield
    except InputError as err:
        msg = str(err)
        m = re.match(r"([A-Za-z_][A-Za-z0-9_]*)=", msg)
        if m is None or m.group(1) not in keys:
            raise
        raise InputError(f"{keys[m.group(1)]}={msg[m.end():]}") from None
