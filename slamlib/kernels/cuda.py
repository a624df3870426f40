"""CUDA backend (``get_backend("cuda")``): the four kernels of the 3D filter in ``numba.cuda``.

Same functions, shapes and math as :mod:`slamlib.kernels.reference` (CONTRIBUTING.md, "Backend interface (3D)";
map lookups in :mod:`slamlib.maps.base`). Every function accepts numpy arrays **or** device arrays: when the
particle / point / weight arrays it is given are device arrays, the results stay on the device (device arrays
returned, no copy back), so a frame can run ``move -> score -> resample`` without host round trips; with numpy
inputs it copies in and out and returns numpy (a drop-in for the CPU backends). Use :func:`to_device`,
:func:`to_host` and :func:`lookup_to_device` (upload a map's lookup once per frame) to manage copies.

Thread mapping
--------------
* **move_particles** (steps 5 + 6), two kernels as in the seed project, one thread per particle ``i``:
  the *rotation kernel* pads the roll/pitch/yaw noise, builds ``N_i = Rz Ry Rx`` and writes
  ``R_new[i] = R_i dR N_i``; the *translation kernel* pads the body-frame motion with the velocity noise
  (``trans_delta = v dt`` already holds the ``dt``), rotates it into the world frame with ``R_i dR`` and adds it to
  ``t_i``. Both read the old ``R`` and write separate outputs, so they can run in either order. The noise is a
  ``(P, 6)`` array, or a :class:`slamlib.noise.LutNoise` whose draws each thread computes itself from
  ``(i, step, seed)`` with the lookup tables (stateless: both kernels recompute the same values; no RNG state, no
  host-to-device copy of noise).
* **transform_points**: one thread per point, grid-stride loop (``j = blockIdx.x * blockDim.x + threadIdx.x``,
  stepping by ``gridDim.x * blockDim.x``), float32 arithmetic.
* **score_particles** (step 8, fused): one **block per particle**; its threads stride over the scan points,
  transform each point by the particle's pose in registers (float64), look it up in the map and accumulate a
  private float64 sum; a tree reduction in shared memory (``log2(blockDim)`` halving rounds with
  ``syncthreads``) leaves the particle's score in ``s[0]``. Memory is ``O(P + N + map)``: the ``P x N``
  transformed points (``1000 x 120k x 12 B = 1.4 GB``) are never stored.
* **systematic_resample** (step 11): an inclusive **scan** (Hillis & Steele 1986, per block in shared memory;
  block totals scanned recursively, then added back: Harris et al., GPU Gems 3 ch. 39) of the weights gives
  ``c``; thread ``i`` binary-searches the first ``j`` with ``(u0 + i) / P < c[j] / c[P-1]`` (``j = P - 1`` when
  none), the reference's ``searchsorted(..., side="right")``.

Tests run in Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, tests/conftest.py). Without a GPU (and without
the simulator), :func:`check_available` raises :class:`~slamlib.errors.BackendUnavailableError` naming the fix.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from slamlib.errors import BackendUnavailableError
from slamlib.maps.base import KIND_MORTON, KIND_VOXEL_HASH
from slamlib.noise import N_COMPONENTS, LutNoise, make_lut_functions

try:
    from numba import cuda
except ImportError:  # numba without numba-cuda: reported by check_available / get_backend
    cuda = None

#: Threads per block of the per-particle and per-point kernels.
THREADS = 128
#: Threads per block of the scoring kernel (one block per particle) and of the scan; a power of two.
SCORE_THREADS = 128
#: Upper bound on blocks of the grid-stride point kernel.
MAX_BLOCKS = 4096

UNAVAILABLE_MESSAGE = (
    "the CUDA backend needs an NVIDIA GPU with its driver and numba-cuda: install it with "
    "`pip install numba-cuda[cu12]` on a machine with a CUDA driver, or use backend=\"cpu\"")


def check_available() -> None:
    """Raise :class:`BackendUnavailableError` (with the fix in its message) when no GPU can run the kernels.

    The CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) counts as available.
    """
    if cuda is None:
        raise BackendUnavailableError(UNAVAILABLE_MESSAGE + " (numba.cuda cannot be imported)")
    try:
        ok = cuda.is_available()
    except Exception as exc:  # noqa: BLE001 - any driver failure means "not available"
        raise BackendUnavailableError(f"{UNAVAILABLE_MESSAGE} ({type(exc).__name__}: {exc})") from None
    if not ok:
        raise BackendUnavailableError(UNAVAILABLE_MESSAGE + " (no CUDA driver or GPU found)")


# ------------------------------------------------------------------------------------------------ host helpers
def is_device_array(a) -> bool:
    """True for numba device arrays (and other ``__cuda_array_interface__`` objects)."""
    if cuda is None or isinstance(a, np.ndarray):
        return False
    # real device arrays expose __cuda_array_interface__; the simulator's FakeCUDAArray has copy_to_host
    return hasattr(a, "__cuda_array_interface__") or hasattr(a, "copy_to_host")


def to_device(a, dtype=None):
    """Copy a numpy array to the device (C-contiguous, optional ``dtype``); device arrays pass through."""
    if is_device_array(a):
        return a
    arr = np.asarray(a) if dtype is None else np.asarray(a, dtype=dtype)
    return cuda.to_device(np.ascontiguousarray(arr))


def to_host(a) -> np.ndarray:
    """Copy a device array back to a numpy array; numpy arrays pass through."""
    return a.copy_to_host() if is_device_array(a) else np.asarray(a)


def lookup_to_device(lookup):
    """The same lookup NamedTuple with every numpy array field copied to the device (scalars unchanged)."""
    return type(lookup)(*(to_device(v) if isinstance(v, np.ndarray) else v for v in lookup))


def tables_to_device(tables):
    """:class:`slamlib.noise.NoiseTables` with its two tables on the device (upload once; pass
    ``LutNoise(tables_to_device(t), step, seed)`` to :func:`move_particles` so nothing is copied per frame)."""
    return type(tables)(to_device(tables.normal), to_device(tables.perm), tables.bits)


def _blocks(n: int, threads: int, cap: int | None = None) -> int:
    b = max(1, (n + threads - 1) // threads)
    return min(b, cap) if cap else b


# --------------------------------------------------------------------------------------------- device code
if cuda is not None:
    _LUT = make_lut_functions(cuda.jit(device=True))
    _lut_draw = _LUT["lut_draw"]

    @cuda.jit(device=True)
    def _rpy(r, p, y, out):
        """``out = Rz(y) Ry(p) Rx(r)`` (3, 3)."""
        cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
        out[0, 0] = cy * cp
        out[0, 1] = cy * sp * sr - sy * cr
        out[0, 2] = cy * sp * cr + sy * sr
        out[1, 0] = sy * cp
        out[1, 1] = sy * sp * sr + cy * cr
        out[1, 2] = sy * sp * cr - cy * sr
        out[2, 0] = -sp
        out[2, 1] = cp * sr
        out[2, 2] = cp * cr

    @cuda.jit(device=True)
    def _noise(i, k, noise, use_lut, normal, perm, bits, step, seed):
        """Standard-normal draw ``k`` of particle ``i``: from the array, or from the lookup tables."""
        if use_lut:
            return np.float64(_lut_draw(i, step, seed, k, normal, perm, bits))
        return np.float64(noise[i, k])

    @cuda.jit(device=True)
    def _r_times_dr(R, i, dR, A):
        for a in range(3):
            for b in range(3):
                A[a, b] = R[i, a, 0] * dR[0, b] + R[i, a, 1] * dR[1, b] + R[i, a, 2] * dR[2, b]

    @cuda.jit
    def _rotation_kernel(R, dR, sigma, noise, use_lut, normal, perm, bits, step, seed, R_new):
        i = cuda.grid(1)
        if i >= R.shape[0]:
            return
        N = cuda.local.array((3, 3), np.float64)
        A = cuda.local.array((3, 3), np.float64)
        _rpy(sigma[3] * _noise(i, 3, noise, use_lut, normal, perm, bits, step, seed),
             sigma[4] * _noise(i, 4, noise, use_lut, normal, perm, bits, step, seed),
             sigma[5] * _noise(i, 5, noise, use_lut, normal, perm, bits, step, seed), N)
        _r_times_dr(R, i, dR, A)
        for a in range(3):
            for b in range(3):
                R_new[i, a, b] = A[a, 0] * N[0, b] + A[a, 1] * N[1, b] + A[a, 2] * N[2, b]

    @cuda.jit
    def _translation_kernel(R, t, dR, trans_delta, sigma, noise, use_lut, normal, perm, bits, step, seed, t_new):
        i = cuda.grid(1)
        if i >= R.shape[0]:
            return
        A = cuda.local.array((3, 3), np.float64)
        _r_times_dr(R, i, dR, A)
        sx = trans_delta[0] + sigma[0] * _noise(i, 0, noise, use_lut, normal, perm, bits, step, seed)
        sy = trans_delta[1] + sigma[1] * _noise(i, 1, noise, use_lut, normal, perm, bits, step, seed)
        sz = trans_delta[2] + sigma[2] * _noise(i, 2, noise, use_lut, normal, perm, bits, step, seed)
        for a in range(3):
            t_new[i, a] = t[i, a] + A[a, 0] * sx + A[a, 1] * sy + A[a, 2] * sz

    @cuda.jit
    def _lut_fill_kernel(normal, perm, bits, step, seed, out):
        """``out[i, k]`` = LUT draw ``k`` of thread ``i`` (the values of :func:`slamlib.noise.lut_normal`)."""
        i = cuda.grid(1)
        if i < out.shape[0]:
            for k in range(out.shape[1]):
                out[i, k] = _lut_draw(i, step, seed, k, normal, perm, bits)

    @cuda.jit
    def _transform_kernel(R, t, pts, out):
        start = cuda.grid(1)
        stride = cuda.gridsize(1)
        r00, r01, r02 = R[0, 0], R[0, 1], R[0, 2]
        r10, r11, r12 = R[1, 0], R[1, 1], R[1, 2]
        r20, r21, r22 = R[2, 0], R[2, 1], R[2, 2]
        for j in range(start, pts.shape[0], stride):
            x, y, z = pts[j, 0], pts[j, 1], pts[j, 2]
            out[j, 0] = r00 * x + r01 * y + r02 * z + t[0]
            out[j, 1] = r10 * x + r11 * y + r12 * z + t[1]
            out[j, 2] = r20 * x + r21 * y + r22 * z + t[2]

    # ---- map lookups (device versions of slamlib.maps.codes / slamlib.kernels.cpu, same formulas)
    _M32 = np.uint64(0xFFFFFFFF)
    _S32 = np.uint64(32)
    _HASH_LO = np.uint64(0x9E3779B97F4A7C15 & 0xFFFFFFFF)
    _HASH_HI = np.uint64(0x9E3779B97F4A7C15 >> 32)
    _OFFSET = np.int64(1 << 20)
    _AXIS_MAX = np.int64((1 << 21) - 1)

    @cuda.jit(device=True)
    def _hash_slot(key, log2_capacity):
        """``((uint64(key) * 0x9E3779B97F4A7C15) mod 2**64) >> (64 - log2_capacity)`` from 32-bit halves
        (no intermediate overflows, so the simulator's numpy scalars agree with the GPU)."""
        a = np.uint64(key)
        a_lo = a & _M32
        a_hi = a >> _S32
        lo = a_lo * _HASH_LO
        cross = ((a_hi * _HASH_LO) & _M32) + ((a_lo * _HASH_HI) & _M32) + (lo >> _S32)
        prod = ((cross & _M32) << _S32) | (lo & _M32)
        return np.int64(prod >> np.uint64(64 - log2_capacity))

    @cuda.jit(device=True)
    def _find_slot(keys, key, log2_capacity, max_probe):
        mask = (np.int64(1) << log2_capacity) - 1
        s = _hash_slot(key, log2_capacity)
        for _ in range(max_probe + 1):
            k = keys[s]
            if k == key:
                return s
            if k == -1:
                return -1
            s = (s + 1) & mask
        return -1

    @cuda.jit(device=True)
    def _voxel_term(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max):
        """Trilinear NDT term of a world point (``VoxelHashLookup``); see ``slamlib.kernels.cpu.voxel_term_nb``."""
        miss = -0.5 * m_max
        gx = wx * inv_h - 0.5
        gy = wy * inv_h - 0.5
        gz = wz * inv_h - 0.5
        if not (abs(gx) <= 2.0**21 and abs(gy) <= 2.0**21 and abs(gz) <= 2.0**21):
            return miss  # far outside the key range, or NaN
        bx = math.floor(gx)
        by = math.floor(gy)
        bz = math.floor(gz)
        fx = gx - bx
        fy = gy - by
        fz = gz - bz
        ux0 = np.int64(bx) + _OFFSET
        uy0 = np.int64(by) + _OFFSET
        uz0 = np.int64(bz) + _OFFSET
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
                    if ux >= 0 and ux <= _AXIS_MAX and uy >= 0 and uy <= _AXIS_MAX and uz >= 0 and uz <= _AXIS_MAX:
                        s = _find_slot(keys, ux | (uy << 21) | (uz << 42), log2_capacity, max_probe)
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

    @cuda.jit(device=True)
    def _part1by2(v):
        v = v & 0x1FFFFF
        v = (v | (v << 32)) & 0x1F00000000FFFF
        v = (v | (v << 16)) & 0x1F0000FF0000FF
        v = (v | (v << 8)) & 0x100F00F00F00F00F
        v = (v | (v << 4)) & 0x10C30C30C30C30C3
        v = (v | (v << 2)) & 0x1249249249249249
        return v

    @cuda.jit(device=True)
    def _find_cell(cell_codes, code):
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

    @cuda.jit(device=True)
    def _morton_d2(wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2):
        """``min(d_nn^2, r2)`` of a world point in a ``MortonLookup`` (the 2x2x2 nearest cells, brute force)."""
        best = r2
        size = np.float64(np.int64(1) << cell_level)
        inv_q = 1.0 / quantum
        ux = wx * inv_q + 1048576.0
        uy = wy * inv_q + 1048576.0
        uz = wz * inv_q + 1048576.0
        fx = math.floor(ux / size - 0.5)
        fy = math.floor(uy / size - 0.5)
        fz = math.floor(uz / size - 0.5)
        lim = np.int64(1) << (21 - cell_level)
        if not (fx >= -1.0 and fy >= -1.0 and fz >= -1.0 and fx < lim and fy < lim and fz < lim):
            return best
        cx0 = np.int64(fx)
        cy0 = np.int64(fy)
        cz0 = np.int64(fz)
        for dz in range(2):
            cz = cz0 + dz
            if cz < 0 or cz >= lim:
                continue
            for dy in range(2):
                cy = cy0 + dy
                if cy < 0 or cy >= lim:
                    continue
                for dx in range(2):
                    cx = cx0 + dx
                    if cx < 0 or cx >= lim:
                        continue
                    code = _part1by2(cx) | (_part1by2(cy) << 1) | (_part1by2(cz) << 2)
                    k = _find_cell(cell_codes, code)
                    if k < 0:
                        continue
                    for j in range(cell_start[k], cell_start[k + 1]):
                        ex = wx - np.float64(points[j, 0])
                        ey = wy - np.float64(points[j, 1])
                        ez = wz - np.float64(points[j, 2])
                        d2 = ex * ex + ey * ey + ez * ez
                        if d2 < best:
                            best = d2
        return best

    @cuda.jit(device=True)
    def _world(R, t, i, x, y, z):
        return (R[i, 0, 0] * x + R[i, 0, 1] * y + R[i, 0, 2] * z + t[i, 0],
                R[i, 1, 0] * x + R[i, 1, 1] * y + R[i, 1, 2] * z + t[i, 1],
                R[i, 2, 0] * x + R[i, 2, 1] * y + R[i, 2, 2] * z + t[i, 2])

    @cuda.jit
    def _search_kernel(c, u0, out):
        """``out[i]`` = first ``j`` with ``(u0 + i) / P < c[j] / c[P-1]`` (``P - 1`` if none)."""
        i = cuda.grid(1)
        P = c.shape[0]
        if i >= P:
            return
        total = c[P - 1]
        u = (u0 + i) / P
        lo = 0
        hi = P - 1
        while lo < hi:
            mid = (lo + hi) >> 1
            if u < c[mid] / total:
                hi = mid
            else:
                lo = mid + 1
        out[i] = lo

    @cuda.jit
    def _add_offsets_kernel(out, block_scan):
        i = cuda.grid(1)
        b = cuda.blockIdx.x
        if i < out.shape[0] and b > 0:
            out[i] += block_scan[b - 1]


@lru_cache(maxsize=None)
def _block_kernels(threads: int):
    """The shared-memory kernels for a block size ``threads`` (a power of two; compiled once per size)."""
    if threads < 1 or threads & (threads - 1):
        raise ValueError(f"threads per block must be a power of two, got {threads}")

    @cuda.jit(device=True)
    def _block_sum(s, tid, value):
        """Tree reduction of ``value`` over the block in shared array ``s``; the total is in ``s[0]``."""
        s[tid] = value
        cuda.syncthreads()
        half = threads // 2
        while half > 0:
            if tid < half:
                s[tid] += s[tid + half]
            cuda.syncthreads()
            half //= 2

    @cuda.jit
    def score_voxel(R, t, pts, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max, out):
        i = cuda.blockIdx.x  # one block per particle
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(tid, pts.shape[0], threads):
            wx, wy, wz = _world(R, t, i, np.float64(pts[j, 0]), np.float64(pts[j, 1]), np.float64(pts[j, 2]))
            acc += _voxel_term(wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max)
        _block_sum(s, tid, acc)
        if tid == 0:
            out[i] = s[0]

    @cuda.jit
    def score_morton(R, t, pts, points, cell_codes, cell_start, quantum, cell_level, r2, scale, out):
        i = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(tid, pts.shape[0], threads):
            wx, wy, wz = _world(R, t, i, np.float64(pts[j, 0]), np.float64(pts[j, 1]), np.float64(pts[j, 2]))
            acc += scale * _morton_d2(wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2)
        _block_sum(s, tid, acc)
        if tid == 0:
            out[i] = s[0]

    @cuda.jit
    def scan_block(x, out, block_sums):
        """Inclusive Hillis-Steele scan of each block's slice of ``x``; block totals into ``block_sums``."""
        tid = cuda.threadIdx.x
        i = cuda.blockIdx.x * threads + tid
        s = cuda.shared.array(threads, np.float64)
        s[tid] = x[i] if i < x.shape[0] else 0.0
        cuda.syncthreads()
        off = 1
        while off < threads:
            v = s[tid - off] if tid >= off else 0.0
            cuda.syncthreads()
            s[tid] += v
            cuda.syncthreads()
            off *= 2
        if i < x.shape[0]:
            out[i] = s[tid]
        if tid == threads - 1:
            block_sums[cuda.blockIdx.x] = s[tid]

    return score_voxel, score_morton, scan_block


# ------------------------------------------------------------------------------------------- host functions
def _particles(R, t):
    if is_device_array(R):
        if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
            raise ValueError(f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}")
        return R, t, True
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
        raise ValueError(f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}")
    return to_device(R), to_device(t), False


def move_particles(R, t, rpy_delta, trans_delta, noise, sigma, threads: int = THREADS):
    """Steps 5 + 6 fused (see :func:`slamlib.kernels.reference.move_particles`), one thread per particle.

    ``noise`` is a ``(P, 6)`` standard-normal array (numpy or device) or a :class:`slamlib.noise.LutNoise`
    (draws generated on the device from the lookup tables: ``noise.draw(P)`` is the same array on the host).
    Returns ``(R_new, t_new)``: device arrays when ``R`` is a device array, numpy otherwise.
    """
    check_available()
    R_d, t_d, on_device = _particles(R, t)
    P = R_d.shape[0]
    sigma = np.ascontiguousarray(sigma, dtype=np.float64).reshape(6)
    rpy = np.asarray(rpy_delta, dtype=np.float64).reshape(3)
    from slamlib.geometry import rpy_to_matrix

    dR = to_device(np.ascontiguousarray(rpy_to_matrix(rpy), dtype=np.float64))
    trans = to_device(np.asarray(trans_delta, dtype=np.float64).reshape(3))
    sig = to_device(sigma)
    if isinstance(noise, LutNoise):
        if noise.step < 0 or noise.seed < 0:
            raise ValueError("LutNoise step and seed must be >= 0")
        use_lut = True
        normal, perm = to_device(noise.tables.normal), to_device(noise.tables.perm)
        bits, step, seed = np.int64(noise.tables.bits), np.int64(noise.step), np.int64(noise.seed)
        noise_d = to_device(np.zeros((1, N_COMPONENTS)))
    else:
        use_lut = False
        if not is_device_array(noise):
            noise = np.ascontiguousarray(noise, dtype=np.float64)
        if noise.shape != (P, N_COMPONENTS):
            raise ValueError(f"noise must have shape (P, 6) = ({P}, 6), got {noise.shape}")
        noise_d = to_device(noise)
        normal, perm = to_device(np.zeros(1, np.float32)), to_device(np.zeros((N_COMPONENTS, 1), np.int32))
        bits = step = seed = np.int64(0)
    R_new = cuda.device_array((P, 3, 3), np.float64)
    t_new = cuda.device_array((P, 3), np.float64)
    if P:
        grid = _blocks(P, threads)
        _rotation_kernel[grid, threads](R_d, dR, sig, noise_d, use_lut, normal, perm, bits, step, seed, R_new)
        _translation_kernel[grid, threads](R_d, t_d, dR, trans, sig, noise_d, use_lut, normal, perm, bits, step,
                                           seed, t_new)
    if on_device:
        return R_new, t_new
    return R_new.copy_to_host(), t_new.copy_to_host()


def lut_normal_device(noise: LutNoise, n: int, threads: int = THREADS):
    """The (n, 6) float32 LUT draws of :class:`~slamlib.noise.LutNoise` generated on the device (device array)."""
    check_available()
    out = cuda.device_array((n, N_COMPONENTS), np.float32)
    if n:
        _lut_fill_kernel[_blocks(n, threads), threads](to_device(noise.tables.normal), to_device(noise.tables.perm),
                                                       np.int64(noise.tables.bits), np.int64(noise.step),
                                                       np.int64(noise.seed), out)
    return out


def transform_points(T, points, threads: int = THREADS, max_blocks: int = MAX_BLOCKS):
    """``p' = R p + t`` for ``T`` (4, 4) and ``points`` (N, 3) float32 -> (N, 3) float32 (float32 arithmetic).

    One thread per point in a grid-stride loop of at most ``max_blocks`` blocks. Returns a device array when
    ``points`` is one.
    """
    check_available()
    T = np.asarray(T, dtype=np.float64)
    on_device = is_device_array(points)
    pts = points if on_device else np.ascontiguousarray(points, dtype=np.float32)
    if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"need T (4, 4) and points (N, 3), got {T.shape} and {pts.shape}")
    pts_d = to_device(pts)
    out = cuda.device_array(pts_d.shape, np.float32)
    if pts_d.shape[0]:
        _transform_kernel[_blocks(pts_d.shape[0], threads, max_blocks), threads](
            to_device(np.ascontiguousarray(T[:3, :3], dtype=np.float32)),
            to_device(np.ascontiguousarray(T[:3, 3], dtype=np.float32)), pts_d, out)
    return out if on_device else out.copy_to_host()


