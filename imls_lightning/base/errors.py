"""One-line user errors shared by every command of the project.

Everything a user can get wrong (a missing file, a bad parameter, a degenerate view) raises
:class:`InputError`. The command-line entry points catch it and print ``error: <message>`` on one
line, exit with status 2 and show no traceback (see :func:`cli_errors`); a setting no config reads is
refused the same way before Hydra composes anything (:func:`checked_command_line`), and a long command
stopped by Ctrl-C says in one line what it kept and how to resume, exit status 130 (:func:`exit_interrupted`).
"""
from __future__ import annotations

import contextlib
import functools
import math
import os
import re
import sys
from pathlib import Path
from typing import Any, Callable, Iterator, Mapping, NoReturn, Sequence, TypeVar

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


#: the exit status of a command stopped by Ctrl-C (128 + SIGINT, as a shell reports a process killed by it)
INTERRUPTED_EXIT = 130
#: set (to ``1``) in the environment of a pipeline's stage commands: a stage stopped by Ctrl-C exits 130 without its
#: own line, as the pipeline says in one line what was kept (:func:`exit_interrupted`)
PIPELINE_STAGE_ENV = "IMLS_PIPELINE_STAGE"


def exit_interrupted(kept: str) -> NoReturn:
    """A long command stopped by Ctrl-C: ``interrupted: <kept>`` on one line of stderr (what was kept and how to
    resume), then exit status 130, no traceback. Silent inside a pipeline's stage (:data:`PIPELINE_STAGE_ENV`), whose
    pipeline says it."""
    if os.environ.get(PIPELINE_STAGE_ENV) != "1":
        print(f"interrupted: {kept}", file=sys.stderr, flush=True)
    sys.exit(INTERRUPTED_EXIT)


def cli_errors(fn: F | None = None, *, interrupted: str | Callable[..., str] | None = None):
    """Decorator for a command's main function: turn :class:`InputError` into a one-line exit
    (status 2) and, with ``interrupted`` (the line, or a function of the main function's arguments that
    returns it: what was kept and how to resume), Ctrl-C into another (:func:`exit_interrupted`, status 130).

    Put it *inside* ``@hydra.main`` so that Hydra never sees the exception (it would print a
    traceback). Use it bare (``@cli_errors``) or with the Ctrl-C line (``@cli_errors(interrupted=...)``).
    """

    def decorate(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                return fn(*args, **kwargs)
            except InputError as err:
                print(f"error: {err}", file=sys.stderr, flush=True)
                sys.exit(2)
            except KeyboardInterrupt:
                if interrupted is None:
                    raise
                exit_interrupted(interrupted(*args, **kwargs) if callable(interrupted) else interrupted)

        return wrapper  # type: ignore[return-value]

    return decorate(fn) if fn is not None else decorate


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
    ``scene.volume.path='/data/volumes_é/x.raw'``, :func:`~imls_lightning.base.overrides.quote_override_value`). A value that also holds Hydra's own syntax
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


#: Hydra's flags whose value is the next argument (that argument is no override)
HYDRA_FLAGS_WITH_VALUE = frozenset({"--config-path", "-cp", "--config-name", "-cn", "--config-dir", "-cd", "--package", "-p",
                               "--experimental-rerun", "--cfg", "-c"})


def _flag_value(argv: Sequence[str], names: Sequence[str]) -> str | None:
    """The value of the last of Hydra's flags ``names`` on the command line (``-cn x`` or ``--config-name=x``)."""
    value = None
    for i, a in enumerate(argv):
        for n in names:
            if a == n and i + 1 < len(argv):
                value = argv[i + 1]
            elif a.startswith(n + "="):
                value = a[len(n) + 1:]
    return value


def _overrides(argv: Sequence[str]) -> list[str]:
    """The overrides of a command line: its ``key=value``, ``+key``, ``~key`` arguments (not flags, nor flags' values)."""
    out, skip = [], False
    for a in argv:
        if skip:
            skip = False
        elif a.startswith("-"):
            skip = a in HYDRA_FLAGS_WITH_VALUE
        elif "=" in a or a.startswith("~"):
            out.append(a)
    return out


def _children(node: Any) -> list[str]:
    from omegaconf import OmegaConf

    return [str(k) for k in node.keys()] if OmegaConf.is_dict(node) else []


