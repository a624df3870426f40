"""Static analysis of the CUDA kernels: compile each for a real card's architecture without a GPU.

Numba's simulator runs the kernels as Python; it checks the arithmetic, not whether NVVM can compile them for a
card (typing of uint64 constants, local arrays, device-function calls, float64 use). This module compiles every
kernel of :mod:`slamlib.kernels.cuda` to PTX with ``numba.cuda.compile_ptx`` (NVVM and libdevice from the
``nvidia-nvvm`` wheel) and assembles the PTX to SASS with nvJitLink (``nvidia-nvjitlink`` wheel, ``-verbose``),
reading ptxas' report: registers per thread, stack frame, spill stores / loads, static shared memory. No driver
and no GPU are needed: the ``cudacompile`` extra of slamlib installs the three CUDA 13 wheels (``nvidia-nvvm``,
``nvidia-cuda-nvrtc``, which numba-cuda needs to locate the toolkit, ``nvidia-nvjitlink``; CUDA 13 like the
``cuda-bindings`` 13 of requirements.lock).

The argument types are the ones the host wrappers really pass: :func:`capture_launches` runs every wrapper of
:mod:`slamlib.kernels.cuda` once on tiny inputs in the simulator with the kernels replaced by recorders that note
each launch's numba argument types (``numba.typeof`` of device arrays, ``bool``, ``np.int64``, ``float``: the
same typing the real dispatcher applies) and launch configuration. Capturing needs the simulator and compiling
needs it off (``NUMBA_ENABLE_CUDASIM`` is read when numba is imported), so :func:`static_report` runs each in
a subprocess (``python -m slamlib.kernels.cuda_static capture|compile``).

Without a driver, numba-cuda compiles device functions "for the current device" (it asks the driver for the
compute capability); :func:`compile_launch` answers that query with the target's compute capability, one
target per process (device functions are cached per argument types, not per target).

:func:`occupancy` is the theoretical occupancy from the documented per-SM limits
(:data:`GPUS`; CUDA C++ Programming Guide, "Technical Specifications per Compute Capability", and the CUDA
Occupancy Calculator's allocation granularities). All of it is static analysis, not measurement.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: Targets checked by default: A100 (sm_80) and H100 (sm_90).
DEFAULT_CCS = ((8, 0), (9, 0))

#: Documented per-SM limits (CUDA C++ Programming Guide, Table "Technical Specifications per Compute
#: Capability"; shared memory: the largest carve-out, 164 KB on 8.0 and 228 KB on 9.0, 1 KB reserved per block;
#: register allocation: 256 registers per warp granularity) and the SM count of the named card.
GPUS = {
    "A100": {
        "cc": (8, 0),
        "sms": 108,
        "max_warps_per_sm": 64,
        "max_blocks_per_sm": 32,
        "regs_per_sm": 65536,
        "reg_alloc_unit": 256,
        "smem_per_sm": 164 * 1024,
        "smem_reserved_per_block": 1024,
        "smem_alloc_unit": 128,
    },
    "H100": {
        "cc": (9, 0),
        "sms": 132,
        "max_warps_per_sm": 64,
        "max_blocks_per_sm": 32,
        "regs_per_sm": 65536,
        "reg_alloc_unit": 256,
        "smem_per_sm": 228 * 1024,
        "smem_reserved_per_block": 1024,
        "smem_alloc_unit": 128,
    },
}

_TOOLCHAIN_HINT = (
    "the CUDA compile check needs NVVM, NVRTC and nvJitLink from the package registry: "
    "`make setup` installs them (pip install -c requirements.lock -e '.[cudacompile]')"
)


# ------------------------------------------------------------------------------------------ argument types
def type_spec(numba_type) -> str | dict:
    """JSON form of a kernel argument's numba type: ``{"dtype", "ndim", "layout"}`` for arrays, else its name."""
    from numba.core import types

    if isinstance(numba_type, types.Array):
        return {
            "dtype": str(numba_type.dtype),
            "ndim": numba_type.ndim,
            "layout": numba_type.layout,
        }
    return str(numba_type)


