"""``slamlib bench cuda --static``: the CUDA kernels' resources and theoretical occupancy, by static analysis.

No GPU and no timing: every kernel of :mod:`slamlib.kernels.cuda` is compiled for sm_80 (A100) and sm_90 (H100)
with the argument types its host wrapper really passes (:func:`slamlib.kernels.cuda_static.static_report`), and
ptxas' report (via nvJitLink) gives registers per thread, stack, static shared memory and spills. From these and
the documented per-SM limits (:data:`slamlib.kernels.cuda_static.GPUS`) each row adds the theoretical occupancy
(resident blocks and warps per SM) and, at the filter's default sizes (``FilterConfig.particle_count()`` particles,
``scored_points`` points), the launch's grid and how much of the card it can keep busy (``fill``).

Everything here is **static analysis, not measurement**: a real GPU run (``slamlib bench cuda``) is needed for
any time. Rows: one per kernel, block size (``threads`` of the per-block-size kernels: 128, the default, and
256) and target.
"""

from __future__ import annotations

#: Block sizes of the per-block-size kernels (scoring, scan) in the report.
BLOCK_SIZES = (128, 256)


def run_static() -> dict:
    """The static report (see the module's docstring); ``SystemExit`` when the toolchain is missing or a kernel
    does not compile."""
    from slamlib.kernels import cuda_static as cs
    from slamlib.slam3d.config import FilterConfig

    reason = cs.check_toolchain()
    if reason:
        raise SystemExit(f"slamlib bench cuda --static: {reason}")
    defaults = FilterConfig()
    sizes = {
        "particles": defaults.particle_count(),
        "points": int(defaults.scored_points),
    }
    report = cs.static_report(cs.DEFAULT_CCS, BLOCK_SIZES, fill_sizes=sizes)
    rows = []
    for r in report["results"]:
        row = {
            "kernel": r["kernel"],
            "wrapper": r["wrapper"],
            "threads": r["block"],
            "gpu": r["gpu"],
            "arch": f"sm_{r['cc'][0]}{r['cc'][1]}",
            "ok": r["ok"],
        }
        if r["ok"]:
            row.update(
                {
                    k: r[k]
                    for k in (
                        "registers",
                        "stack_bytes",
                        "shared_bytes",
                        "local_bytes",
                        "spill_stores_bytes",
                        "spill_loads_bytes",
                    )
                }
            )
            row.update({f"occ_{k}": v for k, v in r["occupancy"].items()})
            if "fill" in r:
                row.update({f"default_{k}": v for k, v in r["fill"].items()})
        else:
            row["error"] = r["error"]
        rows.append(row)
    failed = [f"{r['kernel']} {r['arch']}" for r in rows if not r["ok"]]
    if failed:
        raise SystemExit(
            f"slamlib bench cuda --static: kernels that do not compile: {', '.join(failed)}"
        )
    return {
        "static_analysis": True,
        "note": "static analysis (NVVM + ptxas via nvJitLink, no GPU): registers, memory and theoretical "
        "occupancy from the documented per-SM limits; nothing here is a measured time",
        "toolchain": report["toolchain"],
        "gpus": {k: dict(v, cc=list(v["cc"])) for k, v in cs.GPUS.items()},
        "default_sizes": sizes,
        "block_sizes": list(BLOCK_SIZES),
        "argument_types": [
            {k: launch[k] for k in ("kernel", "threads", "wrapper", "args")}
            for launch in report["launches"]
        ],
        "rows": rows,
    }
