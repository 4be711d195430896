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


def cpu_description() -> str:
    """:func:`benchmarks.machine.cpu_name` with the core generation (AMD's families) and the
    vector extensions the network's kernels care about, from ``/proc/cpuinfo``."""
    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
            if not line.strip():
                break
    except OSError:
        return cpu_name()
    flags = set(fields.get("flags", "").split())
    extras = []
    if fields.get("vendor_id") == "AuthenticAMD":
        family, model = int(fields.get("cpu family", "0")), int(fields.get("model", "0"))
        zen = {23: "Zen 2" if model >= 0x30 else "Zen/Zen+",
               25: "Zen 4" if 0x10 <= model < 0x20 or model >= 0x60 else "Zen 3",
               26: "Zen 5"}.get(family)  # fmt: skip
        if zen:
            extras.append(f"{zen}, family {family} model {model}")
    extras.append("AVX-512" if "avx512f" in flags else ("AVX2" if "avx2" in flags else "no AVX2"))
    vnni = flags & {"avx512_vnni", "avx_vnni"}
    extras.append(f"VNNI ({', '.join(sorted(vnni))})" if vnni else "no VNNI")
    return f"{cpu_name()}: {', '.join(extras)}"
