"""CUDA backend (``get_backend("cuda")``): the four kernels of the 3D filter in ``numba.cuda``.

Same functions, shapes and math as :mod:`slamlib.kernels.reference` (CONTRIBUTING.md, "Backend interface (3D)";
map lookups in :mod:`slamlib.maps.base`). Every function accepts numpy arrays **or** device arrays: when the
particle / point / weight arrays it is given are device arrays, the results stay on the device (device arrays
returned, no copy back), so a frame can run ``move -> score -> resample`` without host round trips; with numpy
inputs it copies in and out and returns numpy (a drop-in for the CPU backends). Use :func:`to_device` and
:func:`to_host` to manage copies. A map's lookup is uploaded once per map version, not once per call:
:func:`lookup_to_device` (called by :func:`score_particles`) keeps the device arrays keyed by the lookup's
``version`` stamp, which every ``merge`` / ``prune`` of the map renews.

The arithmetic per particle and per point (rotation from roll/pitch/yaw, the motion update, the point
transform, the NDT voxel term, hashing / linear probing, Morton codes, cell search, the nearest-neighbour
query) is the ``cuda.jit(device=True)`` build of :func:`slamlib.kernels.device.make_point_functions`, the
same source as the CPU backend's ``njit`` build; the noise draws are the device build of
:func:`slamlib.noise.make_lut_functions`. This module only maps threads and blocks onto them, reduces and scans.
Launch sizes are keywords of the module functions (``threads=``, ``max_blocks=``; defaults :data:`THREADS`,
:data:`SCORE_THREADS`, :data:`MAX_BLOCKS`).

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
  transform each point by the particle's pose in registers (float64), look it up in the map (voxel map: the
  trilinear NDT term; Morton map: the brute-force scan of the 2x2x2 nearest cells, ``morton_d2``, rather than
  the CPU's branch-and-bound, which needs a per-thread stack) and accumulate a private float64 sum; a tree
  reduction in shared memory (``log2(blockDim)`` halving rounds with ``syncthreads``) leaves the particle's
  score in ``s[0]``. Memory is ``O(P + N + map)``: the ``P x N`` transformed points
  (``1000 x 120k x 12 B = 1.4 GB``) are never stored. With ``layout="tiles"`` the grid is
  ``(P, ceil(N / tile_points))`` instead: block ``(i, k)`` sums particle ``i``'s points ``k * tile_points ..``
  into ``partial[i, k]`` and a second kernel (one thread per particle) adds each row in order. At the default
  300 particles one block per particle gives an H100's 132 SMs about two blocks each, below what they can hold
  (``slamlib bench cuda --static``); tiles of :data:`TILE_POINTS` multiply the blocks by the number of tiles, at
  the cost of a ``(P, tiles)`` float64 buffer and a second launch.
* **systematic_resample** (step 11): an inclusive **scan** (Hillis & Steele 1986, per block in shared memory;
  block totals scanned recursively, then added back: Harris et al., GPU Gems 3 ch. 39) of the weights gives
  ``c``; thread ``i`` binary-searches the first ``j`` with ``(u0 + i) / P < c[j] / c[P-1]`` (``j = P - 1`` when
  none), the reference's ``searchsorted(..., side="right")``.

Tests run in Numba's CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``, tests/conftest.py). Without a GPU (and without
the simulator), :func:`check_available` raises :class:`~slamlib.errors.BackendUnavailableError` naming the fix.
"""

from __future__ import annotations

from collections import OrderedDict
from functools import cache

import numpy as np

from slamlib.errors import BackendUnavailableError
from slamlib.kernels.device import make_point_functions
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
#: Points per block of the tiled scoring layout (``score_particles(..., layout="tiles")``).
TILE_POINTS = 256
#: Thread mappings of ``score_particles``: one block per particle, or blocks over particle x point tiles.
SCORE_LAYOUTS = ("block", "tiles")

UNAVAILABLE_MESSAGE = (
    "the CUDA backend needs an NVIDIA GPU with its driver and numba-cuda: install it with "
    '`pip install numba-cuda[cu12]` on a machine with a CUDA driver, or use backend="cpu"'
)


def check_available() -> None:
    """Raise :class:`BackendUnavailableError` (with the fix in its message) when no GPU can run the kernels.

    The CUDA simulator (``NUMBA_ENABLE_CUDASIM=1``) counts as available.
    """
    if cuda is None:
        raise BackendUnavailableError(
            UNAVAILABLE_MESSAGE + " (numba.cuda cannot be imported)"
        )
    try:
        ok = cuda.is_available()
    except Exception as exc:  # noqa: BLE001 - any driver failure means "not available"
        raise BackendUnavailableError(
            f"{UNAVAILABLE_MESSAGE} ({type(exc).__name__}: {exc})"
        ) from None
    if not ok:
        raise BackendUnavailableError(
            UNAVAILABLE_MESSAGE + " (no CUDA driver or GPU found)"
        )


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