def spec_type(spec):
    """The numba type of a :func:`type_spec` value."""
    from numba.core import types

    scalars = {str(t): t for t in (*types.number_domain, types.boolean)}
    if isinstance(spec, dict):
        return types.Array(scalars[spec["dtype"]], int(spec["ndim"]), spec["layout"])
    return scalars[spec]


def _dim(config) -> int:
    return int(np.prod(config)) if isinstance(config, tuple) else int(config)


class _Recorder:
    """Stands in for a kernel: ``rec[grid, block](*args)`` notes the launch, then launches the real kernel."""

    def __init__(self, kernel, name, threads, log, wrapper, launch=True):
        self.kernel, self.name, self.threads, self.log, self.wrapper = (
            kernel,
            name,
            threads,
            log,
            wrapper,
        )
        self.launch = launch

    def __getitem__(self, config):
        grid, block = config[0], config[1]

        def launch(*args):
            from numba import typeof
            from numba.core.typing.typeof import Purpose

            self.log.append(
                {
                    "kernel": self.name,
                    "threads": self.threads,
                    "wrapper": self.wrapper[0],
                    "grid": _dim(grid),
                    "block": _dim(block),
                    "args": [type_spec(typeof(a, Purpose.argument)) for a in args],
                }
            )
            if self.launch:
                self.kernel[config](*args)

        return launch


#: The per-block-size kernels of :mod:`slamlib.kernels.cuda`: factory name -> the names of the kernels it returns,
#: in order (:func:`slamlib.kernels.cuda._block_kernels`, :func:`slamlib.kernels.cuda._tile_kernels`).
FACTORIES = {
    "_block_kernels": ("score_voxel", "score_morton", "scan_block"),
    "_tile_kernels": ("score_voxel_tiles", "score_morton_tiles"),
}
#: Names of every per-block-size kernel.
BLOCK_KERNELS = tuple(name for names in FACTORIES.values() for name in names)


def module_kernels(kc) -> list[str]:
    """Names of the (non-device) kernels defined at module level in ``kc`` = :mod:`slamlib.kernels.cuda`."""
    names = []
    for name, obj in vars(kc).items():
        if hasattr(obj, "targetoptions"):  # numba-cuda's CUDADispatcher
            device = obj.targetoptions.get("device")
        # the simulator's FakeCUDAKernel
        elif hasattr(obj, "_device") and hasattr(obj, "fn"):
            device = obj._device
        else:
            continue
        if not device:
            names.append(name)
    return sorted(names)


