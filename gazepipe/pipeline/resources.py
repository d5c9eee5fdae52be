"""What the machine can give a unit: memory, so a stage can refuse a take it cannot finish in one line instead of
being killed by the system (or making it swap for an hour)."""

from __future__ import annotations

import os
import resource
from pathlib import Path

__all__ = ["available_memory_bytes"]


def available_memory_bytes() -> int | None:
    """Bytes this process can still allocate without swapping, or None when the system does not say.

    The least of: the kernel's estimate of memory available to new work (``MemAvailable``), the room left
    under this process's control group limit (containers, batch schedulers), and the room left under its
    address-space limit (``ulimit -v``, past which an allocation fails).
    """
    found: list[int] = []
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                found.append(int(line.split()[1]) * 1024)
                break
    except (OSError, ValueError, IndexError):
        pass
    cgroup = _cgroup_room()
    if cgroup is not None:
        found.append(cgroup)
    soft, _ = resource.getrlimit(resource.RLIMIT_AS)
    if soft != resource.RLIM_INFINITY:
        found.append(max(0, soft - _address_space_bytes()))
    return min(found) if found else None


def _cgroup_room() -> int | None:
    """Room under the cgroup v2 memory limit of this process, None without one."""
    try:
        rel = next(ln.split(":", 2)[2] for ln in Path("/proc/self/cgroup").read_text().splitlines()
                   if ln.startswith("0::"))
        folder = Path("/sys/fs/cgroup") / rel.lstrip("/")
        limit = (folder / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(0, int(limit) - int((folder / "memory.current").read_text().strip()))
    except (OSError, ValueError, StopIteration, IndexError):
        return None


def _address_space_bytes() -> int:
    try:
        return int(Path("/proc/self/statm").read_text().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0
