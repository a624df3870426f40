"""Describe the machine a result was measured on (benchmarks, sweeps), so committed results say where they came from."""

from __future__ import annotations

import datetime as _dt
import os
import platform


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _gpu_name() -> str | None:
    if os.environ.get("NUMBA_ENABLE_CUDASIM") == "1":
        return "numba CUDA simulator (no GPU)"
    try:
        from numba import cuda

        if cuda.is_available():
            return (
                cuda.get_current_device().name.decode()
                if isinstance(cuda.get_current_device().name, bytes)
                else str(cuda.get_current_device().name)
            )
    except Exception:  # noqa: BLE001 - any driver problem means "no usable GPU"
        return None
    return None


def describe() -> dict:
    """Return CPU model, usable cores, GPU (if any), Python and key library versions, and the UTC time.

    With a GPU, also the numba-cuda version (its compiler decides what the card runs)."""
    from importlib import metadata

    import numba
    import numpy

    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        cores = os.cpu_count()
    gpu = _gpu_name()
    described = {
        "cpu": _cpu_model(),
        "cores": cores,
        "gpu": gpu,
        "python": platform.python_version(),
        "numpy": numpy.__version__,
        "numba": numba.__version__,
        "platform": platform.platform(),
        "utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
    }
    if gpu is not None:
        try:
            described["numba_cuda"] = metadata.version("numba-cuda")
        except metadata.PackageNotFoundError:
            described["numba_cuda"] = None
    return described