def capture_launches(
    block_sizes=None, particles: int = 3, points: int = 5, launch: bool = True
) -> list[dict]:
    """Run every host wrapper of :mod:`slamlib.kernels.cuda` on tiny inputs (in the simulator) and return one
    record per distinct launch: kernel name, ``threads`` (block size of the per-block-size kernels, else
    ``None``), launch ``grid`` / ``block`` and ``args`` (:func:`type_spec` of each argument), the wrapper.

    ``block_sizes``: the block sizes the per-block-size wrappers are run with (default: the module defaults).
    ``particles`` / ``points``: the sizes passed to the wrappers (resampling gets ``max(particles, threads + 1)``
    weights, so the block totals are scanned too). ``launch=False`` records the launches without running the
    kernels (the grids of full-size calls, in no time; the outputs are then meaningless).
    """
    from numba import config as numba_config

    if not numba_config.ENABLE_CUDASIM:
        raise RuntimeError(
            "capture_launches runs the wrappers in the CUDA simulator: set NUMBA_ENABLE_CUDASIM=1 "
            "before numba is imported"
        )
    from slamlib import geometry
    from slamlib.kernels import cuda as kc
    from slamlib.maps import MortonBVHMap, VoxelHashMap
    from slamlib.noise import LutNoise, make_tables

    log: list[dict] = []
    wrapper = ["?"]
    saved = {name: getattr(kc, name) for name in module_kernels(kc)}
    saved_factories = {name: getattr(kc, name) for name in FACTORIES}

    def recording(factory):
        def kernels(threads):
            return tuple(
                _Recorder(k, n, int(threads), log, wrapper, launch)
                for k, n in zip(saved_factories[factory](threads), FACTORIES[factory])
            )

        return kernels

    sizes = tuple(block_sizes) if block_sizes else (kc.SCORE_THREADS,)
    rng = np.random.default_rng(0)
    P = int(particles)
    R = np.stack([geometry.rpy_to_matrix(rng.normal(0, 0.1, 3)) for _ in range(P)])
    t = rng.normal(0, 1, (P, 3))
    sigma = np.full(6, 0.01)
    pts = rng.normal(0, 2, (int(points), 3)).astype(np.float32)
    world = rng.normal(0, 2, (200, 3)).astype(np.float32)
    voxel, morton = VoxelHashMap(capacity=2**10), MortonBVHMap()
    voxel.merge(world)
    morton.merge(world)
    try:
        for name in saved:
            setattr(kc, name, _Recorder(saved[name], name, None, log, wrapper, launch))
        for factory in FACTORIES:
            setattr(kc, factory, recording(factory))
        wrapper[0] = "move_particles"
        kc.move_particles(R, t, [0, 0, 0.1], [1, 0, 0], rng.normal(size=(P, 6)), sigma)
        kc.move_particles(
            R, t, [0, 0, 0.1], [1, 0, 0], LutNoise(make_tables(0, bits=4), 1, 2), sigma
        )
        wrapper[0] = "lut_normal_device"
        kc.lut_normal_device(LutNoise(make_tables(0, bits=4), 1, 2), P)
        wrapper[0] = "transform_points"
        kc.transform_points(geometry.make_pose(R[0], t[0]), pts)
        for threads in sizes:
            wrapper[0] = "score_particles"
            for layout in kc.SCORE_LAYOUTS:
                kc.score_particles(
                    R, t, pts, voxel.lookup(), threads=threads, layout=layout
                )
                kc.score_particles(
                    R, t, pts, morton.lookup(), threads=threads, layout=layout
                )
            # more weights than threads: the block totals are scanned too
            wrapper[0] = "systematic_resample"
            kc.systematic_resample(rng.random(max(P, threads + 1)), 0.5, threads=threads)
    finally:
        for name, kernel in saved.items():
            setattr(kc, name, kernel)
        for factory, make in saved_factories.items():
            setattr(kc, factory, make)
    unique, seen = [], set()
    for rec in log:
        key = json.dumps([rec["kernel"], rec["threads"], rec["args"]])
        if key not in seen:
            seen.add(key)
            unique.append(rec)
    return unique


# ------------------------------------------------------------------------------------------------ compiling
_SUMMARY = (
    r"Function properties for '{entry}':\s*\n[^\n]*?used (\d+) registers[^\n]*?(\d+) stack, (\d+) bytes smem"
    r"[^\n]*?(\d+) bytes lmem"
)


def parse_ptxas_log(log: str, entry: str) -> dict:
    """Registers, stack, spills, static shared and local memory of kernel ``entry`` from nvJitLink's verbose log.

    ``spill_stores_bytes`` / ``spill_loads_bytes`` are summed over **every** function ptxas reports (a callee
    that spills counts); ``registers``, ``stack_bytes`` (cumulative, callees included), ``shared_bytes``
    (static) and ``local_bytes`` come from nvJitLink's summary of the entry function::

        info    : Function properties for '<entry>':
        info    : used 56 registers, used 5 barriers, 40 stack, 0 bytes smem, 1064 bytes cmem[0], 0 bytes lmem

    Raises ``ValueError`` when the summary is missing (an unexpected log format must not pass silently).
    """
    m = re.search(_SUMMARY.format(entry=re.escape(entry)), log)
    if m is None:
        raise ValueError(
            f"no resource summary for {entry!r} in the nvJitLink log:\n{log[:2000]}"
        )
    return {
        "registers": int(m.group(1)),
        "stack_bytes": int(m.group(2)),
        "shared_bytes": int(m.group(3)),
        "local_bytes": int(m.group(4)),
        "spill_stores_bytes": sum(
            int(v) for v in re.findall(r"(\d+) bytes spill stores", log)
        ),
        "spill_loads_bytes": sum(
            int(v) for v in re.findall(r"(\d+) bytes spill loads", log)
        ),
    }