#: How many map versions :func:`lookup_to_device` keeps on the device (least recently used dropped first): the
#: current map, and one more (the previous version until it ages out, or a second map scored alternately).
LOOKUP_CACHE_SIZE = 2
# (kind, version) -> {field name: device array}; see lookup_to_device
_lookup_cache: OrderedDict = OrderedDict()


def lookup_to_device(lookup):
    """The same lookup NamedTuple with its numpy array fields on the device (scalars unchanged).

    A lookup made by a map carries the map's ``version`` stamp (:attr:`slamlib.maps.base.Map3D.version`,
    drawn anew by every ``merge`` / ``prune``): its arrays are uploaded once per version and kept, so scoring
    again before the map changes (the particles of a frame, or frames without a merge) copies nothing; the last
    :data:`LOOKUP_CACHE_SIZE` versions are kept (:func:`clear_lookup_cache` frees them). A tuple with
    ``version == 0`` (made by hand) is uploaded on every call and not kept; device array fields pass through.
    """
    version = int(getattr(lookup, "version", 0))
    if not version or not any(isinstance(v, np.ndarray) for v in lookup):
        return type(lookup)(
            *(to_device(v) if isinstance(v, np.ndarray) else v for v in lookup)
        )
    key = (int(lookup.kind), version)
    arrays = _lookup_cache.get(key)
    if arrays is None:
        arrays = {
            f: to_device(v)
            for f, v in zip(lookup._fields, lookup)
            if isinstance(v, np.ndarray)
        }
        _lookup_cache[key] = arrays
        while len(_lookup_cache) > LOOKUP_CACHE_SIZE:
            _lookup_cache.popitem(last=False)
    else:
        _lookup_cache.move_to_end(key)
    return lookup._replace(**arrays)


def clear_lookup_cache() -> None:
    """Drop the device copies of map lookups kept by :func:`lookup_to_device` (frees their GPU memory)."""
    _lookup_cache.clear()


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
    # the per-particle / per-point math, the same source as the CPU backend's (slamlib.kernels.device)
    _D = make_point_functions(cuda.jit(device=True))
    _rpy_matrix = _D["rpy_matrix"]
    _pose_times = _D["pose_times"]
    _compose_rotation = _D["compose_rotation"]
    _compose_translation = _D["compose_translation"]
    _world_point = _D["world_point"]
    _voxel_term = _D["voxel_term"]
    _morton_d2 = _D["morton_d2"]

    @cuda.jit(device=True)
    def _noise(i, k, noise, use_lut, normal, perm, bits, step, seed):
        """Standard-normal draw ``k`` of particle ``i``: from the array, or from the lookup tables."""
        if use_lut:
            return np.float64(_lut_draw(i, step, seed, k, normal, perm, bits))
        return np.float64(noise[i, k])

    @cuda.jit
    def _rotation_kernel(
        R, dR, sigma, noise, use_lut, normal, perm, bits, step, seed, R_new
    ):
        i = cuda.grid(1)
        if i >= R.shape[0]:
            return
        N = cuda.local.array((3, 3), np.float64)
        A = cuda.local.array((3, 3), np.float64)
        _rpy_matrix(
            sigma[3] * _noise(i, 3, noise, use_lut, normal, perm, bits, step, seed),
            sigma[4] * _noise(i, 4, noise, use_lut, normal, perm, bits, step, seed),
            sigma[5] * _noise(i, 5, noise, use_lut, normal, perm, bits, step, seed),
            N,
        )
        _pose_times(R, i, dR, A)  # A = R_i dR
        _compose_rotation(A, N, R_new, i)

    @cuda.jit
    def _translation_kernel(
        R,
        t,
        dR,
        trans_delta,
        sigma,
        noise,
        use_lut,
        normal,
        perm,
        bits,
        step,
        seed,
        t_new,
    ):
        i = cuda.grid(1)
        if i >= R.shape[0]:
            return
        A = cuda.local.array((3, 3), np.float64)
        _pose_times(R, i, dR, A)
        sx = trans_delta[0] + sigma[0] * _noise(
            i, 0, noise, use_lut, normal, perm, bits, step, seed
        )
        sy = trans_delta[1] + sigma[1] * _noise(
            i, 1, noise, use_lut, normal, perm, bits, step, seed
        )
        sz = trans_delta[2] + sigma[2] * _noise(
            i, 2, noise, use_lut, normal, perm, bits, step, seed
        )
        _compose_translation(t, A, sx, sy, sz, t_new, i)

    @cuda.jit
    def _lut_fill_kernel(normal, perm, bits, step, seed, out):
        """``out[i, k]`` = LUT draw ``k`` of thread ``i`` (the values of :func:`slamlib.noise.lut_normal`)."""
        i = cuda.grid(1)
        if i < out.shape[0]:
            for k in range(out.shape[1]):
                out[i, k] = _lut_draw(i, step, seed, k, normal, perm, bits)

    @cuda.jit
    def _transform_kernel(R, t, pts, out):
        """Grid-stride loop over the points; ``R`` (1, 3, 3), ``t`` (1, 3) float32: one pose."""
        for j in range(cuda.grid(1), pts.shape[0], cuda.gridsize(1)):
            out[j, 0], out[j, 1], out[j, 2] = _world_point(
                R, t, 0, pts[j, 0], pts[j, 1], pts[j, 2]
            )

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
    def _sum_tiles_kernel(partial, out):
        """``out[i] = sum_k partial[i, k]`` in order of ``k``: the second pass of the tiled scoring layout."""
        i = cuda.grid(1)
        if i < out.shape[0]:
            acc = 0.0
            for k in range(partial.shape[1]):
                acc += partial[i, k]
            out[i] = acc

    @cuda.jit
    def _add_offsets_kernel(out, block_scan):
        i = cuda.grid(1)
        b = cuda.blockIdx.x
        if i < out.shape[0] and b > 0:
            out[i] += block_scan[b - 1]


