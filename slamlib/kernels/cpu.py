"""Numba CPU backend (``get_backend("cpu")``): ``@njit(parallel=True, cache=True)`` kernels over ``prange``.

Same functions, shapes and math as :mod:`slamlib.kernels.reference` (see CONTRIBUTING.md, "Backend interface
(3D)", and :mod:`slamlib.maps.base` for the map lookups). Design:

* ``score_particles`` is fused: each task takes a chunk of ``POINT_CHUNK`` scan points and a chunk of
  ``PARTICLE_CHUNK`` particles; for each point it loops over the particles (their copies of the point land in
  the same few voxels / cells, so map memory stays in cache), transforms in registers (float64) and looks up;
  per-(point chunk, particle) partial sums are added in a fixed order, so results do not depend on the thread
  count, and no ``P x N`` array is ever built. Two-way chunking keeps all cores busy for few particles with
  many points as well as many particles with few points.
* ``transform_points`` works in float32 (like :func:`slamlib.geometry.transform_points`) with ``fastmath``
  (only contraction into FMAs and vectorisation; no NaN/inf assumptions matter for a linear map).
* ``score_particles`` does not use ``fastmath``: ``floor`` at voxel/cell boundaries must agree with the
  reference bit for bit.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from slamlib.maps.base import KIND_MORTON, KIND_VOXEL_HASH
from slamlib.maps.codes import AXIS_OFFSET, find_slot_nb, in_range_nb, morton_nb, pack_key_nb

#: Scan points per parallel task of ``score_particles``.
POINT_CHUNK = 64
#: Particles per parallel task of ``score_particles`` (inner loop: one point, consecutive particles).
PARTICLE_CHUNK = 64


# --------------------------------------------------------------------------------------------- move particles
@njit(cache=True, inline="always")
def _rpy_nb(r, p, y, out):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    out[0, 0] = cy * cp
    out[0, 1] = cy * sp * sr - sy * cr
    out[0, 2] = cy * sp * cr + sy * sr
    out[1, 0] = sy * cp
    out[1, 1] = sy * sp * sr + cy * cr
    out[1, 2] = sy * sp * cr - cy * sr
    out[2, 0] = -sp
    out[2, 1] = cp * sr
    out[2, 2] = cp * cr


@njit(parallel=True, cache=True)
def _move_nb(R, t, dR, trans_delta, noise, sigma, R_new, t_new):
    P = R.shape[0]
    for i in prange(P):
        N = np.empty((3, 3))
        _rpy_nb(sigma[3] * noise[i, 3], sigma[4] * noise[i, 4], sigma[5] * noise[i, 5], N)
        A = np.empty((3, 3))  # A = R_i dR
        for a in range(3):
            for b in range(3):
                A[a, b] = R[i, a, 0] * dR[0, b] + R[i, a, 1] * dR[1, b] + R[i, a, 2] * dR[2, b]
        sx = trans_delta[0] + sigma[0] * noise[i, 0]
        sy = trans_delta[1] + sigma[1] * noise[i, 1]
        sz = trans_delta[2] + sigma[2] * noise[i, 2]
        for a in range(3):
            for b in range(3):
                R_new[i, a, b] = A[a, 0] * N[0, b] + A[a, 1] * N[1, b] + A[a, 2] * N[2, b]
            t_new[i, a] = t[i, a] + A[a, 0] * sx + A[a, 1] * sy + A[a, 2] * sz


def _check_particles(R, t):
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
        raise ValueError(f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}")
    return R, t


def move_particles(R, t, rpy_delta, trans_delta, noise, sigma):
    """Steps 5 + 6 fused (see :func:`slamlib.kernels.reference.move_particles`), parallel over particles."""
    R, t = _check_particles(R, t)
    noise = np.ascontiguousarray(noise, dtype=np.float64)
    sigma = np.ascontiguousarray(sigma, dtype=np.float64).reshape(6)
    if noise.shape != (R.shape[0], 6):
        raise ValueError(f"noise must have shape (P, 6) = ({R.shape[0]}, 6), got {noise.shape}")
    rpy = np.asarray(rpy_delta, dtype=np.float64).reshape(3)
    dR = np.empty((3, 3))
    _rpy_nb(rpy[0], rpy[1], rpy[2], dR)
    R_new = np.empty_like(R)
    t_new = np.empty_like(t)
    _move_nb(R, t, dR, np.asarray(trans_delta, dtype=np.float64).reshape(3), noise, sigma, R_new, t_new)
    return R_new, t_new


# ------------------------------------------------------------------------------------------- transform points
@njit(parallel=True, cache=True, fastmath=True)
def _transform_nb(R, t, pts, out):
    r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
    r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
    r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
    t0, t1, t2 = t[0], t[1], t[2]
    for j in prange(pts.shape[0]):
        x, y, z = pts[j, 0], pts[j, 1], pts[j, 2]
        out[j, 0] = r00 * x + r01 * y + r02 * z + t0
        out[j, 1] = r10 * x + r11 * y + r12 * z + t1
        out[j, 2] = r20 * x + r21 * y + r22 * z + t2


def transform_points(T, points):
    """``p' = R p + t`` for ``T`` (4, 4) and ``points`` (N, 3) float32 -> (N, 3) float32 (float32 arithmetic)."""
    T = np.asarray(T, dtype=np.float64)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"need T (4, 4) and points (N, 3), got {T.shape} and {pts.shape}")
    out = np.empty_like(pts)
    _transform_nb(np.ascontiguousarray(T[:3, :3], dtype=np.float32),
                  np.ascontiguousarray(T[:3, 3], dtype=np.float32), pts, out)
    return out


