"""How much memory this process may use: the budget that voxelizing and eigen-solving plan against."""

from __future__ import annotations

import os


def available_memory() -> int:
    """Bytes of memory available to this process (``MemAvailable`` of ``/proc/meminfo``, else the
    free physical pages, else 4 GiB)."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return 4 << 30
