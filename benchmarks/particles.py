"""``slamlib bench particles``: particle updates per second (steps 5 + 6: motion + noise) vs particle count.

The seed project reports about 1.6e8 particles/s on its K40 (saturating from 1e6 particles). Here, on the CPU
backend (``move_particles`` of :mod:`slamlib.kernels.cpu`, all Numba threads), for P = 1e3 .. 1e7 particles
(``R (P, 3, 3)``, ``t (P, 3)`` float64), each round times back to back:

``lut_fused``        LUT noise drawn inside the motion kernel (``noise=LutNoise(tables, step, seed)``; the default
                     4096-entry tables), the particles updated in place (``out=(R, t)``): no ``(P, 6)`` array;
``lut_fused_seed_tables``  the same with the seed's table size (256 entries: every table in L1);
``lut_fused_1thread``  ``lut_fused`` with Numba on one thread (the per-core rate, whatever else runs);
``lut_fused_alloc``  LUT fused, new output arrays per call (``out=None``: their pages fault in during the call);
``lut_fused_soa``    ``lut_fused`` on the same poses stored component-major (``R (3, 3, P)``, ``t (3, P)``:
                     :func:`slamlib.kernels.cpu.move_particles_soa`), float64, in place;
``lut_fused_soa32``  the same in float32 (48 bytes per pose); ``lut_fused_soa32_1thread`` on one thread;
``lut_drawn``        the same LUT draws written to a ``(P, 6)`` array first (:func:`slamlib.noise.lut_normal_nb`),
                     then moved (in place);
``numpy_drawn``      ``np.random.Generator(PCG64).standard_normal((P, 6))`` then moved (in place);
``philox_drawn``     ``np.random.Generator(Philox)`` (counter-based, like the GPU's Philox) then moved (in place).

Rates are ``P / median`` (and ``P / best``) in particles per second, beside the seed's 1.6e8
(``ratio_to_seed``). Bytes moved per particle: the pose read and written (``pose_bytes`` of the row: 96 in float64,
48 in float32), plus 48 + 48 for a drawn ``(P, 6)`` noise array. The memory limit, measured in the same run:
``numpy.copyto`` of the largest size's float64 poses (``copy_gb_per_s``, bytes read + written per second);
``limit_particles_per_s`` of a row is that bandwidth over the bytes it moves.
"""

from __future__ import annotations

import os

import numpy as np

HELP = "particle updates/s (motion + LUT / Philox / numpy noise), 1e3..1e7 particles, beside the seed's 1.6e8/s"

#: The seed's particle update rate on its K40, particles/s.
SEED_PARTICLES_PER_S = 1.6e8
#: Bytes of one particle's pose (R 3x3 + t 3, float64).
POSE_BYTES = 96
#: Rows whose poses are float32 (48 bytes).
FLOAT32_VARIANTS = ("lut_fused_soa32", "lut_fused_soa32_1thread")
#: Noise spread (m, m, m, rad, rad, rad) and the motion increment of every timed call.
SIGMA = (0.1, 0.05, 0.02, 0.002, 0.002, 0.01)
RPY_DELTA = (0.0, 0.0, 0.05)
TRANS_DELTA = (1.0, 0.0, 0.0)


