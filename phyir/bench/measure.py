"""Measuring for ``phyir bench``: timings with their spread, peak memory and the machine's description.

Timings: every call is warmed up, then the calls are timed in turns (A B C A B C ...) so that a
change of load on a shared machine hits them alike.  On CUDA the time of a call is measured on the
device with ``torch.cuda.Event`` pairs (wall and CPU time are kept beside it); on the CPU it is the
wall time, with the process's CPU time (all threads) beside it.

Peak memory: on CUDA ``torch.cuda.max_memory_allocated`` around the call; on the CPU (Linux) the
peak resident set size (``VmHWM``, reset through ``/proc/self/clear_refs``) above the resident size
before the call.  glibc keeps freed memory resident, which hides later peaks; run the measuring
process with :data:`MALLOC_ENV` (every allocation over 64 KiB is its own mapping, returned on free)
so the resident size follows the live allocations.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import subprocess
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import torch

MALLOC_ENV = {"MALLOC_MMAP_THRESHOLD_": "65536", "MALLOC_TRIM_THRESHOLD_": "0"}


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run the block with ``n`` torch CPU threads (None: unchanged), restoring the count after."""
    old = torch.get_num_threads()
    if n is not None:
        torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def is_cuda(device: str | torch.device) -> bool:
    return torch.device(device).type == "cuda"


def spread(xs: list[float], prefix: str = "") -> dict[str, float]:
    """Median, quartiles, min and max of ``xs`` (quartiles by linear interpolation, inclusive)."""
    q = statistics.quantiles(xs, n=4, method="inclusive") if len(xs) > 1 else [xs[0]] * 3
    return {f"{prefix}median_s": statistics.median(xs), f"{prefix}q1_s": q[0], f"{prefix}q3_s": q[2],
            f"{prefix}min_s": min(xs), f"{prefix}max_s": max(xs)}


def time_calls(calls: dict[str, Callable[[], object]], device: str, repeats: int,
               warmup: int = 1) -> dict[str, dict[str, float]]:
    """Per call: ``time_s`` (the headline: device median on CUDA, wall median on the CPU), the wall
    time's median / quartiles / min / max (``median_s`` ...), CPU time (``cpu_s``, median) and, on
    CUDA, the device time's spread (``gpu_median_s`` ...).  ``repeats`` timed runs after ``warmup``."""
    cuda = is_cuda(device)
    for _ in range(warmup):
        for fn in calls.values():
            fn()
    if cuda:
        torch.cuda.synchronize(device)
    wall: dict[str, list[float]] = {k: [] for k in calls}
    cpu: dict[str, list[float]] = {k: [] for k in calls}
    gpu: dict[str, list[float]] = {k: [] for k in calls}
    for _ in range(repeats):
        for k, fn in calls.items():
            if cuda:
                start, end = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
                start.record()
            t0, c0 = time.perf_counter(), time.process_time()
            fn()
            if cuda:
                end.record()
                end.synchronize()
                gpu[k].append(start.elapsed_time(end) / 1e3)
            wall[k].append(time.perf_counter() - t0)
            cpu[k].append(time.process_time() - c0)
    out = {}
    for k in calls:
        row = {**spread(wall[k]), "cpu_s": statistics.median(cpu[k]), "repeats": repeats}
        if cuda:
            row.update(spread(gpu[k], "gpu_"))
        row["time_s"] = row["gpu_median_s" if cuda else "median_s"]
        out[k] = row
    return out


def _vm_hwm_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmHWM")) / 1024


def _vm_rss_mb() -> float:
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS")) / 1024


def cpu_peak_supported() -> bool:
    return os.path.exists("/proc/self/clear_refs") and os.access("/proc/self/clear_refs", os.W_OK)


def peak_memory(fn: Callable[[], object], device: str) -> dict[str, float]:
    """Peak memory of one call of ``fn``: ``extra_peak_mb`` above what was allocated (CUDA) or
    resident (CPU) before it, ``total_peak_mb`` including that (the process's peak resident size on
    the CPU: libraries and weights included).  Empty on a CPU without ``/proc/self/clear_refs``."""
    import gc

    gc.collect()
    if is_cuda(device):
        torch.cuda.synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)
        base = torch.cuda.memory_allocated(device)
        fn()
        torch.cuda.synchronize(device)
        peak = torch.cuda.max_memory_allocated(device)
        return {"extra_peak_mb": (peak - base) / 2**20, "total_peak_mb": peak / 2**20,
                "reserved_peak_mb": torch.cuda.max_memory_reserved(device) / 2**20}
    if not cpu_peak_supported():
        return {}
    with open("/proc/self/clear_refs", "w") as f:
        f.write("5")  # reset the peak to the current resident size
    base = _vm_rss_mb()
    fn()
    peak = _vm_hwm_mb()
    return {"extra_peak_mb": peak - base, "total_peak_mb": peak}


def measure_in_child(module: str, config: dict) -> dict:
    """Run ``python -m <module> --memory <config as JSON>`` in a fresh process with
    :data:`MALLOC_ENV` (its resident size then follows its live allocations, and nothing this
    process freed hides its peaks) and return the JSON object on the last line it prints."""
    import json
    import sys

    env = {**os.environ, **MALLOC_ENV}
    r = subprocess.run([sys.executable, "-m", module, "--memory", json.dumps(config)], env=env,
                       capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"memory child {module} failed ({r.returncode}):\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gb() -> float | None:
    try:
        with open("/proc/meminfo") as f:
            kb = next(int(line.split()[1]) for line in f if line.startswith("MemTotal"))
        return round(kb / 2**20, 1)
    except (OSError, StopIteration):
        return None


def _git_commit() -> str:
    root = Path(__file__).resolve().parents[1]
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True,
                           timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return "unknown"
    return r.stdout.strip() if r.returncode == 0 else "unknown"


def machine_info(device: str) -> dict:
    """What the numbers were measured on: CPU model and cores, memory, torch, device, load."""
    info = {"cpu": _cpu_model(), "cpu_cores": os.cpu_count(),
            "cpu_cores_usable": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else None,
            "memory_gb": _memory_gb(), "os": platform.platform(), "python": platform.python_version(),
            "torch": torch.__version__, "torch_threads": torch.get_num_threads(), "device": device,
            "device_name": torch.cuda.get_device_name(device) if is_cuda(device) else "cpu",
            "git_commit": _git_commit()}
    if hasattr(os, "getloadavg"):
        info["loadavg"] = [round(x, 2) for x in os.getloadavg()]
    return info
