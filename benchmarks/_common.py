"""Helpers every benchmark script shares: what machine the figures come from, how busy it was, peak memory,
plain tables, and results written atomically.

The scripts run as ``python benchmarks/bench_*.py``, so this module is importable as ``_common``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
from typing import Any

import torch

__all__ = [
    "add_threads_argument",
    "machine",
    "machine_load",
    "describe_load",
    "source_fingerprint",
    "status_kib",
    "reset_peak",
    "table",
    "verdict",
    "write_json",
    "save_figure",
]


def machine() -> dict[str, Any]:
    """What the figures were measured on."""
    model = platform.processor()
    try:
        with open("/proc/cpuinfo") as f:
            model = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return {
        "cpu": model,
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "platform": platform.platform(),
        "date": datetime.datetime.now().isoformat(timespec="seconds"),
    }


def machine_load() -> dict[str, Any]:
    """Load average and, where the kernel has it, CPU pressure (PSI ``some avg60``: share of time that some task
    waited for a CPU): how busy the shared machine was."""
    out: dict[str, Any] = {"loadavg": os.getloadavg()}
    try:
        with open("/proc/pressure/cpu") as f:
            fields = dict(kv.split("=") for kv in f.readline().split()[1:])
        out["cpu_pressure_some_avg60"] = float(fields["avg60"])
    except (OSError, KeyError, ValueError):
        pass
    return out


def describe_load(load: dict[str, Any]) -> str:
    text = "load average " + " ".join(f"{x:.2f}" for x in load["loadavg"])
    if "cpu_pressure_some_avg60" in load:
        text += f", CPU pressure {load['cpu_pressure_some_avg60']:.0f}% (some, avg60)"
    return text


def source_fingerprint() -> str:
    """sha256 (12 hex digits) of the installed ``torchfluidwarp`` sources: ties the figures to a code state."""
    import hashlib
    import pathlib

    import torchfluidwarp

    root = pathlib.Path(torchfluidwarp.__file__).parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def status_kib(field: str) -> float:
    """A ``/proc/self/status`` memory field (``VmRSS``, ``VmHWM``) in KiB."""
    with open("/proc/self/status") as f:
        return float(next(line.split()[1] for line in f if line.startswith(field + ":")))


def reset_peak() -> bool:
    """Return freed heap to the OS and reset this process's ``VmHWM`` to its current RSS (Linux >= 4.0).

    ``ru_maxrss`` cannot be reset, and a process started by ``exec`` inherits its parent's peak RSS into
    it (the kernel carries the old address space's high-water mark over), so a child's ``ru_maxrss`` never
    reads below the parent's RSS at launch. ``VmHWM`` after this reset is the peak of this process alone.
    Returns whether the reset worked.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def add_threads_argument(parser: argparse.ArgumentParser) -> None:
    """The benchmarks' ``--threads``: torch CPU threads, default 1."""
    parser.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: on a small shared machine, multi-threaded kernels stall for a scheduler "
        "slice whenever another process holds a core)",
    )


def table(headers: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(headers)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(headers), line(["-" * w for w in widths]), *map(line, rows)])


def verdict(ok: bool) -> str:
    return "met" if ok else "NOT met"


def write_json(path: str, result: Any, default: Any = None) -> None:
    """Write ``result`` as indented JSON to ``path`` through a temporary file, so a crash never leaves half a file."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(result, f, indent=2, default=default)
    os.replace(tmp, path)


def save_figure(fig: Any, path: str) -> None:
    """Save a matplotlib figure to ``path`` through a temporary file, and close it."""
    import matplotlib.pyplot as plt

    tmp = path + ".tmp.png"
    fig.savefig(tmp)
    plt.close(fig)
    os.replace(tmp, path)