@cache
def _block_sum_function(threads: int):
    """The block-wide tree reduction for a block size ``threads`` (a power of two) as a device function."""
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

    return _block_sum


@cache
def _block_kernels(threads: int):
    """The shared-memory kernels for a block size ``threads`` (a power of two; compiled once per size)."""
    _block_sum = _block_sum_function(threads)

    @cuda.jit
    def score_voxel(
        R, t, pts, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max, out
    ):
        i = cuda.blockIdx.x  # one block per particle
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(tid, pts.shape[0], threads):
            wx, wy, wz = _world_point(
                R,
                t,
                i,
                np.float64(pts[j, 0]),
                np.float64(pts[j, 1]),
                np.float64(pts[j, 2]),
            )
            acc += _voxel_term(
                wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max
            )
        _block_sum(s, tid, acc)
        if tid == 0:
            out[i] = s[0]

    @cuda.jit
    def score_morton(
        R, t, pts, points, cell_codes, cell_start, quantum, cell_level, r2, scale, out
    ):
        i = cuda.blockIdx.x
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(tid, pts.shape[0], threads):
            wx, wy, wz = _world_point(
                R,
                t,
                i,
                np.float64(pts[j, 0]),
                np.float64(pts[j, 1]),
                np.float64(pts[j, 2]),
            )
            acc += scale * _morton_d2(
                wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2
            )
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


@cache
def _tile_kernels(threads: int):
    """The scoring kernels of the tiled layout for a block size ``threads`` (a power of two): block ``(i, k)``
    writes the sum over particle ``i``'s points ``k * tile .. (k + 1) * tile - 1`` to ``partial[i, k]``."""
    _block_sum = _block_sum_function(threads)

    @cuda.jit
    def score_voxel_tiles(
        R, t, pts, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max, tile, partial
    ):
        i = cuda.blockIdx.x  # particle
        k = cuda.blockIdx.y  # tile of points
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(k * tile + tid, min((k + 1) * tile, pts.shape[0]), threads):
            wx, wy, wz = _world_point(
                R,
                t,
                i,
                np.float64(pts[j, 0]),
                np.float64(pts[j, 1]),
                np.float64(pts[j, 2]),
            )
            acc += _voxel_term(
                wx, wy, wz, keys, mean, icov, inv_h, log2_capacity, max_probe, m_max
            )
        _block_sum(s, tid, acc)
        if tid == 0:
            partial[i, k] = s[0]

    @cuda.jit
    def score_morton_tiles(
        R,
        t,
        pts,
        points,
        cell_codes,
        cell_start,
        quantum,
        cell_level,
        r2,
        scale,
        tile,
        partial,
    ):
        i = cuda.blockIdx.x
        k = cuda.blockIdx.y
        tid = cuda.threadIdx.x
        s = cuda.shared.array(threads, np.float64)
        acc = 0.0
        for j in range(k * tile + tid, min((k + 1) * tile, pts.shape[0]), threads):
            wx, wy, wz = _world_point(
                R,
                t,
                i,
                np.float64(pts[j, 0]),
                np.float64(pts[j, 1]),
                np.float64(pts[j, 2]),
            )
            acc += scale * _morton_d2(
                wx, wy, wz, points, cell_codes, cell_start, quantum, cell_level, r2
            )
        _block_sum(s, tid, acc)
        if tid == 0:
            partial[i, k] = s[0]

    return score_voxel_tiles, score_morton_tiles


