"""What a report records about its run: the command line and the machine."""
from __future__ import annotations

import os
import platform


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
