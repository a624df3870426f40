"""Plain-numpy reference backend (``get_backend("numpy")``): clear code, the ground truth of the tests.

Shapes and frames follow CONTRIBUTING.md ("Backend interface (3D)"): particles are poses ``T_world_body`` with
rotations ``R (P, 3, 3)`` float64 and positions ``t (P, 3)`` float64; points are ``(N, 3)`` float32 in metres.
The map lookups are documented in :mod:`slamlib.maps.base`. The scores here are computed independently of the
hash table / Morton layout (sorted-key search for the voxel map, a k-d tree for the point map), so comparing the
Numba and CUDA kernels with them also checks those layouts.
"""

from __future__ import annotations

import numpy as np

from slamlib import geometry
from slamlib.maps.base import KIND_MORTON, KIND_VOXEL_HASH
from slamlib.maps.codes import axis_indices, pack_keys
from slamlib.noise import LutNoise


def move_particles(R, t, rpy_delta, trans_delta, noise, sigma, out=None):
    """Steps 5 (offset by motion) and 6 (perturb with noise) for every particle.

    For particle ``i``: ``dR = rpy_to_matrix(rpy_delta)``, ``N_i = rpy_to_matrix(sigma[3:] * noise[i, 3:])``,
    ``R_new = R_i dR N_i`` and ``t_new = t_i + R_i dR (trans_delta + sigma[:3] * noise[i, :3])``; i.e.
    ``T_i <- T_i [dR, trans_delta]`` then ``T_i <- T_i [N_i, sigma_t * n_i]`` (motion and noise in the body frame).

    Parameters
    ----------
    R : (P, 3, 3) float64, t : (P, 3) float64
        Particle poses ``T_world_body``.
    rpy_delta : (3,) radians, trans_delta : (3,) metres
        Body-frame motion since the last frame (e.g. from the IMU).
    noise : (P, 6) or :class:`slamlib.noise.LutNoise`
        Standard normal draws: translation x, y, z then roll, pitch, yaw; a ``LutNoise`` stands for
        ``noise.draw(P)`` (particle ``i`` is thread ``i``).
    sigma : (6,)
        Their standard deviations (metres, radians).

    out : (R_out, t_out), optional
        Arrays that receive the result (may be ``(R, t)``: in place).

    Returns
    -------
    R_new : (P, 3, 3) float64, t_new : (P, 3) float64
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    if isinstance(noise, LutNoise):
        noise = noise.draw(len(R))
    noise = np.asarray(noise, dtype=np.float64)
    sigma = np.asarray(sigma, dtype=np.float64)
    dR = geometry.rpy_to_matrix(np.asarray(rpy_delta, dtype=np.float64))
    N = geometry.rpy_to_matrix(sigma[3:] * noise[:, 3:])
    RdR = R @ dR
    step = np.asarray(trans_delta, dtype=np.float64) + sigma[:3] * noise[:, :3]
    R_new, t_new = RdR @ N, t + np.einsum("pij,pj->pi", RdR, step)
    if out is None:
        return R_new, t_new
    out[0][...] = R_new
    out[1][...] = t_new
    return out[0], out[1]


def transform_points(T, points, out=None):
    """``p' = R p + t`` for ``T`` (4, 4) and ``points`` (N, 3) float32 -> (N, 3) float32 (computed in float64,
    rounded once). ``out`` (N, 3) float32 receives the result and is returned (``out=points``: in place)."""
    # float32 inputs, float64 arithmetic
    pts = np.asarray(points, dtype=np.float32).astype(np.float64)
    res = geometry.transform_points(np.asarray(T, dtype=np.float64), pts)
    if out is None:
        return res.astype(np.float32)
    if out.shape != res.shape or out.dtype != np.float32:
        raise ValueError(
            f"out must be a float32 array of shape {res.shape}, got {out.dtype} {out.shape}"
        )
    out[...] = res
    return out


def _voxel_terms_at(world, keys_query, ok, lookup, stored, occupied):
    """``T_v(p)`` of world points (N, 3) float64 in the voxels with packed keys ``keys_query`` (N,)."""
    pos = np.minimum(np.searchsorted(stored, keys_query), max(stored.size - 1, 0))
    hit = ok & (stored[pos] == keys_query) if stored.size else np.zeros(len(world), bool)
    terms = np.full(len(world), -0.5 * lookup.m_max)
    s = occupied[pos[hit]]
    d = world[hit] - lookup.mean[s].astype(np.float64)
    a = lookup.icov[s].astype(np.float64)
    m = (
        a[:, 0] * d[:, 0] ** 2
        + a[:, 3] * d[:, 1] ** 2
        + a[:, 5] * d[:, 2] ** 2
        + 2.0
        * (
            a[:, 1] * d[:, 0] * d[:, 1]
            + a[:, 2] * d[:, 0] * d[:, 2]
            + a[:, 4] * d[:, 1] * d[:, 2]
        )
    )
    terms[hit] = -0.5 * np.minimum(m, lookup.m_max)
    return terms


def _terms_voxel_hash(world, lookup):
    """Trilinear interpolation over the 8 surrounding voxels of ``T_v(p)`` (see ``VoxelHashLookup``)."""
    occupied = np.flatnonzero(lookup.keys >= 0)
    stored = lookup.keys[occupied]
    order = np.argsort(stored)
    stored, occupied = stored[order], occupied[order]
    g = world * lookup.inv_voxel_size - 0.5
    base = np.floor(g)
    f = g - base
    total = np.zeros(len(world))
    for corner in np.ndindex(2, 2, 2):
        d = np.asarray(corner)
        # voxel index + 2**20 (exact: base + d is integral)
        u, ok_c = axis_indices(base + d, 1.0)
        keys = pack_keys(np.where(ok_c[:, None], u, 0))
        w = np.prod(np.where(d == 1, f, 1.0 - f), axis=1)
        total += w * _voxel_terms_at(world, keys, ok_c, lookup, stored, occupied)
    return total


def _terms_morton(world, lookup):
    """Per-point terms ``-0.5 min(d_nn, radius)^2 / sigma^2`` with a k-d tree over the stored points."""
    from scipy.spatial import cKDTree

    if len(lookup.points) == 0:
        return np.full(len(world), -0.5 * lookup.radius**2 / lookup.sigma**2)
    tree = cKDTree(lookup.points.astype(np.float64))
    d, _ = tree.query(world, k=1, distance_upper_bound=lookup.radius)
    d = np.minimum(d, lookup.radius)
    return -0.5 * d**2 / lookup.sigma**2


def point_terms(world, lookup):
    """Per-point log-likelihood terms (N,) float64 of world points (N, 3) in the map ``lookup``."""
    world = np.asarray(world, dtype=np.float64)
    if lookup.kind == KIND_VOXEL_HASH:
        return _terms_voxel_hash(world, lookup)
    if lookup.kind == KIND_MORTON:
        return _terms_morton(world, lookup)
    raise ValueError(f"unknown lookup kind {lookup.kind!r}")


def score_particles(R, t, points, lookup):
    """Log-likelihood score (P,) float64 of each particle pose for the body-frame scan ``points`` (N, 3).

    ``score_i = sum_j term(R_i p_j + t_i)`` with the map's robust per-point term (:mod:`slamlib.maps.base`);
    the transform is done in float64. Loops over particles (the reference materialises N points at a time).
    """
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t, dtype=np.float64)
    pts = np.asarray(points, dtype=np.float32).astype(np.float64)
    out = np.empty(len(R))
    for i in range(len(R)):
        out[i] = point_terms(pts @ R[i].T + t[i], lookup).sum()
    return out


def systematic_resample(weights, u0):
    """Systematic resampling (Kitagawa 1996; Douc & Cappe 2005): ``(P,)`` int64 indexes.

    With ``c = cumsum(w / sum(w))`` (``c[-1]`` set to exactly 1) and positions ``u_i = (u0 + i) / P`` for
    ``i = 0..P-1``, index ``i`` is the first ``j`` with ``u_i < c[j]`` (filterpy's ``systematic_resample`` with its
    random offset passed in as ``u0`` in ``[0, 1)``). Weights must be non-negative with a positive sum.
    """
    w = np.asarray(weights, dtype=np.float64)
    if (
        w.ndim != 1
        or w.size == 0
        or np.any(~np.isfinite(w))
        or np.any(w < 0)
        or not w.sum() > 0
    ):
        raise ValueError(
            "weights must be a non-empty 1-D array of finite non-negative numbers with positive sum"
        )
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0}")
    c = np.cumsum(w / w.sum())
    c[-1] = 1.0
    positions = (u0 + np.arange(w.size)) / w.size
    return np.searchsorted(c, positions, side="right").astype(np.int64)