# ------------------------------------------------------------------------------------------- host functions
def _particles(R, t):
    if is_device_array(R):
        if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
            raise ValueError(
                f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}"
            )
        return R, t, True
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    if R.ndim != 3 or R.shape[1:] != (3, 3) or t.shape != (R.shape[0], 3):
        raise ValueError(
            f"particles need R (P, 3, 3) and t (P, 3), got {R.shape} and {t.shape}"
        )
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
        bits, step, seed = (
            np.int64(noise.tables.bits),
            np.int64(noise.step),
            np.int64(noise.seed),
        )
        noise_d = to_device(np.zeros((1, N_COMPONENTS)))
    else:
        use_lut = False
        if not is_device_array(noise):
            noise = np.ascontiguousarray(noise, dtype=np.float64)
        if noise.shape != (P, N_COMPONENTS):
            raise ValueError(
                f"noise must have shape (P, 6) = ({P}, 6), got {noise.shape}"
            )
        noise_d = to_device(noise)
        normal, perm = (
            to_device(np.zeros(1, np.float32)),
            to_device(np.zeros((N_COMPONENTS, 1), np.int32)),
        )
        bits = step = seed = np.int64(0)
    R_new = cuda.device_array((P, 3, 3), np.float64)
    t_new = cuda.device_array((P, 3), np.float64)
    if P:
        grid = _blocks(P, threads)
        _rotation_kernel[grid, threads](
            R_d, dR, sig, noise_d, use_lut, normal, perm, bits, step, seed, R_new
        )
        _translation_kernel[grid, threads](
            R_d,
            t_d,
            dR,
            trans,
            sig,
            noise_d,
            use_lut,
            normal,
            perm,
            bits,
            step,
            seed,
            t_new,
        )
    if on_device:
        return R_new, t_new
    return R_new.copy_to_host(), t_new.copy_to_host()


def lut_normal_device(noise: LutNoise, n: int, threads: int = THREADS):
    """The (n, 6) float32 LUT draws of :class:`~slamlib.noise.LutNoise` generated on the device (device array)."""
    check_available()
    out = cuda.device_array((n, N_COMPONENTS), np.float32)
    if n:
        _lut_fill_kernel[_blocks(n, threads), threads](
            to_device(noise.tables.normal),
            to_device(noise.tables.perm),
            np.int64(noise.tables.bits),
            np.int64(noise.step),
            np.int64(noise.seed),
            out,
        )
    return out


def transform_points(
    T, points, out=None, threads: int = THREADS, max_blocks: int = MAX_BLOCKS
):
    """``p' = R p + t`` for ``T`` (4, 4) and ``points`` (N, 3) float32 -> (N, 3) float32 (float32 arithmetic).

    One thread per point in a grid-stride loop of at most ``max_blocks`` blocks. Returns a device array when
    ``points`` is one. ``out`` (N, 3) float32, a device or host array, receives the result and is returned
    (``out=points`` on the device: in place; each thread reads its point before writing it).
    """
    check_available()
    T = np.asarray(T, dtype=np.float64)
    on_device = is_device_array(points)
    pts = points if on_device else np.ascontiguousarray(points, dtype=np.float32)
    if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(
            f"need T (4, 4) and points (N, 3), got {T.shape} and {pts.shape}"
        )
    pts_d = to_device(pts)
    if out is not None and (
        out.shape != pts_d.shape or np.dtype(out.dtype) != np.float32
    ):
        raise ValueError(
            f"out must be a float32 array of shape {pts_d.shape}, got {out.dtype} {out.shape}"
        )
    res = (
        out
        if out is not None and is_device_array(out)
        else cuda.device_array(pts_d.shape, np.float32)
    )
    if pts_d.shape[0]:
        # the pose as a batch of one
        _transform_kernel[_blocks(pts_d.shape[0], threads, max_blocks), threads](
            to_device(np.ascontiguousarray(T[None, :3, :3], dtype=np.float32)),
            to_device(np.ascontiguousarray(T[None, :3, 3], dtype=np.float32)),
            pts_d,
            res,
        )
    if out is not None:
        if not is_device_array(out):
            res.copy_to_host(out)
        return out
    return res if on_device else res.copy_to_host()


