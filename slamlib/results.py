"""One value per fact: the registry of committed benchmark results that the book's pages state.

A number that more than one page states is a *fact*: a key (:data:`FACTS`) naming what was measured, read
from one committed result ``benchmarks/results/NAME.json`` (``slamlib bench NAME``) that records the machine
and the UTC time it ran. A page states a fact by gluing it under its key (:func:`glue_facts`), never by
reading the number on its own, so two pages cannot show two values for it; the book's build check
(``tests/browser/test_book_facts.py``) fails when two pages glue different values under one key, when a glued
fact differs from the registry, or when a page glues a fact's value under another name.

Some quantities are measured by two benchmarks on the same deterministic configuration (the default filter's
ATE on the still drive is in ``slam3d`` and in ``peers``): :data:`MEASURED_TWICE` pairs them, and a unit test
holds the committed results to agree, which they do only when the benchmarks ran on the same code.

Timings of a chapter's own live runs are this build's machine's, not the benchmark's: :func:`this_machine`
labels them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from slamlib.paths import load_bench_result

__all__ = [
    "FACTS",
    "MEASURED_TWICE",
    "Fact",
    "Stated",
    "fact",
    "glue_facts",
    "machine_label",
    "this_machine",
]

#: The default filter's configuration that the ``slam3d`` and ``peers`` benchmarks share (``SLAM3DConfig``
#: defaults): its map kind and particle count, the row read from ``slam3d.json``.
DEFAULT_MAP, DEFAULT_PARTICLES = "voxel_hash", 300

#: The names of the still drive's first 300 frames and of the whole route in ``peers.json``'s ``drives``.
PEERS_STILL, PEERS_WHOLE = "default drive (0, 300)", "whole route (full=True)"


@dataclass(frozen=True)
class Fact:
    """A measured quantity: the benchmark whose committed result holds it, how to read it, its unit.

    ``read`` maps the result (the JSON as a dict) to the value; ``what`` says what was measured, on what
    workload, in words a caption can use."""

    bench: str
    read: Callable[[dict], float]
    unit: str
    what: str


@dataclass(frozen=True)
class Stated:
    """A fact's value as committed, with where it came from: ``machine`` (CPU, cores, GPU) and ``date``
    (UTC day) of the run that measured it."""

    key: str
    value: float
    unit: str
    what: str
    bench: str
    machine: str
    date: str


def _slam3d_row(
    result: dict, kind: str = DEFAULT_MAP, particles: int = DEFAULT_PARTICLES
) -> dict:
    return next(
        r for r in result["results"] if r["map"] == kind and r["particles"] == particles
    )


def _bvh_over_voxel(result: dict, field: str) -> list[float]:
    """Per particle count, the BVH map's ``field`` over the voxel map's."""
    counts = sorted({r["particles"] for r in result["results"]})
    return [
        _slam3d_row(result, "morton_bvh", p)[field]
        / _slam3d_row(result, "voxel_hash", p)[field]
        for p in counts
    ]


def _peers(drive: str, method: str, field: str) -> Callable[[dict], float]:
    return lambda result: result["drives"][drive][method][field]


def _kiss_over(drive: str, method: str) -> Callable[[dict], float]:
    """KISS-ICP's median frame time over ``method``'s on ``drive``: how many times faster ``method`` is."""

    def read(result: dict) -> float:
        d = result["drives"][drive]
        return d["kiss_icp"]["frame_ms_median"] / d[method]["frame_ms_median"]

    return read


_STILL_300 = "the still default drive's first 300 frames"
_DEFAULT = f"the default filter ({DEFAULT_PARTICLES} particles, voxel map)"

#: Every fact that pages of the book state, by key. Keys are glue names (letters, digits, hyphens).
#:
#: :meta hide-value:
FACTS: dict[str, Fact] = {
    "default-fps": Fact(
        "slam3d",
        lambda r: _slam3d_row(r)["fps"],
        "frames/s",
        f"{_DEFAULT} on {_STILL_300}, the whole loop including reading each frame's files",
    ),
    "default-ate-m": Fact(
        "slam3d",
        lambda r: _slam3d_row(r)["ate_rmse_m"],
        "m",
        f"ATE RMSE of {_DEFAULT} on {_STILL_300}",
    ),
    "bvh-ate-ratio-min": Fact(
        "slam3d",
        lambda r: min(_bvh_over_voxel(r, "ate_rmse_m")),
        "",
        f"the BVH map's ATE over the voxel map's on {_STILL_300}, least over 100-1000 particles",
    ),
    "bvh-ate-ratio-max": Fact(
        "slam3d",
        lambda r: max(_bvh_over_voxel(r, "ate_rmse_m")),
        "",
        f"the BVH map's ATE over the voxel map's on {_STILL_300}, most over 100-1000 particles",
    ),
    "bvh-fps-ratio-min": Fact(
        "slam3d",
        lambda r: min(1 / x for x in _bvh_over_voxel(r, "fps")),
        "",
        f"how many times slower the BVH map runs than the voxel map on {_STILL_300}, least",
    ),
    "bvh-fps-ratio-max": Fact(
        "slam3d",
        lambda r: max(1 / x for x in _bvh_over_voxel(r, "fps")),
        "",
        f"how many times slower the BVH map runs than the voxel map on {_STILL_300}, most",
    ),
    "whole-ate-m": Fact(
        "slam3d",
        lambda r: r["long"]["slam"]["ate_rmse_m"],
        "m",
        f"ATE RMSE of {_DEFAULT} over the whole still synthetic route",
    ),
    "whole-t-err-pct": Fact(
        "slam3d",
        lambda r: r["long"]["slam"]["kitti_t_err_percent"],
        "%",
        f"KITTI translational error of {_DEFAULT} over the whole still synthetic route",
    ),
    "whole-dr-ate-m": Fact(
        "slam3d",
        lambda r: r["long"]["dead_reckoning"]["ate_rmse_m"],
        "m",
        "ATE RMSE of dead reckoning from the same IMU data over the whole still synthetic route",
    ),
    "default-frame-ms": Fact(
        "peers",
        _peers(PEERS_STILL, "slamlib", "frame_ms_median"),
        "ms",
        f"median time per frame of {_DEFAULT} on {_STILL_300} (register_frame, no file reading)",
    ),
    "kiss-frame-ms": Fact(
        "peers",
        _peers(PEERS_STILL, "kiss_icp", "frame_ms_median"),
        "ms",
        f"KISS-ICP's median time per frame on {_STILL_300}",
    ),
    "default-over-kiss": Fact(
        "peers",
        _kiss_over(PEERS_STILL, "slamlib"),
        "",
        f"KISS-ICP's median frame time over the default filter's on {_STILL_300}",
    ),
    "lidar-over-kiss": Fact(
        "peers",
        _kiss_over(PEERS_STILL, "slamlib_lidar_only"),
        "",
        f"KISS-ICP's median frame time over LIDAR-only slamlib's on {_STILL_300}",
    ),
}

#: Facts that a second benchmark measures on the same deterministic configuration: the key, the benchmark
#: and how it reads the same quantity. Committed results must agree (to ``MEASURED_TWICE_TOLERANCE``, the
#: rounding of the JSON files); they do only when both benchmarks ran on the same code.
#:
#: :meta hide-value:
MEASURED_TWICE: dict[str, tuple[str, Callable[[dict], float]]] = {
    "default-ate-m": ("peers", _peers(PEERS_STILL, "slamlib", "ate_rmse_m")),
    "whole-ate-m": ("peers", _peers(PEERS_WHOLE, "slamlib", "ate_rmse_m")),
    "whole-dr-ate-m": ("peers", _peers(PEERS_WHOLE, "dead_reckoning", "ate_rmse_m")),
}

#: Metres: the committed results round ATEs to 4 or 5 decimals.
MEASURED_TWICE_TOLERANCE = 1e-4


def _result(bench: str) -> dict:
    result = load_bench_result(bench)
    if result is None:
        raise FileNotFoundError(
            f"benchmarks/results/{bench}.json is missing: run `slamlib bench {bench}` in a source checkout"
        )
    return result


def _label(machine: dict) -> str:
    gpu = machine.get("gpu") or "no GPU"
    return f"{machine['cores']}-core {machine['cpu']} ({gpu}) on {machine['utc'][:10]}"


def machine_label(bench: str) -> str:
    """Where and when ``bench``'s committed result was measured: ``"2-core AMD EPYC (no GPU) on 2026-11-26"``."""
    return _label(_result(bench)["machine"])


