"""Scan matching: the best particle's pose moved to the nearest peak of the NDT map score (Gauss-Newton).

The particle filter finds the basin of the map score; with a few hundred particles in six dimensions its best
particle is still centimetres and tenths of a degree from the peak (see "Coarse to fine" in
:mod:`slamlib.slam3d.pipeline`). Scan matching climbs the rest of the way, as the *improved proposal* of Grisetti,
Stachniss & Burgard ("Improved techniques for grid mapping with Rao-Blackwellized particle filters", IEEE T-RO 2007)
does: the pose is refined by a local optimiser on the same likelihood, and the particles are drawn around the result.

The cost is the filter's own map score, negated (:mod:`slamlib.maps.base`, the voxel hash's trilinear NDT): for the
body points ``p_j`` (N, 3) and the pose ``T = [R, t]``, world points ``q_j = R p_j + t``, and each of the 8 voxels
``c`` whose centres surround ``q_j`` (trilinear weight ``w_jc``, mean ``mu_c``, inverse covariance ``A_c``),

    E(T) = sum_j sum_c  w_jc * 0.5 * min(m_jc, m_max),     m_jc = d^T A_c d,  d = q_j - mu_c,

so ``E = -score`` of :func:`slamlib.slam3d.steps.score_particles` for that one pose (a missing voxel costs
``0.5 m_max``, like a truncated term). Gauss-Newton on the untruncated terms (Biber & Strasser 2003; Magnusson,
"The three-dimensional normal-distributions transform", 2009), with the trilinear weights held fixed within one
step, and the update ``R <- Exp(omega) R``, ``t <- t + v`` (a rotation about the pose's own position, so that the
normal equations stay well conditioned kilometres from the origin)::

    J_j = d q_j / d(omega, v) = [ -[R p_j]_x  |  I_3 ]                     (3, 6)
    H = sum w_jc J_j^T A_c J_j,   g = sum w_jc J_j^T A_c d,   (H + lambda I) delta = -g.

``J_j`` does not depend on the corner, so each point's corners are summed first, ``S_j = sum_c w_jc A_c`` and
``s_j = sum_c w_jc A_c d_jc``, and then ``H = sum_j J_j^T S_j J_j``, ``g = sum_j J_j^T s_j``: the same sums in an
eighth of the multiplications. The points are summed in :data:`MATCH_CHUNKS` fixed chunks in parallel. A step
moves the points by millimetres, so most keep their block of 8 voxels from one step to the next: each point's
block and its 8 hash slots are remembered across the steps of one match and looked up again only when the block
changes (the same slots, so the same sums).

Newton on the fixed point
-------------------------
Gauss-Newton with the weights held is a fixed-point iteration: it stops where the held-weight gradient
``g(x) = sum_j J_j^T s_j`` is zero, but each step re-weights the corners, so it only approaches that point
linearly, the error shrinking by ``|H^-1 K|`` (about a third on KITTI-like scans) per pass, where ``K`` is what
``H`` leaves out of the Jacobian of ``g``. The step here is Newton's on ``g(x) = 0`` itself,
``(H + K + lambda I) delta = -g``, with the whole Jacobian ``dg/d(omega, v) = H + K``::

    K = sum_j J_j^T D_j (M_j J_j + S_j (J_j - Jm_j)) + [u_j]_x [r_j]_x (the omega-omega block),
    M_j = sum_c (A_c d_jc) (grad w_jc)^T,   u_j = D_j s_j,   r_j = R p_j,

``grad w`` the trilinear weight's gradient (``corner_weight_gradient`` of :mod:`slamlib.kernels.device`),
``D_j`` the identity, or ``diag(0, 0, 1)`` for a road point (whose Jacobian ``Jm_j = D_j J_j`` keeps only the
vertical row, below), and the last term the rotation's own curvature (``r x u`` moved by ``omega``). ``K``
changes little over the millimetres of the later steps, so it is computed once, on the first pass, and held:
the same fixed point in fewer passes (on the whole synthetic odometry routes 07 and 05, 4.3 and 4.1 a frame
against Gauss-Newton's 7.1 and 6.5).

A step that does not lower ``E`` is not taken (the iteration stops there), so the result never scores worse than
the start. A step shorter than the tolerance (``|delta|``, radians and metres alike) ends the iteration without
being evaluated: the peak is then about one such step away, and not evaluating it saves a whole pass over the
points.
``lambda = MATCH_DAMPING * trace(H)`` keeps the solve defined on degenerate scenes (a flat plane alone fixes only
three of the six coordinates: the damping leaves the others where they are).

Road points
-----------
The road's returns lie on the LIDAR's rings, which stay in place relative to the sensor: matched against a map that
holds the last scans' rings, they pull a slowly moving scan toward no motion at all (the *ring artifact*,
:func:`slamlib.slam3d.preprocess.thin_ground`). LIDAR-only, nothing outweighs that pull. What the road does tell is
the height and the tilt. So points marked ``road`` enter with only the vertical row of ``J`` (the other two rows
zero): the step may move them up and down, through ``v_z``, ``omega_x`` and ``omega_y``, but their pull along the
road does not count. They hold the pose to the road's plane and leave yaw and the horizontal position to what
stands above it.

Gravity's term
--------------
With an accelerometer the filter knows which way is up (:mod:`slamlib.slam3d.stages.prior`), and step 8 weighs the
particles by it; a match on the map score alone would climb back to the tilt the map was built with. So the cost
may carry the same term (``tilt``): for the measured up ``u`` (body frame, less its fitted bias) and the world's
up ``g_w``::

    E_g(R) = 0.5 w |R^T g_w - u|^2,   r = R^T g_w - u,   d r / d omega = R^T [g_w]_x,

(``R <- Exp(omega) R`` turns ``R^T g_w`` by ``-R^T [omega]_x g_w``), which adds ``w J^T J`` to the rotation block of
``H`` and ``w J^T r`` to ``g`` (Gauss-Newton: the term's own curvature, second order in a residual of
milliradians, is left out). ``w = N * temperature / sigma^2`` puts it on the map term's scale: step 8 weighs a
scan of ``N`` points by ``score / (N * temperature)`` and the prior by ``|r|^2 / (2 sigma^2)``, and the match's
cost is step 8's negative log-weight times ``N * temperature``, so both pick the same pose.

Only the voxel hash map is matched (the Morton map's nearest-neighbour term has no per-voxel Gaussian);
:func:`match_scan` returns the pose unchanged for any other map.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from slamlib.geometry import skew, so3_exp
from slamlib.kernels.device import NO_BLOCK, make_point_functions
from slamlib.maps.base import KIND_VOXEL_HASH

__all__ = [
    "match_scan",
    "normal_equations",
    "gradient_jacobian",
    "tilt_equations",
    "MATCH_DAMPING",
    "MATCH_TOLERANCE",
]

#: Levenberg damping of the Gauss-Newton solve, relative to ``trace(H)``: small enough not to slow a well
#: constrained step, large enough to leave the unconstrained directions of a degenerate scene in place.
MATCH_DAMPING = 1e-6
#: Stop when a step would move the pose by less than this (radians and metres alike: 1e-5 rad at 50 m is 0.5 mm).
#: KISS-ICP stops at 1e-4, but its ICP converges faster than this linear climb; 1e-4 here lost accuracy
#: ("Why these defaults", ``book/defaults_record.md``).
MATCH_TOLERANCE = 1e-5

# The score's voxel pieces, inlined (the pattern of slamlib.kernels.cpu; after editing slamlib/kernels/device.py
# clear Numba's cache, which is keyed on this file's timestamp only).
_F = make_point_functions(njit(inline="always"))
_voxel_cell = _F["voxel_cell"]
_corner_slot = _F["corner_slot"]
_corner_weight = _F["corner_weight"]
_corner_weight_gradient = _F["corner_weight_gradient"]


#: The points are summed in this many fixed chunks, in parallel, and the chunks' sums are then added in order: the
#: same numbers whatever the number of threads (a chunk per thread would make them depend on it).
MATCH_CHUNKS = 16
#: One chunk's partial sums: H's upper triangle (21 entries from 0), g (6 from _G), the cost (at _COST) and K
#: (36, row-major from _K; the first pass only).
_N_UPPER = 21
_G, _COST, _K = _N_UPPER, _N_UPPER + 6, _N_UPPER + 7
_N_SUMS = _K + 36


@njit(cache=True, parallel=True)
def _normal_equations_nb(
    R,
    t,
    pts,
    road,
    keys,
    mean,
    icov,
    inv_h,
    log2_capacity,
    max_probe,
    m_max,
    blocks,
    slots,
    with_k,
):
    # Per point, the 8 corners' weighted A_c and A_c d first (S = sum w A, v = sum w A d), then J^T S J and J^T v
    # once: the same sums as corner by corner, since J does not depend on the corner, in an eighth of the work.
    n = pts.shape[0]
    parts = np.zeros((MATCH_CHUNKS, _N_SUMS))
    for chunk in prange(MATCH_CHUNKS):
        J = np.zeros((3, 6))
        SJ = np.zeros((3, 6))
        Jf = np.zeros((3, 6))  # the unmasked Jacobian, for K
        KJ = np.zeros((3, 6))
        acc = parts[chunk]
        for j in range(n * chunk // MATCH_CHUNKS, n * (chunk + 1) // MATCH_CHUNKS):
            x, y, z = np.float64(pts[j, 0]), np.float64(pts[j, 1]), np.float64(pts[j, 2])
            rx = R[0, 0] * x + R[0, 1] * y + R[0, 2] * z
            ry = R[1, 0] * x + R[1, 1] * y + R[1, 2] * z
            rz = R[2, 0] * x + R[2, 1] * y + R[2, 2] * z
            wx, wy, wz = rx + t[0], ry + t[1], rz + t[2]
            # the block, corners and weights of the score's voxel_term (slamlib.kernels.device)
            ux0, uy0, uz0, fx, fy, fz, ok = _voxel_cell(wx, wy, wz, inv_h)
            if not ok:
                acc[_COST] += 0.5 * m_max
                continue
            # a Gauss-Newton step moves a point by millimetres: its block (and so its 8 corner slots) is mostly
            # the one of the step before, remembered per point instead of hashed again
            if ux0 != blocks[j, 0] or uy0 != blocks[j, 1] or uz0 != blocks[j, 2]:
                blocks[j, 0], blocks[j, 1], blocks[j, 2] = ux0, uy0, uz0
                for corner in range(8):
                    slots[j, corner] = _corner_slot(
                        ux0, uy0, uz0, corner, keys, log2_capacity, max_probe
                    )
            s0 = s1 = s2 = s3 = s4 = s5 = 0.0  # S = sum_c w A_c (symmetric: 6 entries)
            v0 = v1 = v2 = 0.0  # v = sum_c w A_c d
            # M = sum_c (A_c d) (grad w_c)^T, row-major (K only)
            m00 = m01 = m02 = m10 = m11 = m12 = m20 = m21 = m22 = 0.0
            cost = 0.0
            for corner in range(8):
                w = _corner_weight(fx, fy, fz, corner)
                s = slots[j, corner]
                if s < 0:
                    cost += 0.5 * w * m_max
                    continue
                e0 = wx - np.float64(mean[s, 0])
                e1 = wy - np.float64(mean[s, 1])
                e2 = wz - np.float64(mean[s, 2])
                a0, a1, a2 = (
                    np.float64(icov[s, 0]),
                    np.float64(icov[s, 1]),
                    np.float64(icov[s, 2]),
                )
                a3, a4, a5 = (
                    np.float64(icov[s, 3]),
                    np.float64(icov[s, 4]),
                    np.float64(icov[s, 5]),
                )
                d0 = a0 * e0 + a1 * e1 + a2 * e2  # A d
                d1 = a1 * e0 + a3 * e1 + a4 * e2
                d2 = a2 * e0 + a4 * e1 + a5 * e2
                m = e0 * d0 + e1 * d1 + e2 * d2
                if m >= m_max:  # truncated: constant, no gradient
                    cost += 0.5 * w * m_max
                    continue
                cost += 0.5 * w * m
                s0 += w * a0
                s1 += w * a1
                s2 += w * a2
                s3 += w * a3
                s4 += w * a4
                s5 += w * a5
                v0 += w * d0
                v1 += w * d1
                v2 += w * d2
                if with_k:
                    q0, q1, q2 = _corner_weight_gradient(fx, fy, fz, corner, inv_h)
                    m00, m01, m02 = m00 + d0 * q0, m01 + d0 * q1, m02 + d0 * q2
                    m10, m11, m12 = m10 + d1 * q0, m11 + d1 * q1, m12 + d1 * q2
                    m20, m21, m22 = m20 + d2 * q0, m21 + d2 * q1, m22 + d2 * q2
            acc[_COST] += cost
            # d q / d omega = -[r]_x, d q / d v = I; a road point keeps only the vertical row (module docstring)
            across = 0.0 if road[j] else 1.0
            J[0, 1], J[0, 2], J[0, 3] = rz * across, -ry * across, across
            J[1, 0], J[1, 2], J[1, 4] = -rz * across, rx * across, across
            J[2, 0], J[2, 1], J[2, 5] = ry, -rx, 1.0
            for c in range(6):
                SJ[0, c] = s0 * J[0, c] + s1 * J[1, c] + s2 * J[2, c]
                SJ[1, c] = s1 * J[0, c] + s3 * J[1, c] + s4 * J[2, c]
                SJ[2, c] = s2 * J[0, c] + s4 * J[1, c] + s5 * J[2, c]
                acc[_G + c] += J[0, c] * v0 + J[1, c] * v1 + J[2, c] * v2
            u = 0
            for c in range(6):
                for k in range(c, 6):
                    acc[u] += J[0, c] * SJ[0, k] + J[1, c] * SJ[1, k] + J[2, c] * SJ[2, k]
                    u += 1
            if with_k:
                # K's rows from this point: Jm^T (M Jf + S (Jf - Jm)), Jm = J (masked), Jf unmasked
                Jf[0, 1], Jf[0, 2], Jf[0, 3] = rz, -ry, 1.0
                Jf[1, 0], Jf[1, 2], Jf[1, 4] = -rz, rx, 1.0
                Jf[2, 0], Jf[2, 1], Jf[2, 5] = ry, -rx, 1.0
                for c in range(6):
                    e0, e1, e2 = (
                        Jf[0, c] - J[0, c],
                        Jf[1, c] - J[1, c],
                        Jf[2, c] - J[2, c],
                    )
                    KJ[0, c] = (
                        m00 * Jf[0, c]
                        + m01 * Jf[1, c]
                        + m02 * Jf[2, c]
                        + s0 * e0
                        + s1 * e1
                        + s2 * e2
                    )
                    KJ[1, c] = (
                        m10 * Jf[0, c]
                        + m11 * Jf[1, c]
                        + m12 * Jf[2, c]
                        + s1 * e0
                        + s3 * e1
                        + s4 * e2
                    )
                    KJ[2, c] = (
                        m20 * Jf[0, c]
                        + m21 * Jf[1, c]
                        + m22 * Jf[2, c]
                        + s2 * e0
                        + s4 * e1
                        + s5 * e2
                    )
                for c in range(6):
                    for k in range(6):
                        acc[_K + 6 * c + k] += (
                            J[0, c] * KJ[0, k] + J[1, c] * KJ[1, k] + J[2, c] * KJ[2, k]
                        )
                # the rotation's curvature: d(r x u)/d omega = [u]_x [r]_x = r u^T - (u . r) I
                u0, u1, u2 = v0 * across, v1 * across, v2
                ur = u0 * rx + u1 * ry + u2 * rz
                rr = (rx, ry, rz)
                uu = (u0, u1, u2)
                for c in range(3):
                    for k in range(3):
                        acc[_K + 6 * c + k] += rr[c] * uu[k] - (ur if c == k else 0.0)
    H = np.zeros((6, 6))
    g = np.zeros(6)
    K = np.zeros((6, 6))
    cost = 0.0
    for chunk in range(MATCH_CHUNKS):  # in order: the same sums on any number of threads
        u = 0
        for c in range(6):
            for k in range(c, 6):
                H[c, k] += parts[chunk, u]
                u += 1
            g[c] += parts[chunk, _G + c]
            for k in range(6):
                K[c, k] += parts[chunk, _K + 6 * c + k]
        cost += parts[chunk, _COST]
    for c in range(6):
        for k in range(c):
            H[c, k] = H[k, c]
    return H, g, cost, K


def _road(road, n):
    """The road mask as a contiguous (n,) bool array (all False when None)."""
    if road is None:
        return np.zeros(n, dtype=np.bool_)
    road = np.ascontiguousarray(road, dtype=np.bool_)
    if road.shape != (n,):
        raise ValueError(
            f"road must be a (N,) mask of the {n} points, got shape {road.shape}"
        )
    return road


def _block_cache(n):
    """The per-point cache of :func:`_normal_equations_nb`: each point's last voxel block (n, 3), none yet, and
    its 8 corner slots (n, 8)."""
    return np.full((n, 3), NO_BLOCK, np.int64), np.empty((n, 8), np.int64)


def _lookup_args(lookup):
    return (
        lookup.keys,
        lookup.mean,
        lookup.icov,
        float(lookup.inv_voxel_size),
        int(lookup.log2_capacity),
        int(lookup.max_probe),
        float(lookup.m_max),
    )


def _equations(pose, points, lookup, road, with_k):
    T = np.asarray(pose, dtype=np.float64)
    pts = np.ascontiguousarray(points, dtype=np.float32)
    return _normal_equations_nb(
        np.ascontiguousarray(T[:3, :3]),
        np.ascontiguousarray(T[:3, 3]),
        pts,
        _road(road, len(pts)),
        *_lookup_args(lookup),
        *_block_cache(len(pts)),
        with_k,
    )


def normal_equations(
    pose, points, lookup, road=None
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(H (6, 6), g (6,), E)`` of the module docstring at ``pose`` (4, 4) ``T_world_body`` for body ``points``
    (N, 3) against a :class:`~slamlib.maps.base.VoxelHashLookup`; ``E = -score`` of that pose. ``road`` (N,) bool
    (default none) marks the points whose Jacobian keeps only the height, roll and pitch columns."""
    H, g, E, _ = _equations(pose, points, lookup, road, False)
    return H, g, E