def score_particles(
    R,
    t,
    points,
    lookup,
    threads: int = SCORE_THREADS,
    layout: str = "block",
    tile_points: int = TILE_POINTS,
):
    """Fused transform + map lookup log-likelihood (P,) float64, one block of ``threads`` per particle.

    ``layout="tiles"``: blocks over particles x tiles of ``tile_points`` points, partial sums added by a second
    kernel (more blocks for few particles; see the module's docstring). Same values up to summation order.

    ``lookup`` is a :class:`~slamlib.maps.base.VoxelHashLookup` or :class:`~slamlib.maps.base.MortonLookup`
    (numpy fields, or device fields from :func:`lookup_to_device`). A map's numpy lookup is uploaded once per map
    version (:func:`lookup_to_device` keeps the device copy), not once per call. Returns a device array when
    ``R`` is one.
    """
    check_available()
    R_d, t_d, on_device = _particles(R, t)
    pts = (
        points
        if is_device_array(points)
        else np.ascontiguousarray(points, dtype=np.float32)
    )
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (N, 3), got {pts.shape}")
    if layout not in SCORE_LAYOUTS:
        raise ValueError(f"layout must be one of {SCORE_LAYOUTS}, got {layout!r}")
    if int(tile_points) < 1:
        raise ValueError(f"tile_points must be >= 1, got {tile_points}")
    pts_d = to_device(pts)
    P = R_d.shape[0]
    out = cuda.device_array(P, np.float64)
    score_voxel, score_morton, _ = _block_kernels(int(threads))
    if layout == "tiles":
        n_tiles = max(1, -(-pts_d.shape[0] // int(tile_points)))
        partial = cuda.device_array((P, n_tiles), np.float64)
        voxel_tiles, morton_tiles = _tile_kernels(int(threads))
        score_voxel = _TileLaunch(voxel_tiles, n_tiles, int(tile_points), partial, out)
        score_morton = _TileLaunch(morton_tiles, n_tiles, int(tile_points), partial, out)
    lk = lookup_to_device(lookup)  # uploads the map only when its version changed
    if lk.kind == KIND_VOXEL_HASH:
        if P:
            score_voxel[P, threads](
                R_d,
                t_d,
                pts_d,
                lk.keys,
                lk.mean,
                lk.icov,
                float(lk.inv_voxel_size),
                np.int64(lk.log2_capacity),
                np.int64(lk.max_probe),
                float(lk.m_max),
                out,
            )
    elif lk.kind == KIND_MORTON:
        scale = -0.5 / float(lk.sigma) ** 2
        r2 = float(lk.radius) ** 2
        # empty map: every point costs the truncation
        if P and lk.cell_codes.shape[0] == 0:
            vals = np.full(P, scale * r2 * pts_d.shape[0])
            return to_device(vals) if on_device else vals
        if P:
            score_morton[P, threads](
                R_d,
                t_d,
                pts_d,
                lk.points,
                lk.cell_codes,
                lk.cell_start,
                float(lk.quantum),
                np.int64(lk.cell_level),
                r2,
                scale,
                out,
            )
    else:
        raise ValueError(f"unknown lookup kind {lookup.kind!r}")
    return out if on_device else out.copy_to_host()


class _TileLaunch:
    """``launch[P, threads](*args, out)`` of a per-particle scoring kernel, done by the tiled layout instead:
    ``tile_kernel[(P, n_tiles), threads](*args, tile, partial)``, then the row sums of ``partial`` into ``out``."""

    def __init__(self, tile_kernel, n_tiles, tile, partial, out):
        self.kernel, self.n_tiles, self.tile, self.partial, self.out = (
            tile_kernel,
            n_tiles,
            tile,
            partial,
            out,
        )

    def __getitem__(self, config):
        P, threads = config

        def launch(*args):
            self.kernel[(P, self.n_tiles), threads](
                *args[:-1], np.int64(self.tile), self.partial
            )
            _sum_tiles_kernel[_blocks(P, THREADS), THREADS](self.partial, self.out)

        return launch


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
        weights = w
    c = inclusive_scan(weights, threads)
    P = c.shape[0]
    out = cuda.device_array(P, np.int64)
    _search_kernel[_blocks(P, threads), threads](c, float(u0), out)
    return out if on_device else out.copy_to_host()