# ------------------------------------------------------------------------------------------------- scoring
@njit(cache=True, inline="always")
def voxel_term_nb(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max):
    """Per-point term of world point ``(wx, wy, wz)`` in a ``VoxelHashLookup`` (trilinear over 8 voxels)."""
    miss = -0.5 * m_max
    gx = wx * inv_h - 0.5
    gy = wy * inv_h - 0.5
    gz = wz * inv_h - 0.5
    bx = np.floor(gx)
    by = np.floor(gy)
    bz = np.floor(gz)
    if not (abs(bx) <= 2.0**21 and abs(by) <= 2.0**21 and abs(bz) <= 2.0**21):
        return miss  # far outside the key range, or NaN
    fx = gx - bx
    fy = gy - by
    fz = gz - bz
    ux0 = np.int64(bx) + AXIS_OFFSET
    uy0 = np.int64(by) + AXIS_OFFSET
    uz0 = np.int64(bz) + AXIS_OFFSET
    total = 0.0
    for dx in range(2):
        ux = ux0 + dx
        wgx = fx if dx == 1 else 1.0 - fx
        for dy in range(2):
            uy = uy0 + dy
            wgy = fy if dy == 1 else 1.0 - fy
            for dz in range(2):
                uz = uz0 + dz
                w = wgx * wgy * (fz if dz == 1 else 1.0 - fz)
                s = -1
                if in_range_nb(ux) and in_range_nb(uy) and in_range_nb(uz):
                    s = find_slot_nb(keys, pack_key_nb(ux, uy, uz), log2_capacity, max_probe)
                if s < 0:
                    total += w * miss
                    continue
                ex = wx - np.float64(mean[s, 0])
                ey = wy - np.float64(mean[s, 1])
                ez = wz - np.float64(mean[s, 2])
                m = (np.float64(icov[s, 0]) * ex * ex + np.float64(icov[s, 3]) * ey * ey
                     + np.float64(icov[s, 5]) * ez * ez
                     + 2.0 * (np.float64(icov[s, 1]) * ex * ey + np.float64(icov[s, 2]) * ex * ez
                              + np.float64(icov[s, 4]) * ey * ez))
                total += w * (-0.5 * min(m, m_max))
    return total


@njit(parallel=True, cache=True)
def _score_voxel_nb(R, t, pts, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max, pt_chunk, part_chunk):
    P = R.shape[0]
    N = pts.shape[0]
    npc = (N + pt_chunk - 1) // pt_chunk
    nqc = (P + part_chunk - 1) // part_chunk
    partial = np.zeros((npc, P))
    for task in prange(npc * nqc):
        c = task // nqc
        i0 = (task - c * nqc) * part_chunk
        i1 = min(P, i0 + part_chunk)
        for j in range(c * pt_chunk, min(N, (c + 1) * pt_chunk)):
            x = np.float64(pts[j, 0])
            y = np.float64(pts[j, 1])
            z = np.float64(pts[j, 2])
            for i in range(i0, i1):  # the particles' copies of point j hit the same few voxels: cache-friendly
                wx = R[i, 0, 0] * x + R[i, 0, 1] * y + R[i, 0, 2] * z + t[i, 0]
                wy = R[i, 1, 0] * x + R[i, 1, 1] * y + R[i, 1, 2] * z + t[i, 1]
                wz = R[i, 2, 0] * x + R[i, 2, 1] * y + R[i, 2, 2] * z + t[i, 2]
                partial[c, i] += voxel_term_nb(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe,
                                               m_max)
    out = np.zeros(P)
    for c in range(npc):
        for i in range(P):
            out[i] += partial[c, i]
    return out