def _patch_current_device(cc) -> None:
    """Answer numba-cuda's "current device" query with compute capability ``cc`` (no driver needed), and
    compile for exactly ``compute_XY`` (numba's ``FORCE_CUDA_CC``; otherwise it asks NVRTC, which this check
    does not install, for the closest architecture it supports)."""
    import numba.cuda.dispatcher as dispatcher
    from numba.cuda import config

    config.FORCE_CUDA_CC = tuple(cc)

    class _Target:
        compute_capability = tuple(cc)
        name = f"sm_{cc[0]}{cc[1]} (compile-only)"

    dispatcher.get_current_device = lambda: _Target


def kernel_dispatcher(name: str, threads):
    """The ``cuda.jit`` kernel ``name`` (``threads``: the block size of a per-block-size kernel)."""
    from slamlib.kernels import cuda as kc

    if threads is None:
        return getattr(kc, name)
    factory = next(f for f, names in FACTORIES.items() if name in names)
    return getattr(kc, factory)(int(threads))[FACTORIES[factory].index(name)]


def compile_launch(launch: dict, cc) -> dict:
    """Compile one captured launch for compute capability ``cc``: PTX (NVVM), then SASS (nvJitLink, verbose).

    Returns the launch record with ``cc``, ``ok``, ``error`` (the compile error's text, else ``None``) and the
    resources of :func:`parse_ptxas_log`. Call :func:`_patch_current_device` with the same ``cc`` first.
    """
    from numba import cuda

    rec = dict(launch, cc=list(cc), ok=False, error=None)
    try:
        sig = tuple(spec_type(s) for s in launch["args"])
        kernel = kernel_dispatcher(launch["kernel"], launch["threads"])
        # the kernel's own cuda.jit options, as a launch would compile it
        opts = kernel.targetoptions
        ptx, _ = cuda.compile_ptx(
            kernel.py_func,
            sig,
            cc=tuple(cc),
            debug=opts.get("debug"),
            lineinfo=opts.get("lineinfo", False),
            fastmath=opts.get("fastmath", False),
            opt=opts.get("opt"),
            launch_bounds=opts.get("launch_bounds"),
        )
        entry = re.search(r"\.entry\s+(\S+?)\s*\(", ptx).group(1)
        log = link_log(ptx, cc, opts.get("max_registers"))
    except Exception as exc:  # noqa: BLE001 - every compile failure is reported, and fails the check
        rec["error"] = f"{type(exc).__name__}: {exc}"[:4000]
        return rec
    rec.update(parse_ptxas_log(log, entry), ptx_chars=len(ptx), ok=True)
    return rec


def link_log(ptx: str, cc, max_registers: int | None = None) -> str:
    """nvJitLink's verbose log (ptxas' resource report) of assembling ``ptx`` for ``sm_XY`` (``max_registers``:
    the kernel's ``cuda.jit(max_registers=...)``, ptxas' ``-maxrregcount``)."""
    from cuda.core import Linker, LinkerOptions, ObjectCode

    options = LinkerOptions(
        arch=f"sm_{cc[0]}{cc[1]}", verbose=True, max_register_count=max_registers
    )
    linker = Linker(ObjectCode.from_ptx(ptx.encode()), options=options)
    linker.link("cubin")
    return linker.get_info_log()


