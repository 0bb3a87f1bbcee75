"""Worker processes that never outlive their parent, and the files a killed writer leaves behind.

Example:
    >>> import os
    >>> pid_alive(os.getpid()), pid_alive(2 ** 22 + 1)
    (True, False)
"""
from __future__ import annotations

import os
import threading
import time
from pathlib import Path


def exit_when_orphaned(parent_pid: int, period: float = 0.5) -> None:
    """Start a daemon thread that ends this worker at once when its parent dies.

    A worker's own loop may check its parent too, but a ``Queue.get`` (or a process pool's call queue) can block
    for ever inside ``recv_bytes``: a parent killed while it was writing leaves half a message in the pipe, and
    every worker holds the pipe's write end, so no end of file ever comes. ``os._exit`` skips cleanup on purpose:
    what a worker was writing is redone on resume (a view not in the parent's log, a volume under a temporary name).
    Use it as a pool's ``initializer`` with ``initargs=(os.getpid(),)``.
    """
    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(period)
        os._exit(0)

    threading.Thread(target=watch, name="orphan-watch", daemon=True).start()


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one we may not signal counts as alive)."""
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except (OverflowError, ValueError):
        return False
    return True


def remove_stale_temporaries(path: str | Path) -> list[Path]:
    """Remove ``.<name>.<pid>.tmp`` siblings of ``path`` whose writer ``pid`` is dead (a killed
    :func:`~imls_lightning.base.atomic.atomic_write` with ``unique=True``: half-written, never renamed); returns them."""
    p = Path(path)
    gone = []
    prefix = f".{p.name}."
    for tmp in p.parent.glob(f".{p.name}.*.tmp"):
        pid = tmp.name[len(prefix):-len(".tmp")]
        if pid.isdigit() and not pid_alive(int(pid)):
            tmp.unlink(missing_ok=True)
            gone.append(tmp)
    return gone


__all__ = ["exit_when_orphaned", "pid_alive", "remove_stale_temporaries"]