def score_particles(R, t, points, lookup, threads: int = SCORE_THREADS):
    """Fused transform + map lookup log-likelihood (P,) float64, one block of ``threads`` per particle.

    ``lookup`` is a :class:`~slamlib.maps.base.VoxelHashLookup` or :class:`~slamlib.maps.base.MortonLookup`
    (numpy fields, or device fields from :func:`lookup_to_device`). Returns a device array when ``R`` is one.
    """
    check_available()
    R_d, t_d, on_device = _particles(R, t)
    pts = points if is_device_array(points) else np.ascontiguousarray(points, dtype=np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    pts_d = to_device(pts)
    P = R_d.shape[0]
    out = cuda.device_array(P, np.float64)
    score_voxel, score_morton, _ = _block_kernels(int(threads))
    if lookup.kind == KIND_VOXEL_HASH:
        if P:
            score_voxel[P, threads](R_d, t_d, pts_d, to_device(lookup.keys), to_device(lookup.mean),
                                    to_device(lookup.icov), float(lookup.inv_voxel_size),
                                    np.int64(lookup.log2_capacity), np.int64(lookup.max_probe), float(lookup.m_max),
                                    out)
    elif lookup.kind == KIND_MORTON:
        scale = -0.5 / float(lookup.sigma) ** 2
        r2 = float(lookup.radius) ** 2
        if P and lookup.cell_codes.shape[0] == 0:  # empty map: every point costs the truncation
            vals = np.full(P, scale * r2 * pts_d.shape[0])
            return to_device(vals) if on_device else vals
        if P:
            score_morton[P, threads](R_d, t_d, pts_d, to_device(lookup.points), to_device(lookup.cell_codes),
                                     to_device(lookup.cell_start), float(lookup.quantum),
                                     np.int64(lookup.cell_level), r2, scale, out)
    else:
        raise ValueError(f"unknown lookup kind {lookup.kind!r}")
    return out if on_device else out.copy_to_host()


def inclusive_scan(x, threads: int = SCORE_THREADS):
    """Inclusive prefix sum of a 1-D float64 device array (device array out): block scans, recursive totals."""
    check_available()
    x_d = to_device(x, np.float64) if not is_device_array(x) else x
    n = x_d.shape[0]
    _, _, scan_block = _block_kernels(int(threads))
    out = cuda.device_array(n, np.float64)
    nb = _blocks(n, threads)
    sums = cuda.device_array(nb, np.float64)
    scan_block[nb, threads](x_d, out, sums)
    if nb > 1:
        sums_scan = inclusive_scan(sums, threads)
        _add_offsets_kernel[nb, threads](out, sums_scan)
    return out


def systematic_resample(weights, u0, threads: int = SCORE_THREADS):
    """Systematic resampling (P,) int64 (see :func:`slamlib.kernels.reference.systematic_resample`) on the device.

    Scan of the weights (:func:`inclusive_scan`), then one thread per output index binary-searches the scan.
    numpy weights are validated like the reference; device weights are trusted (checking needs a copy back).
    Returns a device array when ``weights`` is one.
    """
    check_available()
    if not 0.0 <= u0 < 1.0:
        raise ValueError(f"u0 must be in [0, 1), got {u0}")
    on_device = is_device_array(weights)
    if not on_device:
        w = np.ascontiguousarray(weights, dtype=np.float64)
        if w.ndim != 1 or w.size == 0 or np.any(~np.isfinite(w)) or np.any(w < 0) or not w.sum() > 0:
            raise ValueError("weights must be a non-empty 1-D array of finite non-negative numbers with positive sum")
        weights = w
    c = inclusive_scan(weights, threads)
    P = c.shape[0]
    out = cuda.device_array(P, np.int64)
    _search_kernel[_blocks(P, threads), threads](c, float(u0), out)
    return out if on_device else out.copy_to_host()


@dataclass(frozen=True)
class CudaBackend:
    """The CUDA kernels with their launch configuration (thin object; the math is in the module functions).

    Construction checks that a GPU (or the simulator) is usable and raises
    :class:`~slamlib.errors.BackendUnavailableError` otherwise.
    """

    threads: int = THREADS
    score_threads: int = SCORE_THREADS
    max_blocks: int = MAX_BLOCKS
    name: str = "cuda"

    def __post_init__(self):
        check_available()

    def move_particles(self, R, t, rpy_delta, trans_delta, noise, sigma):
        return move_particles(R, t, rpy_delta, trans_delta, noise, sigma, threads=self.threads)

    def transform_points(self, T, points):
        return transform_points(T, points, threads=self.threads, max_blocks=self.max_blocks)

    def score_particles(self, R, t, points, lookup):
        return score_particles(R, t, points, lookup, threads=self.score_threads)

    def systematic_resample(self, weights, u0):
        return systematic_resample(weights, u0, threads=self.score_threads)

    to_device = staticmethod(to_device)
    to_host = staticmethod(to_host)
    lookup_to_device = staticmethod(lookup_to_device)
    tables_to_device = staticmethod(tables_to_device)