def _child(node: Any, seg: str) -> Any:
    """``node``'s child ``seg`` (a key of a mapping, an index of a list), or the ``_NONE`` marker."""
    from omegaconf import OmegaConf

    if OmegaConf.is_dict(node) and seg in _children(node):
        return node._get_node(seg)
    if OmegaConf.is_list(node) and seg.lstrip("-").isdigit() and -len(node) <= int(seg) < len(node):
        return node._get_node(int(seg))
    return _NONE


_NONE = object()


def _target_params(node: Any) -> list[str] | None:
    """The arguments the ``_target_`` of config node ``node`` takes (``["*"]``: any keyword), or ``None``: ``node`` has
    no ``_target_`` (or one that cannot be imported: then it reads nothing we can name)."""
    import inspect

    from omegaconf import OmegaConf

    if not OmegaConf.is_dict(node) or "_target_" not in _children(node):
        return None
    try:
        from hydra.utils import get_object

        params = inspect.signature(get_object(str(node._get_node("_target_")._value()))).parameters.values()
    except Exception:  # an import that fails, a builtin without a signature: nothing to name
        return None
    if any(p.kind is inspect.Parameter.VAR_KEYWORD and not p.name.startswith("_") for p in params):
        return ["*"]  # **kwargs it reads (a ``**_`` swallows keys nobody reads: the tasks' run keys)
    return [p.name for p in params if p.kind not in (inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)] + \
        ["_partial_", "_recursive_", "_convert_", "_args_"]


def _reads(cfg: Any, key: str) -> str | None:
    """Whether the composed config ``cfg`` has ``key`` (``"config"``), or a ``_target_`` node above it takes it as an
    argument (``"schema"``: ``recnn.net.features`` of FoVolNet's), else ``None``."""
    node = cfg
    segs = key.split(".")
    for i, seg in enumerate(segs):
        nxt = _child(node, seg)
        if nxt is _NONE:
            params = _target_params(node) if i == len(segs) - 1 else None
            return "schema" if params is not None and (seg in params or "*" in params) else None
        node = nxt
    return "config"


def _closest(cfg: Any, key: str, groups: Sequence[str]) -> str | None:
    """The valid key nearest to ``key`` (:func:`difflib.get_close_matches` segment by segment, then over every key),
    ``+``-prefixed where only a ``_target_``'s argument reads it; ``None`` when nothing is near."""
    import difflib

    node, path, fixed, schema = cfg, [], False, False
    for i, seg in enumerate(key.split(".")):
        if _child(node, seg) is not _NONE:
            node = _child(node, seg)
            path.append(seg)
            continue
        names = _children(node) + (list(groups) if i == 0 else [])
        params = [p for p in (_target_params(node) or []) if p != "*" and not p.startswith("_")]
        match = difflib.get_close_matches(seg, names + params, n=1, cutoff=0.6)
        if not match:
            break
        path.append(match[0])
        fixed = True
        if match[0] not in names:  # a _target_'s argument: nothing below it
            schema = True
            break
        node = _child(node, match[0])
    if fixed:
        return ("+" if schema else "") + ".".join(path)
    every = [k for k in _flat_keys(cfg) if not key.startswith(k + ".")]  # not the part of the key that exists
    match = difflib.get_close_matches(key, every, n=1, cutoff=0.75)
    return match[0] if match else None


def _flat_keys(node: Any, prefix: str = "") -> list[str]:
    from omegaconf import OmegaConf

    out = []
    for k in _children(node):
        path = f"{prefix}{k}"
        out.append(path)
        child = node._get_node(k)
        if OmegaConf.is_dict(child):
            out += _flat_keys(child, path + ".")
    return out