@njit(cache=True, inline="always")
def _find_cell_nb(cell_codes, code):
    """Index of ``code`` in the sorted ``cell_codes`` or -1 (binary search)."""
    lo = 0
    hi = cell_codes.shape[0]
    while lo < hi:
        mid = (lo + hi) >> 1
        if cell_codes[mid] < code:
            lo = mid + 1
        else:
            hi = mid
    if lo < cell_codes.shape[0] and cell_codes[lo] == code:
        return lo
    return -1


#: Entries of the per-task direct-mapped cache of cell look-ups in ``score_particles`` (Morton map).
CELL_CACHE = 256


@njit(cache=True, inline="always")
def _find_cell_cached_nb(cell_codes, code, cache_code, cache_k):
    """:func:`_find_cell_nb` through a direct-mapped cache (``cache_code`` starts filled with -1).

    The copies of one scan point under nearby particles fall in the same few cells, so most binary searches
    (about 15 unpredictable branches each, the main cost of a query) are answered from the cache."""
    e = np.int64((np.uint64(code) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(56)) & (cache_code.shape[0] - 1)
    if cache_code[e] == code:
        return cache_k[e]
    k = _find_cell_nb(cell_codes, code)
    cache_code[e] = code
    cache_k[e] = k
    return k


@njit(cache=True, inline="always")
def _axis_gap(u, c, size):
    """Distance (in quanta) along one axis from coordinate ``u`` to the cell ``[c size, (c + 1) size)``."""
    lo = c * size
    if u < lo:
        return lo - u
    hi = lo + size
    if u > hi:
        return u - hi
    return 0.0


#: Runs of at most this many points are scanned linearly instead of split further.
MORTON_LEAF = 64


@njit(cache=True)
def morton_nn_nb(wx, wy, wz, codes, points, cell_codes, cell_start, cell_lo, cell_hi, quantum, cell_level, best,
                 best_j, stack, leaf, cache_code, cache_k):
    """Nearest stored point to world point ``(wx, wy, wz)`` closer than ``sqrt(best)``: ``(best, best_j)``.

    Exact branch-and-bound search of the implicit octree over the sorted Morton codes (see ``MortonLookup``):
    the 2x2x2 block of level-``cell_level`` cells nearest the point (the one holding it first), each found by
    binary search in ``cell_codes`` (skipped when the tight box ``cell_lo``/``cell_hi`` of its points is not nearer
    than ``best``); a node whose run has more than :data:`MORTON_LEAF` points is split into its
    8 child runs (consecutive in Morton order, bounded by binary search on ``codes >> 3 (level - 1)``), the child
    holding the point visited first; nodes whose box is not nearer than ``best`` are skipped. Pass
    ``best = radius^2, best_j = -1`` for a plain query, or a smaller ``best`` with the index ``best_j`` of a point
    at that squared distance (warm start); the result is ``min(d_nn^2, best)`` either way.
    ``stack`` is scratch space, int64 of shape ``(8 * (cell_level + 2), 6)``; ``cache_code`` (power-of-two length,
    filled with -1 before first use) and ``cache_k`` cache cell look-ups between calls.
    """
    inv_q = 1.0 / quantum
    ux = wx * inv_q + AXIS_OFFSET  # coordinates in quanta, offset
    uy = wy * inv_q + AXIS_OFFSET
    uz = wz * inv_q + AXIS_OFFSET
    size0 = np.float64(np.int64(1) << cell_level)
    fx = np.floor(ux / size0 - 0.5)
    fy = np.floor(uy / size0 - 0.5)
    fz = np.floor(uz / size0 - 0.5)
    ncell = np.float64(np.int64(1) << (21 - cell_level))
    if not (fx >= -1.0 and fy >= -1.0 and fz >= -1.0 and fx < ncell and fy < ncell and fz < ncell):
        return best, best_j  # also catches NaN
    cx0 = np.int64(fx)
    cy0 = np.int64(fy)
    cz0 = np.int64(fz)
    lim = np.int64(1) << (21 - cell_level)
    q2 = quantum * quantum
    for rnd in range(2):  # round 0: the cell that holds the point; round 1: the other seven
        for blk in range(8):
            cx = cx0 + (blk & 1)
            cy = cy0 + ((blk >> 1) & 1)
            cz = cz0 + (blk >> 2)
            if cx < 0 or cy < 0 or cz < 0 or cx >= lim or cy >= lim or cz >= lim:
                continue
            gx = _axis_gap(ux, cx, size0)
            gy = _axis_gap(uy, cy, size0)
            gz = _axis_gap(uz, cz, size0)
            box2 = (gx * gx + gy * gy + gz * gz) * q2
            if (rnd == 0) != (box2 == 0.0) or box2 >= best:
                continue
            k = _find_cell_cached_nb(cell_codes, morton_nb(cx, cy, cz), cache_code, cache_k)
            if k < 0:
                continue
            gx = max(np.float64(cell_lo[k, 0]) - wx, 0.0, wx - np.float64(cell_hi[k, 0]))
            gy = max(np.float64(cell_lo[k, 1]) - wy, 0.0, wy - np.float64(cell_hi[k, 1]))
            gz = max(np.float64(cell_lo[k, 2]) - wz, 0.0, wz - np.float64(cell_hi[k, 2]))
            if gx * gx + gy * gy + gz * gz >= best:
                continue  # the tight box of the cell's points is too far
            stack[0, 0] = cell_start[k]
            stack[0, 1] = cell_start[k + 1]
            stack[0, 2] = cell_level
            stack[0, 3] = cx
            stack[0, 4] = cy
            stack[0, 5] = cz
            sp = 1
            while sp > 0:
                sp -= 1
                lo = stack[sp, 0]
                hi = stack[sp, 1]
                lev = stack[sp, 2]
                nx = stack[sp, 3]
                ny = stack[sp, 4]
                nz = stack[sp, 5]
                size = np.float64(np.int64(1) << lev)
                gx = _axis_gap(ux, nx, size)
                gy = _axis_gap(uy, ny, size)
                gz = _axis_gap(uz, nz, size)
                if (gx * gx + gy * gy + gz * gz) * q2 >= best:
                    continue
                if hi - lo <= leaf or lev == 0:
                    for j in range(lo, hi):
                        ex = wx - np.float64(points[j, 0])
                        ey = wy - np.float64(points[j, 1])
                        ez = wz - np.float64(points[j, 2])
                        d2 = ex * ex + ey * ey + ez * ez
                        if d2 < best:
                            best = d2
                            best_j = j
                    continue
                shift = 3 * (lev - 1)
                parent = (codes[lo] >> shift) >> 3
                half = size * 0.5
                # the child holding the point (if any) is pushed last, so it is searched first
                hold = -1
                if ux >= nx * size and uy >= ny * size and uz >= nz * size:
                    hxi = np.int64(ux - nx * size >= half)
                    hyi = np.int64(uy - ny * size >= half)
                    hzi = np.int64(uz - nz * size >= half)
                    if (ux < (nx + 1) * size and uy < (ny + 1) * size and uz < (nz + 1) * size):
                        hold = hxi | (hyi << 1) | (hzi << 2)
                start = lo
                hold_lo = 0
                hold_hi = 0
                for ch in range(8):
                    # end of child ch: first index in [start, hi) whose level-(lev-1) prefix exceeds it
                    target = (parent << 3) | ch
                    l2 = start
                    h2 = hi
                    while l2 < h2:
                        mid = (l2 + h2) >> 1
                        if (codes[mid] >> shift) <= target:
                            l2 = mid + 1
                        else:
                            h2 = mid
                    if l2 > start:
                        if ch == hold:
                            hold_lo = start
                            hold_hi = l2
                        else:
                            stack[sp, 0] = start
                            stack[sp, 1] = l2
                            stack[sp, 2] = lev - 1
                            stack[sp, 3] = 2 * nx + (ch & 1)
                            stack[sp, 4] = 2 * ny + ((ch >> 1) & 1)
                            stack[sp, 5] = 2 * nz + (ch >> 2)
                            sp += 1
                    start = l2
                if hold_hi > hold_lo:
                    stack[sp, 0] = hold_lo
                    stack[sp, 1] = hold_hi
                    stack[sp, 2] = lev - 1
                    stack[sp, 3] = 2 * nx + (hold & 1)
                    stack[sp, 4] = 2 * ny + ((hold >> 1) & 1)
                    stack[sp, 5] = 2 * nz + (hold >> 2)
                    sp += 1
    return best, best_j


@njit(cache=True, inline="always")
def morton_nn_d2_nb(wx, wy, wz, codes, points, cell_codes, cell_start, cell_lo, cell_hi, quantum, cell_level, r2):
    """``min(d_nn^2, r2)`` of world point ``(wx, wy, wz)`` in a ``MortonLookup`` (allocates its own stack)."""
    stack = np.empty((8 * (cell_level + 2), 6), np.int64)
    cache_code = np.full(1, -1, np.int64)
    cache_k = np.empty(1, np.int64)
    return morton_nn_nb(wx, wy, wz, codes, points, cell_codes, cell_start, cell_lo, cell_hi, quantum, cell_level,
                        r2, -1, stack, MORTON_LEAF, cache_code, cache_k)[0]


@njit(parallel=True, cache=True)
def _score_morton_nb(R, t, pts, codes, points, cell_codes, cell_start, cell_lo, cell_hi, quantum, cell_level,
                     radius, sigma,
                     pt_chunk, part_chunk, leaf, cache_size):
    P = R.shape[0]
    N = pts.shape[0]
    npc = (N + pt_chunk - 1) // pt_chunk
    nqc = (P + part_chunk - 1) // part_chunk
    partial = np.zeros((npc, P))
    r2 = radius * radius
    scale = -0.5 / (sigma * sigma)
    for task in prange(npc * nqc):
        stack = np.empty((8 * (cell_level + 2), 6), np.int64)
        cache_code = np.full(cache_size, -1, np.int64)
        cache_k = np.empty(cache_size, np.int64)
        c = task // nqc
        i0 = (task - c * nqc) * part_chunk
        i1 = min(P, i0 + part_chunk)
        for j in range(c * pt_chunk, min(N, (c + 1) * pt_chunk)):
            x = np.float64(pts[j, 0])
            y = np.float64(pts[j, 1])
            z = np.float64(pts[j, 2])
            prev = -1
            for i in range(i0, i1):
                wx = R[i, 0, 0] * x + R[i, 0, 1] * y + R[i, 0, 2] * z + t[i, 0]
                wy = R[i, 1, 0] * x + R[i, 1, 1] * y + R[i, 1, 2] * z + t[i, 1]
                wz = R[i, 2, 0] * x + R[i, 2, 1] * y + R[i, 2, 2] * z + t[i, 2]
                best = r2
                if prev >= 0:  # warm start: the previous particle's neighbour bounds this one's distance
                    ex = wx - np.float64(points[prev, 0])
                    ey = wy - np.float64(points[prev, 1])
                    ez = wz - np.float64(points[prev, 2])
                    best = min(r2, ex * ex + ey * ey + ez * ez)
                best, found = morton_nn_nb(wx, wy, wz, codes, points, cell_codes, cell_start, cell_lo, cell_hi,
                                           quantum, cell_level, best, prev if best < r2 else -1, stack, leaf,
                                           cache_code, cache_k)
                prev = found
                partial[c, i] += scale * best
    out = np.zeros(P)
    for c in range(npc):
        for i in range(P):
            out[i] += partial[c, i]
    return out


def score_particles(R, t, points, lookup):
    """Fused transform + lookup log-likelihood (P,) float64 (see :func:`slamlib.kernels.reference.score_particles`).

    ``lookup`` is a :class:`~slamlib.maps.base.VoxelHashLookup` or :class:`~slamlib.maps.base.MortonLookup`.
    """
    R, t = _check_particles(R, t)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if lookup.kind == KIND_VOXEL_HASH:
        return _score_voxel_nb(R, t, pts, lookup.keys, lookup.mean, lookup.icov, float(lookup.inv_voxel_size),
                               int(lookup.log2_capacity), int(lookup.max_probe), float(lookup.m_max), POINT_CHUNK,
                               PARTICLE_CHUNK)
    if lookup.kind == KIND_MORTON:
        return _score_morton_nb(R, t, pts, lookup.codes, lookup.points, lookup.cell_codes, lookup.cell_start,
                                lookup.cell_lo, lookup.cell_hi,
                                float(lookup.quantum), int(lookup.cell_level), float(lookup.radius),
                                float(lookup.sigma), POINT_CHUNK, PARTICLE_CHUNK, MORTON_LEAF, CELL_CACHE)
    raise ValueError(f"unknown lookup kind {lookup.kind!r}")


# ----------------------------------------------------------------------------------------------- resampling
@njit(cache=True)
def _systematic_nb(c, u0):
    P = c.shape[0]
    out = np.empty(P, np.int64)
    j = 0
    for i in range(P):
        u = (u0 + i) / P
        while j < P - 1 and not (u < c[j]):
            j += 1
        out[i] = j
    return out


def systematic_resample(weights, u0):
    """Systematic resampling (P,) int64 (see :func:`slamlib.kernels.reference.systematic_resample`), O(P)."""
    w = np.ascontiguousarray(weights, dtype=np.float64)
    if w.ndim != 1 or w.size == 0 or np.any(~np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
        raise ValueError("weights must be a non-empty 1-D array of finite non-negative numbers with positive sum")
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0}")
    c = np.cumsum(w / w.sum())  # the same normalised cumulative sum as the reference
    c[-1] = 1.0
    return _systematic_nb(c, float(u0))
