"""What a benchmark says about the machine it ran on: speed figures are ratios taken in one
run, quoted with the CPU that gave them (VMs of one kind differ 2x)."""

from __future__ import annotations

import os
import platform
from pathlib import Path


def cpu_name() -> str:
    """The CPU's model name (``lscpu``'s "Model name") and how many CPUs this process sees,
    e.g. ``Intel(R) Xeon(R) Processor (2 CPUs)``."""
    model = platform.processor() or platform.machine() or "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model} ({os.cpu_count()} CPUs)"