def check_config_keys(config_dir: str | Path, config_name: str, argv: Sequence[str]) -> list[str]:
    """Check that every key a command line sets is one its config (or the ``_target_`` a config node builds) reads, so
    that a typo is one line instead of Hydra's six (``data.resolutoin=32``) or, worse, silently accepted
    (``+data.resolutoin=32``, ``+modle.x=1``: a new key nothing reads, under a new run hash).

    The config ``config_name`` of ``config_dir`` is composed with the command line's config-group choices; then
    ``key=value`` and ``~key`` need ``key`` there; ``+key=value`` and ``++key=value`` need it there or an argument of
    a ``_target_`` node above it (``++recnn.net.features=8``: FoVolNet's; a ``**_`` that swallows unknown keys reads
    none). ``+key=value`` on a key the config has already is passed on as ``++key=value``, and ``+group=name`` on a
    group the config's defaults have a slot for as ``group=name`` (Hydra would refuse to "append" either): what the
    user asked. Hydra's own
    keys (``hydra.*``, ``hydra/...``) are left to Hydra, and so is everything when ``--config-dir``/``--config-path``
    changes where the configs are.

    Returns:
        The command line, with those ``+`` made ``++`` (or dropped).

    Raises:
        InputError: ``<the argument>: no such setting ...; did you mean <the closest valid key>?`` (one line).
    """
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import OverrideType
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    argv = list(argv)
    if _flag_value(argv, ("--config-dir", "-cd", "--config-path", "-cp")) is not None or GlobalHydra.instance().is_initialized():
        return argv
    root = Path(config_dir).resolve()
    name = _flag_value(argv, ("--config-name", "-cn")) or config_name
    parser = OverridesParser.create()
    groups, values = [], []
    for arg in _overrides(argv):
        try:
            o = parser.parse_overrides([arg])[0]
        except HydraException as err:
            raise InputError(f"{arg}: not an override Hydra can read ({str(err).splitlines()[0]}); "
                             "expected key=value, +key=value or ~key (quote values with spaces or brackets)") from None
        key = o.key_or_group
        if key == "hydra" or key.startswith(("hydra.", "hydra/")):
            continue
        (groups if (root / key).is_dir() or "/" in key or o.package is not None else values).append((arg, o))
    if not values:
        return argv
    out = list(argv)
    for _attempt in range(len(groups) + 1):
        try:
            with initialize_config_dir(str(root), version_base="1.3", job_name="check"):
                cfg = compose(name, overrides=[arg for arg, _ in groups])
            break
        except (HydraException, OmegaConfBaseException, OSError, ValueError) as err:
            lines = [ln.strip() for ln in str(err).splitlines() if ln.strip()]
            first = lines[0] if lines else type(err).__name__
            # +group=x where the config's defaults have a slot for the group already: what the user asked is group=x
            slot = next((i for i, (a, o) in enumerate(groups) if o.type is OverrideType.ADD
                         and first.startswith(f"Multiple values for {o.key_or_group}.")), None)
            if slot is None:
                raise InputError(f"{' '.join(a for a, _ in groups) or config_name}: {first}") from None
            arg = groups[slot][0]
            out[out.index(arg)] = arg[1:]
            groups[slot] = (arg[1:], parser.parse_overrides([arg[1:]])[0])
    group_names = sorted(p.name for p in root.iterdir() if p.is_dir())
    for arg, o in values:
        key = o.key_or_group
        reads = _reads(cfg, key)
        if reads == "config" or (reads == "schema" and o.type in (OverrideType.ADD, OverrideType.FORCE_ADD)):
            if reads == "config" and o.type is OverrideType.ADD:
                out[out.index(arg)] = "+" + arg  # +key on a key the config has: set it (Hydra would refuse to append)
            continue
        if reads == "schema":  # key=value on an argument the config does not list: Hydra needs it appended
            raise InputError(f"{arg}: {key} is not in the config, but {key.rsplit('.', 1)[0]}._target_ takes it: "
                             f"add it with +{arg}")
        near = _closest(cfg, key, group_names)
        if o.type is OverrideType.DEL:
            near = near.lstrip("+") if near else None
            raise InputError(f"{arg}: no such setting to delete" + (f"; did you mean ~{near}?" if near else ""))
        hint = f"; did you mean {near}?" if near else "; --help lists the settings"
        if o.type in (OverrideType.ADD, OverrideType.FORCE_ADD):
            raise InputError(f"{arg}: no config or schema reads {key}{hint}")
        raise InputError(f"{arg}: no such setting{hint}")
    return out


def checked_command_line(config_dir: str | Path, config_name: str | None = None) -> Callable[[F], F]:
    """Decorator for a Hydra command, put *outside* ``@hydra.main``, that fixes or refuses in one
    line what Hydra would answer with a long message or a traceback, before Hydra composes
    anything: an unknown config-group choice (``scene=no_such_scene``: the ``error:`` line lists the
    choices there are), values with non-ASCII characters (quoted, see :func:`quote_non_ascii`) and,
    given the command's ``config_name``, a key no config reads (:func:`check_config_keys`: ``data.resolutoin=32``,
    ``+modle.x=1``, with the closest valid key). Errors exit with status 2."""

    def wrap(fn: F) -> F:
        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            try:
                sys.argv[1:] = quote_non_ascii(sys.argv[1:])
                check_group_choices(config_dir, sys.argv[1:])
                if config_name is not None:
                    sys.argv[1:] = check_config_keys(config_dir, config_name, sys.argv[1:])
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