def fact(key: str) -> Stated:
    """The committed value of fact ``key`` with its unit, description and the run that measured it.

    Raises ``KeyError`` naming the known keys for an unknown one."""
    if key not in FACTS:
        raise KeyError(f"no fact {key!r}; the registry has {sorted(FACTS)}")
    f = FACTS[key]
    result = _result(f.bench)
    return Stated(
        key=key,
        value=float(f.read(result)),
        unit=f.unit,
        what=f.what,
        bench=f.bench,
        machine=_label(result["machine"]),  # the file read once
        date=result["machine"]["utc"][:10],
    )


def glue_facts(*keys: str) -> dict[str, float]:
    """Glue each fact's committed value under its key (``{glue:text}`KEY:.2f``` in a page's prose) and the
    machine that measured it under ``KEY-machine``; returns the values by key, for the page's checks."""
    from myst_nb import glue

    values = {}
    for key in keys:
        stated = fact(key)
        glue(key, stated.value, display=False)
        glue(f"{key}-machine", stated.machine, display=False)
        values[key] = stated.value
    return values


def this_machine() -> str:
    """A label for timings a page measures live: ``"on the machine that built this page (2-core AMD EPYC)"``.

    Those timings are this build's, not a committed benchmark's (:func:`fact`), and are never stated as one."""
    from slamlib.machine import describe

    m = describe()
    return f"on the machine that built this page ({m['cores']}-core {m['cpu']})"