def run(quick: bool) -> dict:
    import numba

    from benchmarks.transform import _one_thread, _rounds
    from slamlib import noise as N
    from slamlib.geometry import rpy_to_matrix
    from slamlib.kernels import cpu as cpu_module
    from slamlib.kernels import get_backend

    cpu = get_backend("cpu")
    sizes = [10**k for k in range(3, 5 if quick else 8)]
    tables = N.make_tables(0)
    seed_tables = N.make_tables(0, bits=N.SEED_BITS)
    sigma = np.asarray(SIGMA)
    rows = []
    load_before = os.getloadavg()
    for P in sizes:
        rng = np.random.default_rng(0)
        R = np.ascontiguousarray(rpy_to_matrix(rng.normal(0.0, 0.1, (P, 3))))
        t = rng.normal(0.0, 5.0, (P, 3))
        pcg = np.random.Generator(np.random.PCG64(1))
        philox = np.random.Generator(np.random.Philox(1))
        lut = N.LutNoise(tables, 3, 7)
        lut_seed = N.LutNoise(seed_tables, 3, 7)
        # component-major
        Rs, ts = np.ascontiguousarray(R.transpose(1, 2, 0)), np.ascontiguousarray(t.T)
        Rs32, ts32 = Rs.astype(np.float32), ts.astype(np.float32)

        def move_soa(Rc, tc):
            return cpu_module.move_particles_soa(
                Rc, tc, RPY_DELTA, TRANS_DELTA, lut, sigma, out=(Rc, tc)
            )

        def move(noise, out=(R, t)):
            return cpu.move_particles(R, t, RPY_DELTA, TRANS_DELTA, noise, sigma, out=out)

        fns = {
            "lut_fused": lambda: move(lut),
            "lut_fused_seed_tables": lambda: move(lut_seed),
            "lut_fused_1thread": lambda: _one_thread(move, lut),
            "lut_fused_alloc": lambda: move(lut, out=None),
            "lut_fused_soa": lambda: move_soa(Rs, ts),
            "lut_fused_soa32": lambda: move_soa(Rs32, ts32),
            "lut_fused_soa32_1thread": lambda: _one_thread(move_soa, Rs32, ts32),
            "lut_drawn": lambda: move(N.lut_normal_nb(tables, P, 3, 7)),
            "numpy_drawn": lambda: move(pcg.standard_normal((P, 6))),
            "philox_drawn": lambda: move(philox.standard_normal((P, 6))),
        }
        # the copy limit, at the largest size
        R_copy = np.empty_like(R) if P == sizes[-1] else None
        copy = {"copyto": lambda: np.copyto(R_copy, R)} if R_copy is not None else {}
        res = _rounds(
            {**fns, **copy},
            3 if quick else (7 if P >= 10**7 else (15 if P >= 10**6 else 31)),
        )
        if copy:
            st = res.pop("copyto")
            copy_gb_per_s = 2 * R.nbytes / st["median_s"] / 1e9
            copy_row = {
                "particles": P,
                "bytes_moved": 2 * R.nbytes,
                **st,
                "gb_per_s": copy_gb_per_s,
            }
        for name, st in res.items():
            rate = P / st["median_s"]
            rows.append(
                {
                    "variant": name,
                    "particles": P,
                    **st,
                    "particles_per_s": rate,
                    "best_particles_per_s": P / st["min_s"],
                    "ratio_to_seed": rate / SEED_PARTICLES_PER_S,
                    "best_ratio_to_seed": P / st["min_s"] / SEED_PARTICLES_PER_S,
                    "noise_array": name.endswith("drawn"),
                    "in_place": name != "lut_fused_alloc",
                    "threads": 1
                    if name.endswith("1thread")
                    else int(numba.get_num_threads()),
                    "pose_bytes": POSE_BYTES // 2
                    if name in FLOAT32_VARIANTS
                    else POSE_BYTES,
                    "layout": "component-major" if "soa" in name else "particle-major",
                    "table_entries": (1 << seed_tables.bits)
                    if name == "lut_fused_seed_tables"
                    else ((1 << tables.bits) if name.startswith("lut") else None),
                }
            )
            print(
                f"P={P:>9d} {name:22s} {st['median_s'] * 1e3:10.3f} ms  {rate:.3g} particles/s "
                f"(best {P / st['min_s']:.3g}; seed {SEED_PARTICLES_PER_S:.2g})",
                flush=True,
            )
        R = t = fns = Rs = ts = Rs32 = ts32 = R_copy = (
            None  # free this size before the next
        )
    return {
        "threads": int(numba.get_num_threads()),
        "seed_particles_per_s": SEED_PARTICLES_PER_S,
        "pose_bytes": POSE_BYTES,
        "sigma": list(SIGMA),
        "copy": copy_row,
        "copy_gb_per_s": copy_gb_per_s,
        "load_average_1min": {"start": load_before[0], "end": os.getloadavg()[0]},
        "rows": [
            {
                **r,
                "limit_particles_per_s": copy_gb_per_s
                * 1e9
                / (2 * r["pose_bytes"] + (96 if r["noise_array"] else 0)),
            }
            for r in rows
        ],
    }
