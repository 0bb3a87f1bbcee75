"""What a report records about its run: the command line and the machine."""
from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass


def hydra_command(module: str, fallback: str) -> str:
    """The command line of the running Hydra app (``python -m <module> <overrides>``, an override
    with a space quoted), for reports; ``fallback`` when not run through Hydra.

    Example:
        >>> hydra_command("imls_lightning.evaluate", "evaluate(cfg) through the Python API")
        'evaluate(cfg) through the Python API'
    """
    try:
        from shlex import quote

        from hydra.core.hydra_config import HydraConfig

        if HydraConfig.initialized():
            args = " ".join(quote(a) if " " in a else a for a in HydraConfig.get().overrides.task)
            return f"python -m {module} {args}".rstrip()
    except Exception:  # informative only
        pass
    return fallback


def machine_info(device: str = "cpu") -> dict[str, str]:
    """CPU model, cores, library versions and the device the networks ran on."""
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {"cpu": cpu, "cores": str(os.cpu_count()), "python": platform.python_version(),
            "platform": platform.platform()}
    try:
        import torch

        info["torch"] = torch.__version__
        info["torch threads"] = str(torch.get_num_threads())
        if str(device).startswith("cuda") and torch.cuda.is_available():
            info["device"] = f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
        else:
            info["device"] = str(device)
    except Exception:  # informative only
        info["device"] = str(device)
    for mod, attr in (("numba", "__version__"), ("vtk", None)):
        try:
            m = __import__(mod)
            info[mod] = m.vtkVersion.GetVTKVersion() if mod == "vtk" else getattr(m, attr)
        except Exception:
            info[mod] = "not installed"
    return info


def busy_cores(seconds: float = 0.5) -> float | None:
    """How many CPU cores were busy over the next ``seconds`` (from ``/proc/stat``: all but idle and
    I/O wait), a number in ``[0, cores]``; ``None`` where there is no ``/proc/stat``. Read before a
    timing, it says whether other jobs share the cores the timing will use.

    Example:
        >>> b = busy_cores(0.05)
        >>> b is None or 0.0 <= b <= os.cpu_count()
        True
    """
    first = _cpu_ticks()
    time.sleep(seconds)
    second = _cpu_ticks()
    if first is None or second is None:
        return None
    (total0, idle0), (total1, idle1) = first, second
    total = total1 - total0
    if total <= 0:
        return 0.0
    return min(max((total - (idle1 - idle0)) / total, 0.0), 1.0) * (os.cpu_count() or 1)


#: cores other jobs may keep busy while something is timed (more: its times read high; seed_shell's C pattern
#: measured 383 ms beside another job and 258 ms alone, and its bound 1.04x against a measured 0.88x; rt_plumes's
#: IML/S decoder 193 ms in its row, timed beside a niced test suite, and 50 ms with the cores free)
BUSY_LIMIT = 0.25


def shared_cores_warning(busy: float | None, what: str) -> str | None:
    """One line when ``busy`` cores (:func:`busy_cores` read before a timing, or :class:`OtherLoad` around it)
    exceed :data:`BUSY_LIMIT`, else ``None``.

    Example:
        >>> shared_cores_warning(0.02, "this estimate") is None
        True
        >>> shared_cores_warning(1.5, "this estimate")
        'warning: this estimate was timed while other jobs kept 1.50 cores busy: its times read high; measure it with the cores free'
    """
    if busy is None or busy <= BUSY_LIMIT:
        return None
    return f"warning: {what} was timed while other jobs kept {busy:.2f} cores busy: its times read high; measure it with the cores free"


def _cpu_ticks() -> tuple[int, int] | None:
    """``(all, idle + I/O wait)`` clock ticks of every core since boot, from ``/proc/stat``'s first line (user ..
    steal: guest time is inside user time), or None where there is no ``/proc/stat``."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
        return sum(fields[:8]), fields[3] + (fields[4] if len(fields) > 4 else 0)
    except (OSError, ValueError, IndexError):
        return None


def _busy_seconds() -> float | None:
    """CPU seconds every core of the machine has been busy since boot (all but idle and I/O wait), or None."""
    ticks = _cpu_ticks()
    return None if ticks is None else (ticks[0] - ticks[1]) / os.sysconf("SC_CLK_TCK")


def others_cores(busy_s: float, own_s: float, wall_s: float, cores: int) -> float:
    """The cores other processes kept busy over ``wall_s`` seconds: the machine's busy CPU seconds ``busy_s`` less
    this process's own ``own_s`` (every thread of it), per second, in ``[0, cores]``.

    Example:
        >>> others_cores(busy_s=3.0, own_s=2.0, wall_s=2.0, cores=2)   # 2 s of ours, 1 s of someone else's
        0.5
        >>> others_cores(busy_s=1.9, own_s=2.0, wall_s=2.0, cores=2)   # the clocks' granularity: never below 0
        0.0
    """
    if wall_s <= 0:
        return 0.0
    return min(max((busy_s - own_s) / wall_s, 0.0), float(cores))


@dataclass
class OtherLoad:
    """Around a timed block, how many cores *other* processes kept busy (:func:`others_cores`): the machine's busy
    time from ``/proc/stat`` less this process's own CPU time (``os.times``, all its threads: the ray caster's and
    the networks'). :func:`busy_cores` read before a timing misses a job that starts during it, and read during it
    counts the timing itself. ``cores`` is None where there is no ``/proc/stat``.

    Example:
        >>> with OtherLoad() as load:
        ...     _ = sum(range(10_000))
        >>> load.cores is None or 0.0 <= load.cores <= os.cpu_count()
        True
    """

    cores: float | None = None
    own_cores: float = 0.0  # the cores this process itself kept busy over the block
    seconds: float = 0.0

    def __enter__(self) -> "OtherLoad":
        self._busy0, self._own0, self._t0 = _busy_seconds(), _own_seconds(), time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        busy1, own1 = _busy_seconds(), _own_seconds()
        self.seconds = time.perf_counter() - self._t0
        self.own_cores = (own1 - self._own0) / self.seconds if self.seconds > 0 else 0.0
        if self._busy0 is None or busy1 is None:
            self.cores = None
        else:
            self.cores = others_cores(busy1 - self._busy0, own1 - self._own0, self.seconds, os.cpu_count() or 1)


def _own_seconds() -> float:
    t = os.times()
    return t.user + t.system
