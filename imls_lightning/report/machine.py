"""What a report records about its run: the command line and the machine."""
from __future__ import annotations

import os
import platform
import time


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
    def ticks() -> tuple[int, int]:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
        return sum(fields), fields[3] + (fields[4] if len(fields) > 4 else 0)

    try:
        total0, idle0 = ticks()
        time.sleep(seconds)
        total1, idle1 = ticks()
    except (OSError, ValueError, IndexError):
        return None
    total = total1 - total0
    if total <= 0:
        return 0.0
    return min(max((total - (idle1 - idle0)) / total, 0.0), 1.0) * (os.cpu_count() or 1)
