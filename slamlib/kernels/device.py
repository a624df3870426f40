"""The per-particle and per-point math of the 3D kernels, written once and compiled for each backend.

:func:`make_point_functions` holds the only source of the arithmetic that the Numba CPU kernels
(:mod:`slamlib.kernels.cpu`, loops over ``prange``) and the CUDA kernels (:mod:`slamlib.kernels.cuda`, threads
and grid-stride loops) run for one particle or one point: the rotation from roll/pitch/yaw, the motion update
of one particle, the rigid transform of one point, the trilinear NDT voxel term and the nearest-neighbour query
of the Morton map. It builds on the integer codes of :func:`slamlib.maps.codes.make_code_functions` (hash,
find-slot, Morton codes, find-cell) from the same call, so that each build calls its own compiled siblings.
The builds (the pattern of :func:`slamlib.noise.make_lut_functions`):

* identity decorator: plain Python on scalars (:data:`PY`): the readable specification, and what the tests
  compare the compiled builds with, bit for bit;
* ``numba.njit(inline="always")``: the CPU build, inlined into the ``prange`` loops of :mod:`slamlib.kernels.cpu`;
* ``numba.cuda.jit(device=True)``: the device functions of :mod:`slamlib.kernels.cuda`.

The kernels around these functions only arrange loops, threads, chunks and reductions. The reference backend
(:mod:`slamlib.kernels.reference`) does not use them: it stays an independent numpy formulation (sorted-key
search, k-d tree) that the tests compare every backend with.

Rules that keep the builds identical: float math uses only ``+ - * /``, ``math.floor``, ``math.sin/cos``,
``abs`` and ``min`` (IEEE-exact, or a libm call: ``sin``/``cos`` may differ in the last bit between libraries),
compiled without ``fastmath`` (the one exception, the CPU ``transform_points``, agrees to float32 rounding);
``math.floor`` is only called on
finite values of modest size (range checks come first), since under the CUDA simulator it is Python's
``math.floor`` that raises on NaN; integer math is on typed numpy scalars (see :mod:`slamlib.maps.codes`).
Array arguments are indexed, never allocated, so the same source runs with numpy arrays, Numba arrays and
CUDA local / global memory.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from slamlib.maps.base import BITS_PER_AXIS
from slamlib.maps.codes import AXIS_OFFSET_F64, AXIS_OFFSET_I64, make_code_functions

#: Truncation of the voxel grid coordinate: ``|p / h - 1/2| <= 2**21`` is the widest range in which the
#: int64 conversion is safe and an index can still be in range; beyond it every corner is a miss.
VOXEL_GRID_LIMIT = float(1 << BITS_PER_AXIS)
#: A voxel block index no block has (``voxel_cell``'s indexes stay within about ``2**22`` of zero, below it too):
#: what a kernel that remembers blocks' corner slots starts its memory with.
NO_BLOCK = np.int64(-(2**62))


def _identity(fn):
    return fn


def make_point_functions(deco: Callable = _identity) -> dict:
    """Compile the per-particle / per-point math with ``deco``; returns a dict of scalar functions.

    Includes every function of :func:`slamlib.maps.codes.make_code_functions` (same build), plus:

    ``rpy_matrix(r, p, y, out)``
        ``out = Rz(y) Ry(p) Rx(r)`` ((3, 3) float64 array; angles in radians), the ZYX (yaw-pitch-roll)
        convention of :func:`slamlib.geometry.rpy_to_matrix`.
    ``rpy_matrix_cs(cr, sr, cp, sp, cy, sy, out)``
        The same matrix from the cosines and sines of roll, pitch and yaw (``rpy_matrix`` calls it), for
        kernels that read them from a per-frame table instead of calling ``cos``/``sin`` per particle.
    ``rpy_rotation_cs(cr, sr, cp, sp, cy, sy)``, ``rpy_rotation(r, p, y)``
        That matrix as a row-major 9-tuple (``rpy_matrix_cs`` writes it): for kernels that keep it in registers.
    ``row_times(r0, r1, r2, m00, m01, ..., m22)``
        The row vector ``r M`` as a 3-tuple (``M`` row-major, as scalars): one row of a 3x3 product, summed in the
        order ``r0 m0b + r1 m1b + r2 m2b``. The motion update of one particle is three rows of
        ``R_i dR`` then of ``(R_i dR) N``.
    ``row_step(t0, a0, a1, a2, sx, sy, sz)``
        ``t0 + a0 sx + a1 sy + a2 sz``: one component of ``t_i + A s``.
    ``pose_times(R, i, M, A)``
        ``A = R[i] M`` for ``R`` (P, 3, 3) and ``M``, ``A`` (3, 3) (``row_times`` of each row).
    ``compose_rotation(A, N, R_new, i)``
        ``R_new[i] = A N`` (3x3 product).
    ``compose_translation(t, A, sx, sy, sz, t_new, i)``
        ``t_new[i] = t[i] + A (sx, sy, sz)`` (a body-frame step rotated into the world frame, metres).
    ``world_point(R, t, i, x, y, z)``
        ``R[i] p + t[i]`` for the point ``p = (x, y, z)``, as a tuple; computed in the type of the inputs
        (float64 for scoring, float32 for ``transform_points``), summed in the order ``r0 x + r1 y + r2 z + t``.
    ``voxel_term(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max)``
        Trilinear NDT term of the world point in a :class:`~slamlib.maps.base.VoxelHashLookup` (float64):
        ``sum w_c T_c(p)`` over the 8 voxels whose centres surround ``p``; ``T_c = -0.5 min(d^T A d, m_max)``
        when found, ``-0.5 m_max`` when not (Biber & Strasser 2003; Magnusson 2009). Built from the four below.
    ``voxel_cell(wx, wy, wz, inv_h)``
        ``(ux0, uy0, uz0, fx, fy, fz, ok)``: the offset int64 indexes of the lowest of the 8 voxels whose centres
        surround the point and its fractional position among them; ``ok`` False when the point is beyond the
        key range or NaN (every corner a miss).
    ``corner_slot(ux0, uy0, uz0, k, keys, log2_capacity, max_probe)``
        Hash slot (int64, -1 if absent) of corner ``k = 4 dx + 2 dy + dz`` (0..7) of that block.
    ``corner_weight(fx, fy, fz, k)``
        Its trilinear weight ``w_x w_y w_z`` (``f`` for the upper corner along an axis, ``1 - f`` for the lower).
    ``corner_weight_gradient(fx, fy, fz, k, inv_h)``
        That weight's gradient with respect to the world point (1/m), a 3-tuple: ``d w / d x = +-inv_h w_y w_z``
        (``+`` for the upper corner along x), and likewise along y and z. Scan matching's Newton step uses it
        (:mod:`slamlib.slam3d.match`).
    ``slot_term(wx, wy, wz, s, mean, icov, m_max)``
        ``T_c(p)`` of the voxel in slot ``s``, ``-0.5 m_max`` for ``s < 0``. A kernel whose neighbouring
        queries share a block looks its 8 slots up once (``corner_slot``) and sums ``corner_weight * slot_term``
        in corner order, which is ``voxel_term`` bit for bit.
    ``cell_block(wx, wy, wz, quantum, cell_level)``
        ``(ux, uy, uz, cx0, cy0, cz0, ok)``: the point in quanta offset by ``2**20`` (float64), and the lowest
        corner (int64) of the 2x2x2 block of level-``cell_level`` cells nearest it (the cells whose centres
        surround it); ``ok`` is False when the whole block is outside the 21-bit range, or the point is NaN.
    ``cells_per_axis(cell_level)``
        ``2**(21 - cell_level)`` (int64): cells along one axis at that level.
    ``nearest_in_run(points, lo, hi, wx, wy, wz, best, best_j)``
        ``(best, best_j)`` updated with the points ``points[lo:hi]`` nearer (squared distance, float64, m^2)
        than ``best``.
    ``morton_d2(wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2)``
        ``min(d_nn^2, r2)`` in a :class:`~slamlib.maps.base.MortonLookup`: the documented query (the 2x2x2
        nearest cells, each searched by ``find_cell``, then scanned), exact when ``r2 <= (quantum 2**L / 2)^2``.
    """
    F = make_code_functions(deco)
    in_range, pack_key, find_slot = F["in_range"], F["pack_key"], F["find_slot"]
    morton, find_cell = F["morton"], F["find_cell"]

    def rpy_rotation_cs(cr, sr, cp, sp, cy, sy):
        return (
            cy * cp,
            cy * sp * sr - sy * cr,
            cy * sp * cr + sy * sr,
            sy * cp,
            sy * sp * sr + cy * cr,
            sy * sp * cr - cy * sr,
            -sp,
            cp * sr,
            cp * cr,
        )

    rpy_rotation_cs = deco(rpy_rotation_cs)

    def rpy_matrix_cs(cr, sr, cp, sp, cy, sy, out):
        (
            out[0, 0],
            out[0, 1],
            out[0, 2],
            out[1, 0],
            out[1, 1],
            out[1, 2],
            out[2, 0],
            out[2, 1],
            out[2, 2],
        ) = rpy_rotation_cs(cr, sr, cp, sp, cy, sy)

    rpy_matrix_cs = deco(rpy_matrix_cs)

    def rpy_rotation(r, p, y):
        return rpy_rotation_cs(
            math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
        )

    rpy_rotation = deco(rpy_rotation)

    def rpy_matrix(r, p, y, out):
        rpy_matrix_cs(
            math.cos(r),
            math.sin(r),
            math.cos(p),
            math.sin(p),
            math.cos(y),
            math.sin(y),
            out,
        )

    def row_times(r0, r1, r2, m00, m01, m02, m10, m11, m12, m20, m21, m22):
        return (
            r0 * m00 + r1 * m10 + r2 * m20,
            r0 * m01 + r1 * m11 + r2 * m21,
            r0 * m02 + r1 * m12 + r2 * m22,
        )

    row_times = deco(row_times)

    def row_step(t0, a0, a1, a2, sx, sy, sz):
        return t0 + a0 * sx + a1 * sy + a2 * sz

    row_step = deco(row_step)

    def pose_times(R, i, M, A):
        for a in range(3):
            A[a, 0], A[a, 1], A[a, 2] = row_times(
                R[i, a, 0],
                R[i, a, 1],
                R[i, a, 2],
                M[0, 0],
                M[0, 1],
                M[0, 2],
                M[1, 0],
                M[1, 1],
                M[1, 2],
                M[2, 0],
                M[2, 1],
                M[2, 2],
            )

    def compose_rotation(A, N, R_new, i):
        for a in range(3):
            R_new[i, a, 0], R_new[i, a, 1], R_new[i, a, 2] = row_times(
                A[a, 0],
                A[a, 1],
                A[a, 2],
                N[0, 0],
                N[0, 1],
                N[0, 2],
                N[1, 0],
                N[1, 1],
                N[1, 2],
                N[2, 0],
                N[2, 1],
                N[2, 2],
            )

    def compose_translation(t, A, sx, sy, sz, t_new, i):
        for a in range(3):
            t_new[i, a] = row_step(t[i, a], A[a, 0], A[a, 1], A[a, 2], sx, sy, sz)

    def world_point(R, t, i, x, y, z):
        return (
            R[i, 0, 0] * x + R[i, 0, 1] * y + R[i, 0, 2] * z + t[i, 0],
            R[i, 1, 0] * x + R[i, 1, 1] * y + R[i, 1, 2] * z + t[i, 1],
            R[i, 2, 0] * x + R[i, 2, 1] * y + R[i, 2, 2] * z + t[i, 2],
        )

    def voxel_cell(wx, wy, wz, inv_h):
        gx = wx * inv_h - 0.5  # voxel centres at integers
        gy = wy * inv_h - 0.5
        gz = wz * inv_h - 0.5
        if not (
            abs(gx) <= VOXEL_GRID_LIMIT
            and abs(gy) <= VOXEL_GRID_LIMIT
            and abs(gz) <= VOXEL_GRID_LIMIT
        ):
            # far outside the key range, or NaN (checked before floor: see the module docstring)
            return AXIS_OFFSET_I64, AXIS_OFFSET_I64, AXIS_OFFSET_I64, 0.0, 0.0, 0.0, False
        bx = math.floor(gx)
        by = math.floor(gy)
        bz = math.floor(gz)
        return (
            np.int64(bx) + AXIS_OFFSET_I64,
            np.int64(by) + AXIS_OFFSET_I64,
            np.int64(bz) + AXIS_OFFSET_I64,
            gx - bx,
            gy - by,
            gz - bz,
            True,
        )

    voxel_cell = deco(voxel_cell)

    def corner_slot(ux0, uy0, uz0, k, keys, log2_capacity, max_probe):
        ux = ux0 + (k >> 2)
        uy = uy0 + ((k >> 1) & 1)
        uz = uz0 + (k & 1)
        if in_range(ux) and in_range(uy) and in_range(uz):
            return find_slot(keys, pack_key(ux, uy, uz), log2_capacity, max_probe)
        return np.int64(-1)

    corner_slot = deco(corner_slot)

    def corner_weight(fx, fy, fz, k):
        wgx = fx if (k >> 2) == 1 else 1.0 - fx
        wgy = fy if ((k >> 1) & 1) == 1 else 1.0 - fy
        return wgx * wgy * (fz if (k & 1) == 1 else 1.0 - fz)

    corner_weight = deco(corner_weight)

    def corner_weight_gradient(fx, fy, fz, k, inv_h):
        upper_x, upper_y, upper_z = (k >> 2) == 1, ((k >> 1) & 1) == 1, (k & 1) == 1
        wgx = fx if upper_x else 1.0 - fx
        wgy = fy if upper_y else 1.0 - fy
        wgz = fz if upper_z else 1.0 - fz
        return (
            (inv_h if upper_x else -inv_h) * wgy * wgz,
            (inv_h if upper_y else -inv_h) * wgx * wgz,
            (inv_h if upper_z else -inv_h) * wgx * wgy,
        )

    corner_weight_gradient = deco(corner_weight_gradient)

    def slot_term(wx, wy, wz, s, mean, icov, m_max):
        if s < 0:
            return -0.5 * m_max
        ex = wx - np.float64(mean[s, 0])
        ey = wy - np.float64(mean[s, 1])
        ez = wz - np.float64(mean[s, 2])
        m = (
            np.float64(icov[s, 0]) * ex * ex
            + np.float64(icov[s, 3]) * ey * ey
            + np.float64(icov[s, 5]) * ez * ez
            + 2.0
            * (
                np.float64(icov[s, 1]) * ex * ey
                + np.float64(icov[s, 2]) * ex * ez
                + np.float64(icov[s, 4]) * ey * ez
            )
        )
        return -0.5 * min(m, m_max)

    slot_term = deco(slot_term)

    def voxel_term(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max):
        ux0, uy0, uz0, fx, fy, fz, ok = voxel_cell(wx, wy, wz, inv_h)
        if not ok:
            return -0.5 * m_max
        total = 0.0
        for k in range(8):
            s = corner_slot(ux0, uy0, uz0, k, keys, log2_capacity, max_probe)
            total += corner_weight(fx, fy, fz, k) * slot_term(
                wx, wy, wz, s, mean, icov, m_max
            )
        return total

    def cells_per_axis(cell_level):
        return np.int64(1) << (BITS_PER_AXIS - cell_level)

    cells_per_axis = deco(cells_per_axis)

    def cell_block(wx, wy, wz, quantum, cell_level):
        inv_q = 1.0 / quantum
        ux = wx * inv_q + AXIS_OFFSET_F64
        uy = wy * inv_q + AXIS_OFFSET_F64
        uz = wz * inv_q + AXIS_OFFSET_F64
        size = np.float64(np.int64(1) << cell_level)
        gx = ux / size - 0.5  # cell centres at integers
        gy = uy / size - 0.5
        gz = uz / size - 0.5
        ncell = np.float64(cells_per_axis(cell_level))
        # floor(g) in [-1, ncell) <=> g in [-1, ncell); NaN fails too (checked before floor)
        if not (
            gx >= -1.0
            and gy >= -1.0
            and gz >= -1.0
            and gx < ncell
            and gy < ncell
            and gz < ncell
        ):
            return ux, uy, uz, np.int64(0), np.int64(0), np.int64(0), False
        return (
            ux,
            uy,
            uz,
            np.int64(math.floor(gx)),
            np.int64(math.floor(gy)),
            np.int64(math.floor(gz)),
            True,
        )

    cell_block = deco(cell_block)

    def nearest_in_run(points, lo, hi, wx, wy, wz, best, best_j):
        for j in range(lo, hi):
            ex = wx - np.float64(points[j, 0])
            ey = wy - np.float64(points[j, 1])
            ez = wz - np.float64(points[j, 2])
            d2 = ex * ex + ey * ey + ez * ez
            if d2 < best:
                best = d2
                best_j = j
        return best, best_j

    nearest_in_run = deco(nearest_in_run)

    def morton_d2(wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2):
        best = r2
        _, _, _, cx0, cy0, cz0, ok = cell_block(wx, wy, wz, quantum, cell_level)
        if not ok:
            return best
        lim = cells_per_axis(cell_level)
        for blk in range(8):  # x fastest, then y, then z
            cx = cx0 + (blk & 1)
            cy = cy0 + ((blk >> 1) & 1)
            cz = cz0 + (blk >> 2)
            if cx < 0 or cy < 0 or cz < 0 or cx >= lim or cy >= lim or cz >= lim:
                continue
            k = find_cell(cell_codes, morton(cx, cy, cz))
            if k < 0:
                continue
            best, _ = nearest_in_run(
                points, cell_start[k], cell_start[k + 1], wx, wy, wz, best, np.int64(-1)
            )
        return best

    out = dict(F)
    out.update(
        {
            "rpy_matrix": deco(rpy_matrix),
            "rpy_matrix_cs": rpy_matrix_cs,
            "rpy_rotation_cs": rpy_rotation_cs,
            "rpy_rotation": rpy_rotation,
            "row_times": row_times,
            "row_step": row_step,
            "pose_times": deco(pose_times),
            "compose_rotation": deco(compose_rotation),
            "compose_translation": deco(compose_translation),
            "world_point": deco(world_point),
            "voxel_term": deco(voxel_term),
            "voxel_cell": voxel_cell,
            "corner_slot": corner_slot,
            "corner_weight": corner_weight,
            "corner_weight_gradient": corner_weight_gradient,
            "slot_term": slot_term,
            "cells_per_axis": cells_per_axis,
            "cell_block": cell_block,
            "nearest_in_run": nearest_in_run,
            "morton_d2": deco(morton_d2),
        }
    )
    return out


#: The plain-Python build (scalars; numpy arrays for the array arguments): the specification the tests use.
PY = make_point_functions()