def toolchain_versions() -> dict:
    """Versions of the packages that compile: numba, numba-cuda, cuda-bindings, the NVVM, NVRTC, nvJitLink wheels."""
    from importlib import metadata

    out = {}
    for pkg in (
        "numba",
        "numba-cuda",
        "llvmlite",
        "cuda-bindings",
        "cuda-core",
        "nvidia-nvvm",
        "nvidia-cuda-nvrtc",
        "nvidia-nvjitlink",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def compile_all(launches: list[dict], cc) -> list[dict]:
    """:func:`compile_launch` of every launch for one ``cc`` (patches the current-device query)."""
    from numba import config as numba_config

    if numba_config.ENABLE_CUDASIM:
        raise RuntimeError(
            "compiling for a real card needs the CUDA simulator off (NUMBA_ENABLE_CUDASIM unset)"
        )
    _patch_current_device(cc)
    return [compile_launch(launch, cc) for launch in launches]


# ---------------------------------------------------------------------------------------------- occupancy
def occupancy(registers: int, shared_bytes: int, block: int, gpu: str) -> dict:
    """Theoretical occupancy of a kernel on ``gpu`` (a key of :data:`GPUS`) from its resources.

    Blocks per SM = min(block limit, warp limit ``floor(max_warps / warps_per_block)``, register limit
    ``floor(floor(regs_per_sm / ceil(32 * registers, 256)) / warps_per_block)``, shared-memory limit
    ``floor(smem_per_sm / ceil(shared + 1 KB reserved, 128))``); occupancy = active warps / max warps.
    """
    g = GPUS[gpu]
    warps = -(-int(block) // 32)
    unit = g["reg_alloc_unit"]
    regs_per_warp = -(-(max(int(registers), 1) * 32) // unit) * unit
    limits = {
        "blocks": g["max_blocks_per_sm"],
        "warps": g["max_warps_per_sm"] // warps,
        "registers": (g["regs_per_sm"] // regs_per_warp) // warps,
        "shared": g["smem_per_sm"]
        // (
            -(-(int(shared_bytes) + g["smem_reserved_per_block"]) // g["smem_alloc_unit"])
            * g["smem_alloc_unit"]
        ),
    }
    blocks = min(limits.values())
    return {
        "blocks_per_sm": blocks,
        "limited_by": min(limits, key=limits.get),
        "active_warps": blocks * warps,
        "occupancy": blocks * warps / g["max_warps_per_sm"],
    }


def launch_fill(grid: int, block: int, occ: dict, gpu: str) -> dict:
    """How much of ``gpu`` one launch of ``grid`` blocks of ``block`` threads can keep busy (theoretical).

    ``blocks_per_sm``: the grid's blocks per SM when spread evenly (``grid / SMs``); ``busy_sms``: the fraction
    of SMs that get a block at all; ``waves``: ``grid / (resident blocks per SM x SMs)`` (below 1: the card is not
    filled, above 1: more than one round of blocks); ``warp_fraction``: resident warps per SM the launch can
    provide, over the SM's maximum (at most the kernel's occupancy ``occ`` from :func:`occupancy`).
    """
    g = GPUS[gpu]
    warps = -(-int(block) // 32)
    resident = occ["blocks_per_sm"] * g["sms"]
    per_sm = min(grid / g["sms"], occ["blocks_per_sm"])
    return {
        "grid": int(grid),
        "sms": g["sms"],
        "blocks_per_sm": grid / g["sms"],
        "busy_sms": min(grid, g["sms"]) / g["sms"],
        "waves": grid / resident,
        "warp_fraction": per_sm * warps / g["max_warps_per_sm"],
    }


# ------------------------------------------------------------------------------------------ orchestration
def _env(simulator: bool) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("NUMBA_ENABLE_CUDASIM", "SLAMLIB_REAL_CUDA")
    }
    if simulator:
        env["NUMBA_ENABLE_CUDASIM"] = "1"
    return env


def _run_json(args: list[str], simulator: bool, stdin: str | None = None):
    proc = subprocess.run(
        [sys.executable, "-m", "slamlib.kernels.cuda_static", *args],
        input=stdin,
        capture_output=True,
        text=True,
        env=_env(simulator),
    )
    if proc.returncode != 0:
        raise RuntimeError(
            f"`python -m slamlib.kernels.cuda_static {' '.join(args)}` failed "
            f"({proc.returncode}):\n{proc.stderr[-4000:]}"
        )
    return json.loads(proc.stdout)


def static_report(
    ccs=DEFAULT_CCS, block_sizes=None, fill_sizes: dict | None = None
) -> dict:
    """Capture the launches (simulator subprocess), compile them for every ``cc`` (one clean subprocess per
    target, run side by side) and add the occupancy on the card of each target (:data:`GPUS`).

    ``fill_sizes`` (``{"particles": P, "points": N}``): also record the grids the wrappers launch at these sizes
    (kernels not run) and add each kernel's :func:`launch_fill` (``fill``) at them.

    Returns ``{"toolchain": ..., "launches": [...], "results": [...]}``; each result is a compiled launch
    (:func:`compile_launch`) with ``gpu``, ``occupancy`` when it compiled, and ``fill`` when asked.
    """
    threads_args = [f"--threads={t}" for t in (block_sizes or ())]
    launches = _run_json(["capture", *threads_args], simulator=True)
    grids = {}
    if fill_sizes:
        sized = _run_json(
            [
                "capture",
                *threads_args,
                f"--particles={int(fill_sizes['particles'])}",
                f"--points={int(fill_sizes['points'])}",
                "--dry",
            ],
            simulator=True,
        )
        grids = {(r["kernel"], r["threads"]): r["grid"] for r in sized}
    payload = json.dumps(launches)
    with ThreadPoolExecutor(len(ccs)) as pool:
        per_cc = list(
            pool.map(
                lambda cc: _run_json(["compile", f"--cc={cc[0]}{cc[1]}"], False, payload),
                ccs,
            )
        )
    results = []
    for batch in per_cc:
        for rec in batch["results"]:
            gpu = next((n for n, g in GPUS.items() if list(g["cc"]) == rec["cc"]), None)
            rec["gpu"] = gpu
            if rec["ok"] and gpu:
                rec["occupancy"] = occupancy(
                    rec["registers"], rec["shared_bytes"], rec["block"], gpu
                )
                grid = grids.get((rec["kernel"], rec["threads"]))
                if grid is not None:
                    rec["fill"] = launch_fill(grid, rec["block"], rec["occupancy"], gpu)
            results.append(rec)
    return {"toolchain": per_cc[0]["toolchain"], "launches": launches, "results": results}


def check_toolchain() -> str | None:
    """Why kernels cannot be compiled here (NVVM / NVRTC / nvJitLink missing), or ``None`` when they can."""
    try:
        from cuda.pathfinder import load_nvidia_dynamic_lib

        for lib in ("nvvm", "nvrtc", "nvJitLink"):
            load_nvidia_dynamic_lib(lib)
    except Exception as exc:  # noqa: BLE001
        return f"{_TOOLCHAIN_HINT} ({type(exc).__name__}: {exc})"
    return None


def main(argv=None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m slamlib.kernels.cuda_static")
    parser.add_argument("command", choices=["capture", "compile"])
    parser.add_argument(
        "--threads",
        type=int,
        action="append",
        help="block size of the per-block-size kernels",
    )
    parser.add_argument(
        "--cc", default="90", help="compute capability to compile for, e.g. 80 or 90"
    )
    parser.add_argument(
        "--particles",
        type=int,
        default=3,
        help="capture: particles passed to the wrappers",
    )
    parser.add_argument(
        "--points",
        type=int,
        default=5,
        help="capture: scan points passed to the wrappers",
    )
    parser.add_argument(
        "--dry",
        action="store_true",
        help="capture: record the launches without running them",
    )
    args = parser.parse_args(argv)
    if args.command == "capture":
        json.dump(
            capture_launches(
                args.threads, args.particles, args.points, launch=not args.dry
            ),
            sys.stdout,
        )
        return 0
    reason = check_toolchain()
    if reason:
        print(reason, file=sys.stderr)
        return 2
    cc = (int(args.cc[:-1]), int(args.cc[-1]))
    json.dump(
        {
            "toolchain": toolchain_versions(),
            "results": compile_all(json.load(sys.stdin), cc),
        },
        sys.stdout,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
