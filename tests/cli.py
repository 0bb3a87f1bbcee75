"""A Hydra command run in this process, as ``python -m`` runs it (:func:`run_in_process`).

A subprocess pays 6-9 s on 2 cores for importing torch, Lightning and Hydra before it reads its first setting;
each documented error of a command's settings is one more such start. In this process the imports are paid once.
Every command keeps at least one test through a real ``python -m`` subprocess for its one-line stderr and exit status.
"""
from __future__ import annotations

import contextlib
import io
import logging
import runpy
import sys
from dataclasses import dataclass
from typing import Sequence


@dataclass
class CliRun:
    """What a command run left: its exit status and what it printed (``subprocess.CompletedProcess``'s fields)."""

    returncode: int
    stdout: str
    stderr: str


def run_in_process(module: str, args: Sequence[str]) -> CliRun:
    """Run ``python -m <module> <args>`` here: ``sys.argv`` set, stdout and stderr captured, the
    exit status from ``SystemExit`` (0 when ``main`` returns), Hydra's global state cleared before and after, and
    the root logger's handlers and torch's float32 matmul precision put back afterwards (Hydra's job logging
    replaces the handlers: one bound to the captured streams, or to the run's log file, would outlive the run).

    Example:
        >>> r = run_in_process("imls_lightning.train", ["model=iml", "model.mode=both"])  # doctest: +SKIP
        >>> r.returncode, r.stderr.splitlines()[-1][:17]                                  # doctest: +SKIP
        (2, 'error: model.mode')
    """
    from hydra.core.global_hydra import GlobalHydra

    out, err = io.StringIO(), io.StringIO()
    argv = sys.argv
    sys.argv = [module, *args]
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    import torch

    precision = torch.get_float32_matmul_precision()  # the train entry point sets "high" for its process
    GlobalHydra.instance().clear()
    code = 0
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                # as ``python -m`` runs it: the module's code as ``__main__`` (a package's ``__main__``), so that
                # Hydra finds ``config_path`` beside the file, as it does for a script
                runpy.run_module(module, run_name="__main__", alter_sys=True)
            except SystemExit as stop:
                code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
    finally:
        sys.argv = argv
        GlobalHydra.instance().clear()
        # the run's HydraConfig (its overrides) outlives the run too: code that asks whether it runs under Hydra
        # (report.machine.hydra_command) would read the last in-process command's
        from hydra.core.hydra_config import HydraConfig

        HydraConfig.instance().cfg = None
        for h in root.handlers:
            if h not in handlers:
                h.close()
        root.handlers[:] = handlers
        root.setLevel(level)
        torch.set_float32_matmul_precision(precision)
    return CliRun(code, out.getvalue(), err.getvalue())