def gradient_jacobian(pose, points, lookup, road=None) -> np.ndarray:
    """``dg/d(omega, v) = H + K`` (6, 6), the Jacobian of :func:`normal_equations`' ``g`` under the step
    ``R <- Exp(omega) R, t <- t + v`` (module docstring, "Newton on the fixed point"): the matrix of
    :func:`match_scan`'s Newton step. Not symmetric; arguments as :func:`normal_equations`."""
    H, _, _, K = _equations(pose, points, lookup, road, True)
    return H + K


def tilt_equations(
    R, up, world_up, weight: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(H (6, 6), g (6,), E_g)`` of gravity's term (module docstring, "Gravity's term") at the rotation ``R``
    (3, 3) ``R_world_body``: ``E_g = 0.5 weight |R^T world_up - up|^2`` with ``up`` (3,) the measured up in the
    body frame and ``world_up`` (3,) the world's, both unit vectors; only the rotation block (the first three
    rows and columns, ``omega``) is filled."""
    R = np.asarray(R, dtype=np.float64)
    world_up = np.asarray(world_up, dtype=np.float64)
    r = R.T @ world_up - np.asarray(up, dtype=np.float64)
    J = R.T @ skew(world_up)
    H, g = np.zeros((6, 6)), np.zeros(6)
    H[:3, :3] = weight * J.T @ J
    g[:3] = weight * J.T @ r
    return H, g, 0.5 * weight * float(r @ r)


def match_scan(
    pose,
    points,
    map_,
    iterations: int,
    road=None,
    tolerance: float = MATCH_TOLERANCE,
    tilt=None,
    return_hessian: bool = False,
):
    """``pose`` (4, 4) ``T_world_body`` moved by at most ``iterations`` Newton steps on the Gauss-Newton gradient
    to the nearest peak of ``map_``'s score for the body ``points`` (N, 3) (module docstring): ``(H + K) delta =
    -g``, with ``K`` from the first pass. Each step is taken only if it lowers the cost; the iteration stops at the
    first that does not, or at the first step shorter than ``tolerance`` (``|delta|`` of ``(omega, v)``, radians
    and metres; that step is not taken).
    ``road`` (N,) bool marks road points (:func:`slamlib.slam3d.preprocess.road_mask`), which then pull only on the
    height, roll and pitch (module docstring, "Road points"). ``tilt`` ``(up, world_up, weight)`` adds gravity's
    term (:func:`tilt_equations`; module docstring, "Gravity's term"); None: the map score alone. Returns a new
    (4, 4) array; a copy of ``pose`` when the map is not a voxel hash, empty, or ``iterations`` is 0.
    ``return_hessian``: return ``(pose, C)`` instead, ``C`` (6, 6) the map cost's curvature at ``pose``, the
    symmetric part of the Newton matrix ``H + K`` of the first pass, without gravity's term (zeros where no match
    was made): the map's information on the pose, in the cost's units (:class:`slamlib.slam3d.stages.TiltPrior`'s
    ``"adaptive"`` reads its tilt block). The Gauss-Newton ``H`` alone overstates it: ``K``, from the voxel
    Gaussians' own slopes, takes a good part of it back.
    """
    T = np.array(pose, dtype=np.float64)
    unmatched = (T, np.zeros((6, 6))) if return_hessian else T
    if iterations <= 0 or len(map_) == 0 or len(points) == 0:
        return unmatched
    lookup = map_.lookup()
    if lookup.kind != KIND_VOXEL_HASH:
        return unmatched
    pts = np.ascontiguousarray(points, dtype=np.float32)
    args = (_road(road, len(pts)),) + _lookup_args(lookup) + _block_cache(len(pts))
    R, t = np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3])

    def with_tilt(R, H, g, cost):
        if tilt is None:
            return H, g, cost
        Hg, gg, Eg = tilt_equations(R, *tilt)
        return H + Hg, g + gg, cost + Eg

    def equations(R, t):
        H, g, cost, _ = _normal_equations_nb(R, t, pts, *args, False)
        return with_tilt(R, H, g, cost)

    # K from the first pass only, held for the later steps (module docstring)
    H_map, g, cost, K = _normal_equations_nb(R, t, pts, *args, True)
    H, g, cost = with_tilt(R, H_map, g, cost)
    for _ in range(iterations):
        damping = MATCH_DAMPING * max(float(np.trace(H)), np.finfo(float).tiny)
        delta = -np.linalg.solve(H + K + damping * np.eye(6), g)
        if np.linalg.norm(delta) < tolerance:  # the peak is about this step away
            break
        R2, t2 = so3_exp(delta[:3]) @ R, t + delta[3:]
        H2, g2, cost2 = equations(R2, t2)
        if not cost2 < cost:
            break
        R, t, H, g, cost = R2, t2, H2, g2, cost2
    T[:3, :3], T[:3, 3] = R, t
    if not return_hessian:
        return T
    curvature = H_map + K
    return T, 0.5 * (curvature + curvature.T)
