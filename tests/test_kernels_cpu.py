"""The Numba CPU backend against the numpy reference, and the reference against the definitions."""

import re

import numba
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamlib import geometry
from slamlib.errors import BackendUnavailableError
from slamlib.kernels import Backend, cpu, get_backend, reference
from slamlib.maps import MortonBVHMap, VoxelHashMap

REF = get_backend("numpy")
CPU = get_backend("cpu")


def _particles(rng, P, spread=0.3):
    R = geometry.rpy_to_matrix(rng.uniform(-np.pi, np.pi, (P, 3)) * spread)
    t = rng.normal(0.0, 3.0, (P, 3))
    return R, t


def test_get_backend_names():
    for name in ("numpy", "cpu"):
        b = get_backend(name)
        assert isinstance(b, Backend) and b.name == name
        assert callable(b.score_particles) and callable(b.systematic_resample)
    with pytest.raises(ValueError, match="unknown backend"):
        get_backend("opencl")


def test_get_backend_cuda_is_a_backend_or_a_clear_error():
    try:
        b = get_backend("cuda")
    except BackendUnavailableError as exc:
        assert "numba-cuda" in str(exc) or "cpu" in str(exc)
    else:
        assert b.name == "cuda"


finite = st.floats(-3.0, 3.0, allow_nan=False)


@settings(max_examples=25, deadline=None)
@given(
    st.integers(1, 40),
    st.tuples(finite, finite, finite),
    st.tuples(finite, finite, finite),
    st.integers(0, 2**32 - 1),
)
def test_move_particles_cpu_equals_reference(P, rpy_delta, trans_delta, seed):
    rng = np.random.default_rng(seed)
    R, t = _particles(rng, P)
    noise = rng.standard_normal((P, 6))
    sigma = rng.uniform(0.0, 0.2, 6)
    R_ref, t_ref = REF.move_particles(R, t, rpy_delta, trans_delta, noise, sigma)
    R_cpu, t_cpu = CPU.move_particles(R, t, rpy_delta, trans_delta, noise, sigma)
    np.testing.assert_allclose(R_cpu, R_ref, atol=1e-12)
    np.testing.assert_allclose(t_cpu, t_ref, atol=1e-10)
    # rotations stay rotations
    np.testing.assert_allclose(
        np.einsum("pji,pjk->pik", R_cpu, R_cpu),
        np.broadcast_to(np.eye(3), R.shape),
        atol=1e-10,
    )


def test_move_particles_is_step5_then_step6():
    """The CONTRIBUTING.md formula as 4x4 products: step 5 rotates by dR and then moves by trans_delta in the
    rotated body frame, ``T_i <- T_i [dR, 0] [I, trans_delta]``; step 6 is ``T_i <- T_i [N_i, sigma_t n_i]``.

    (Note ``[dR, 0] [I, d] = [dR, dR d]``: the formula's ``t_i + R_i dR trans_delta`` is not ``T_i [dR, d]``,
    whose translation is ``t_i + R_i d``.)"""
    rng = np.random.default_rng(11)
    P = 7
    R, t = _particles(rng, P)
    rpy_delta, trans_delta = np.array([0.01, -0.03, 0.2]), np.array([1.2, 0.1, -0.05])
    noise, sigma = (
        rng.standard_normal((P, 6)),
        np.array([0.1, 0.05, 0.02, 0.01, 0.02, 0.03]),
    )
    dR = geometry.rpy_to_matrix(rpy_delta)
    for backend in (REF, CPU):
        R_new, t_new = backend.move_particles(R, t, rpy_delta, trans_delta, noise, sigma)
        for i in range(P):
            T = geometry.make_pose(R[i], t[i])
            # step 5
            T = (
                T
                @ geometry.make_pose(dR, np.zeros(3))
                @ geometry.make_pose(np.eye(3), trans_delta)
            )
            # step 6
            T = T @ geometry.make_pose(
                geometry.rpy_to_matrix(sigma[3:] * noise[i, 3:]), sigma[:3] * noise[i, :3]
            )
            np.testing.assert_allclose(
                geometry.make_pose(R_new[i], t_new[i]), T, atol=1e-12
            )
            # and the formula written out
            N_i = geometry.rpy_to_matrix(sigma[3:] * noise[i, 3:])
            np.testing.assert_allclose(R_new[i], R[i] @ dR @ N_i, atol=1e-12)
            np.testing.assert_allclose(
                t_new[i],
                t[i] + R[i] @ dR @ (trans_delta + sigma[:3] * noise[i, :3]),
                atol=1e-12,
            )


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 3000), st.integers(0, 2**32 - 1))
def test_transform_points_cpu_equals_reference_and_geometry(N, seed):
    rng = np.random.default_rng(seed)
    T = geometry.make_pose(
        geometry.rpy_to_matrix(rng.uniform(-3, 3, 3)), rng.normal(0, 50, 3)
    )
    pts = rng.normal(0.0, 30.0, (N, 3)).astype(np.float32)
    out_cpu, out_ref = CPU.transform_points(T, pts), REF.transform_points(T, pts)
    assert out_cpu.dtype == np.float32 and out_cpu.shape == (N, 3)
    exact = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(out_ref, exact, atol=1e-4, rtol=1e-5)
    np.testing.assert_allclose(out_cpu, out_ref, atol=1e-4, rtol=1e-5)


@pytest.mark.parametrize(
    "N", [0, 1, 5, 16385, 40000]
)  # around and across TRANSFORM_CHUNK spans
def test_transform_points_out_and_in_place_equal_the_allocating_call(N):
    from slamlib.kernels import cpu

    rng = np.random.default_rng(N)
    T = geometry.make_pose(
        geometry.rpy_to_matrix(rng.uniform(-3, 3, 3)), rng.normal(0, 50, 3)
    )
    pts = rng.normal(0.0, 30.0, (N, 3)).astype(np.float32)
    keep = pts.copy()
    fresh = CPU.transform_points(T, pts)
    np.testing.assert_allclose(fresh, REF.transform_points(T, pts), atol=1e-4, rtol=1e-5)
    out = np.full_like(pts, np.nan)
    assert CPU.transform_points(T, pts, out=out) is out
    # the input is untouched
    assert np.array_equal(out, fresh) and np.array_equal(pts, keep)
    work = pts.copy()
    assert CPU.transform_points(T, work, out=work) is work
    assert np.array_equal(work, fresh)
    ref_out = np.empty_like(pts)
    assert REF.transform_points(T, pts, out=ref_out) is ref_out
    assert np.array_equal(ref_out, REF.transform_points(T, pts))
    if N > cpu.TRANSFORM_CHUNK:  # every span written, including the last partial one
        assert np.isfinite(out).all()


def _float_slices(n):
    """``(raw, [(offset, out)])``: NaN-filled float32 ``raw`` and (n, 3) views into it starting at each of the 16
    float offsets from a 64-byte line boundary, so every output alignment a float32 array can have is covered."""
    raw = np.full(3 * n + 64, np.nan, np.float32)
    base = (-(raw.__array_interface__["data"][0] // 4)) % 16
    return raw, [
        (base + o, raw[base + o : base + o + 3 * n].reshape(n, 3)) for o in range(16)
    ]


@pytest.mark.parametrize("N", [0, 1, 15, 16, 17, 40, 333])
def test_streaming_transform_equals_the_plain_kernel_at_every_alignment(N):
    """The non-temporal kernel (head and tail plain, whole lines between) writes exactly the plain kernel's
    floats, at all 16 output alignments, with small task sizes so that many tasks and partial groups occur,
    and nothing outside ``out``."""
    from slamlib.kernels import cpu

    rng = np.random.default_rng(N)
    T = geometry.make_pose(
        geometry.rpy_to_matrix(rng.uniform(-3, 3, 3)), rng.normal(0, 50, 3)
    )
    R32, t32 = T[None, :3, :3].astype(np.float32), T[None, :3, 3].astype(np.float32)
    pts = rng.normal(0.0, 30.0, (N, 3)).astype(np.float32)
    want = np.empty_like(pts)
    cpu._transform_nb(R32, t32, pts.reshape(-1), want.reshape(-1), 7)
    raw, outs = _float_slices(N)
    for start, out in outs:
        raw[:] = np.nan
        head = cpu._stream_head(out)
        assert (out.__array_interface__["data"][0] + 12 * head) % 64 == 0
        for chunk in (1, 2, 1000):
            cpu._transform_stream_nb(
                R32, t32, pts.reshape(-1), out.reshape(-1), head, chunk
            )
            assert np.array_equal(out, want), (start, chunk)
        outside = np.r_[raw[:start], raw[start + 3 * N :]]
        assert np.isnan(outside).all()


def test_transform_points_streams_large_outputs_with_the_plain_results(monkeypatch):
    """Above ``STREAM_MIN_POINTS`` ``out=`` goes through the streaming kernel (its threshold lowered here, and
    once at its real size): the same floats as the plain kernel, at every alignment; a fresh output and in
    place do not stream."""
    from slamlib.kernels import cpu

    rng = np.random.default_rng(7)
    T = geometry.make_pose(
        geometry.rpy_to_matrix(rng.uniform(-3, 3, 3)), rng.normal(0, 50, 3)
    )
    pts = rng.normal(0.0, 30.0, (3000, 3)).astype(np.float32)
    want = CPU.transform_points(T, pts)
    calls = []
    real = cpu._transform_stream_nb
    monkeypatch.setattr(
        cpu, "_transform_stream_nb", lambda *a: (calls.append(a[4]), real(*a))
    )
    monkeypatch.setattr(cpu, "STREAM_MIN_POINTS", 1000)
    for _, out in _float_slices(len(pts))[1]:
        assert CPU.transform_points(T, pts, out=out) is out and np.array_equal(out, want)
    # every head length taken
    assert len(calls) == 16 and sorted(set(calls)) == list(range(16))
    # a fresh output: plain stores
    assert np.array_equal(CPU.transform_points(T, pts), want) and len(calls) == 16
    monkeypatch.undo()
    big = rng.normal(0.0, 30.0, (cpu.STREAM_MIN_POINTS + 5, 3)).astype(np.float32)
    plain = np.empty_like(big)
    cpu._transform_nb(
        T[None, :3, :3].astype(np.float32),
        T[None, :3, 3].astype(np.float32),
        big.reshape(-1),
        plain.reshape(-1),
        cpu.TRANSFORM_CHUNK,
    )
    assert np.array_equal(CPU.transform_points(T, big), plain)
    assert np.array_equal(CPU.transform_points(T, big, out=big), plain)


@pytest.mark.skipif(
    __import__("platform").machine() not in ("x86_64", "AMD64"), reason="x86-64 mnemonics"
)
@pytest.mark.skipif(
    numba.config.DISABLE_JIT,
    reason="reads compiled machine code (make mutate runs the kernels as Python)",
)
def test_streaming_kernels_carry_their_memory_hints():
    """The hints survive compilation: non-temporal stores and a fence in the streaming kernel, prefetches in
    it and in the in-place kernel (LLVM would drop ``!nontemporal`` silently, e.g. on a misaligned store)."""
    import re

    from numba import njit

    from slamlib.kernels import cpu

    x, y = np.zeros(300, np.float32), np.zeros(300, np.float32)
    R, t = np.eye(3, dtype=np.float32)[None], np.zeros((1, 3), np.float32)
    asm = {}
    # a wrong head would fault: non-temporal vector stores need aligned lines
    head = cpu._stream_head(y)
    for name, args in (
        ("_transform_stream_nb", (R, t, x, y, head, 1)),
        ("_transform_inplace_nb", (R, t, x, 1)),
    ):
        # compiled afresh: Numba returns no code for a kernel loaded from its on-disk cache
        fresh = njit(parallel=True, fastmath={"contract"})(getattr(cpu, name).py_func)
        fresh(*args)
        asm[name] = "\n".join(fresh.inspect_asm().values())
    assert re.search(r"\bv?movntp[sd]\b", asm["_transform_stream_nb"])
    assert re.search(r"\bsfence\b", asm["_transform_stream_nb"])
    assert all(re.search(r"\bprefetcht0\b", a) for a in asm.values())


def test_memory_hints_as_python_mean_what_the_compiled_hints_do():
    """Each hint's Python meaning (used with the JIT disabled) and its compiled form give the same array."""
    from numba import njit

    from slamlib.kernels import memory_hints as mh

    @njit
    def line_and_fence(dst, i, src, j):
        mh.prefetch(src, j)
        mh.stream_line(dst, i, src, j)
        mh.store_fence()

    src = np.arange(40, dtype=np.float32)
    raw, outs = _float_slices(16)
    start, dst = outs[0]
    a, b = dst.reshape(-1).copy(), dst.reshape(-1)
    mh.prefetch(src, 3)
    mh.stream_line(a, 0, src, 5)
    mh.store_fence()
    line_and_fence(b, np.uint64(0), src, np.uint64(5))
    assert (
        np.array_equal(a[:16], src[5:21])
        and np.array_equal(b[:16], a[:16])
        and np.isnan(b[16:]).all()
    )


def test_transform_points_out_is_checked():
    pts = np.ones((10, 3), np.float32)
    with pytest.raises(ValueError, match="out"):
        CPU.transform_points(np.eye(4), pts, out=np.empty((10, 3), np.float64))
    with pytest.raises(ValueError, match="out"):
        CPU.transform_points(np.eye(4), pts, out=np.empty((9, 3), np.float32))
    with pytest.raises(ValueError, match="overlaps"):
        big = np.ones((11, 3), np.float32)
        CPU.transform_points(np.eye(4), big[:10], out=big[1:])


@pytest.mark.parametrize(
    "P, bits", [(1, 4), (13, 4), (16, 4), (17, 4), (3000, 4), (3000, 12)]
)
def test_move_particles_with_lut_noise_is_the_same_math(P, bits):
    """LUT noise drawn inside the kernel == the same draws passed as an array (bit for bit, both with and without
    the per-call cos/sin tables: P above / below the table size 2**bits) == the reference; in place too."""
    from slamlib.noise import LutNoise, make_tables

    rng = np.random.default_rng(P + bits)
    R, t = _particles(rng, P)
    sigma = rng.uniform(0.0, 0.3, 6)
    lut = LutNoise(make_tables(5, bits=bits), 9, 21)
    args = ([0.02, -0.01, 0.3], [1.1, 0.2, -0.1])
    R_f, t_f = CPU.move_particles(R, t, *args, lut, sigma)
    R_a, t_a = CPU.move_particles(R, t, *args, lut.draw(P), sigma)
    assert np.array_equal(R_f, R_a) and np.array_equal(t_f, t_a)
    R_r, t_r = REF.move_particles(R, t, *args, lut, sigma)
    np.testing.assert_allclose(R_f, R_r, atol=1e-12)
    np.testing.assert_allclose(t_f, t_r, atol=1e-10)
    assert not np.allclose(
        R_f, CPU.move_particles(R, t, *args, LutNoise(lut.tables, 10, 21), sigma)[0]
    )
    R_i, t_i = R.copy(), t.copy()
    res = CPU.move_particles(R_i, t_i, *args, lut, sigma, out=(R_i, t_i))
    assert res[0] is R_i and res[1] is t_i
    assert np.array_equal(R_i, R_f) and np.array_equal(t_i, t_f)
    R_j, t_j = R.copy(), t.copy()
    CPU.move_particles(R_j, t_j, *args, lut.draw(P), sigma, out=(R_j, t_j))
    assert np.array_equal(R_j, R_a) and np.array_equal(t_j, t_a)
    R_o, t_o = np.empty_like(R), np.empty_like(t)
    REF.move_particles(R, t, *args, lut, sigma, out=(R_o, t_o))
    assert np.array_equal(R_o, R_r) and np.array_equal(t_o, t_r)


@pytest.mark.parametrize("P, bits", [(1, 4), (17, 4), (3000, 4), (3000, 12)])
def test_move_particles_soa_is_the_same_math_in_the_other_layout(P, bits):
    """Component-major particles (R (3, 3, P), t (3, P)) move exactly as particle-major ones (float64: bit for
    bit, LUT noise with and without the cos/sin tables and drawn noise (6, P)); float32 stays float32 and agrees
    to float32 rounding; in place and out= as for move_particles."""
    from slamlib.kernels.cpu import move_particles_soa
    from slamlib.noise import LutNoise, make_tables

    rng = np.random.default_rng(P + 7 * bits)
    R, t = _particles(rng, P)
    sigma = rng.uniform(0.0, 0.3, 6)
    lut = LutNoise(make_tables(3, bits=bits), 4, 11)
    args = ([0.02, -0.01, 0.3], [1.1, 0.2, -0.1])
    Rs, ts = np.ascontiguousarray(R.transpose(1, 2, 0)), np.ascontiguousarray(t.T)
    noise = rng.standard_normal((P, 6))
    for nz_aos, nz_soa in ((lut, lut), (noise, np.ascontiguousarray(noise.T))):
        R_a, t_a = CPU.move_particles(R, t, *args, nz_aos, sigma)
        R_s, t_s = move_particles_soa(Rs, ts, *args, nz_soa, sigma)
        assert R_s.shape == (3, 3, P) and t_s.shape == (3, P) and R_s.dtype == np.float64
        assert np.array_equal(R_s.transpose(2, 0, 1), R_a) and np.array_equal(t_s.T, t_a)
        R_f, t_f = move_particles_soa(
            Rs.astype(np.float32), ts.astype(np.float32), *args, nz_soa, sigma
        )
        assert R_f.dtype == np.float32 and t_f.dtype == np.float32
        np.testing.assert_allclose(R_f.transpose(2, 0, 1), R_a, atol=3e-6)
        np.testing.assert_allclose(t_f.T, t_a, atol=3e-6 * (1 + np.abs(t_a).max()))
        R_i, t_i = Rs.copy(), ts.copy()
        res = move_particles_soa(R_i, t_i, *args, nz_soa, sigma, out=(R_i, t_i))
        assert (
            res[0] is R_i
            and res[1] is t_i
            and np.array_equal(R_i, R_s)
            and np.array_equal(t_i, t_s)
        )
    with pytest.raises(ValueError, match=r"R \(3, 3, P\) and t \(3, P\)"):
        move_particles_soa(R, t, *args, lut, sigma)
    with pytest.raises(ValueError, match=r"noise must have shape \(6, P\)"):
        # (P, 6): the particle-major noise
        move_particles_soa(Rs, ts, *args, noise, sigma)


def test_move_particles_soa_keeps_float64_for_mixed_or_other_types():
    from slamlib.kernels.cpu import move_particles_soa
    from slamlib.noise import LutNoise, make_tables

    Rs = np.repeat(np.eye(3)[:, :, None], 5, axis=2)
    lut = LutNoise(make_tables(0, bits=4), 0, 0)
    for R, t in (
        (Rs.astype(np.float32), np.zeros((3, 5))),
        (Rs, np.zeros((3, 5), np.float32)),
        (Rs.astype(np.float16), np.zeros((3, 5), np.float16)),
    ):
        R_new, t_new = move_particles_soa(
            R, t, [0, 0, 0.1], [1, 0, 0], lut, np.full(6, 0.01)
        )
        assert R_new.dtype == np.float64 and t_new.dtype == np.float64
        np.testing.assert_allclose(t_new[0], 1.0, atol=0.1)


def test_row_primitives_are_the_3x3_products():
    """device.row_times / row_step / rpy_rotation_cs (the motion update kept in registers) are row r M,
    t + A s and the ZYX matrix; the Python and njit builds agree bit for bit."""
    from slamlib.kernels import cpu
    from slamlib.kernels.device import PY

    rng = np.random.default_rng(3)
    for _ in range(20):
        r, M = rng.normal(size=3), rng.normal(size=(3, 3))
        got = [f["row_times"](*r, *M.ravel()) for f in (PY, cpu._F)]
        assert got[0] == got[1]
        np.testing.assert_allclose(got[0], r @ M, rtol=1e-14, atol=1e-14)
        a, s, t0 = rng.normal(size=3), rng.normal(size=3), rng.normal()
        step = [f["row_step"](t0, *a, *s) for f in (PY, cpu._F)]
        assert step[0] == step[1] and step[0] == pytest.approx(
            t0 + a @ s, rel=1e-14, abs=1e-14
        )
        ang = rng.uniform(-np.pi, np.pi, 3)
        cs = [v for x in ang for v in (np.cos(x), np.sin(x))]
        n = [f["rpy_rotation_cs"](*cs) for f in (PY, cpu._F)]
        assert n[0] == n[1]
        np.testing.assert_allclose(
            np.reshape(n[0], (3, 3)), geometry.rpy_to_matrix(ang), atol=1e-15
        )


def test_transform_points_rejects_bad_shapes():
    with pytest.raises(ValueError):
        CPU.transform_points(np.eye(3), np.zeros((4, 3), np.float32))
    with pytest.raises(ValueError):
        CPU.transform_points(np.eye(4), np.zeros((4, 2), np.float32))


def _box_world(rng, n=6000):
    """Points on the faces of a few random boxes plus clutter, around (0, 0, 0), metres."""
    out = []
    for _ in range(4):
        c, size = rng.uniform(-4, 4, 3), rng.uniform(0.5, 3.0, 3)
        p = rng.uniform(-0.5, 0.5, (n // 4, 3))
        ax = rng.integers(0, 3, n // 4)
        p[np.arange(n // 4), ax] = np.sign(p[np.arange(n // 4), ax]) * 0.5
        out.append(c + p * size)
    return np.vstack(out + [rng.uniform(-6, 6, (n // 10, 3))]).astype(np.float32)


def _maps(rng):
    world = _box_world(rng)
    maps = [
        VoxelHashMap(voxel_size=0.4, capacity=2**14),
        MortonBVHMap(radius=0.3, dedup_level=2),
        MortonBVHMap(radius=1.0, sigma=0.3, quantum=0.02, dedup_level=0),
    ]
    for m in maps:
        m.merge(world)
    return maps


@settings(max_examples=10, deadline=None)
@given(st.integers(1, 30), st.integers(1, 700), st.integers(0, 2**32 - 1))
def test_score_particles_cpu_equals_reference(P, N, seed):
    rng = np.random.default_rng(seed)
    maps = _maps(rng)
    R, t = _particles(rng, P, spread=0.1)
    t *= 0.1
    # many near surfaces, some outside the map
    pts = rng.uniform(-7, 7, (N, 3)).astype(np.float32)
    for m in maps:
        lk = m.lookup()
        ref = REF.score_particles(R, t, pts, lk)
        cpu = CPU.score_particles(R, t, pts, lk)
        assert cpu.shape == (P,) and cpu.dtype == np.float64
        np.testing.assert_allclose(cpu, ref, rtol=1e-9, atol=1e-6)


def test_score_particles_empty_map_and_far_points():
    rng = np.random.default_rng(5)
    R, t = _particles(rng, 4)
    pts = rng.normal(0, 5, (50, 3)).astype(np.float32)
    for m in (VoxelHashMap(capacity=64, m_max=9.0), MortonBVHMap(radius=0.5, sigma=0.25)):
        floor = -0.5 * 9.0 if isinstance(m, VoxelHashMap) else -0.5 * 0.5**2 / 0.25**2
        for backend in (REF, CPU):
            np.testing.assert_allclose(
                backend.score_particles(R, t, pts, m.lookup()), 50 * floor
            )
        m.merge(pts)  # now the identity pose hits every point exactly
        I, z = np.eye(3)[None], np.zeros((1, 3))
        for backend in (REF, CPU):
            s = backend.score_particles(I, z, pts, m.lookup())
            assert s[0] > 50 * floor
            far = backend.score_particles(I, z + 1e4, pts, m.lookup())
            np.testing.assert_allclose(far, 50 * floor)


def test_score_particles_is_exact_nearest_neighbour_for_morton():
    """Morton score = -0.5 min(d_nn, r)^2 / sigma^2 by brute force, for single points."""
    rng = np.random.default_rng(6)
    world = rng.uniform(-2, 2, (3000, 3)).astype(np.float32)
    m = MortonBVHMap(radius=0.4, sigma=0.2, dedup_level=0)
    m.merge(world)
    stored = m.points().astype(np.float64)
    queries = rng.uniform(-2.5, 2.5, (200, 3))
    I = np.eye(3)[None]
    for q in queries:
        d = np.sqrt(np.min(np.sum((stored - q) ** 2, axis=1)))
        want = -0.5 * min(d, 0.4) ** 2 / 0.2**2
        got = CPU.score_particles(I, q[None], np.zeros((1, 3), np.float32), m.lookup())[0]
        np.testing.assert_allclose(got, want, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(
    st.lists(st.floats(0.0, 10.0, allow_nan=False), min_size=1, max_size=300),
    st.floats(0.0, 0.999999),
)
def test_systematic_resample_cpu_equals_reference(w, u0):
    w = np.asarray(w)
    if not w.sum() > 0:
        w = w + 1.0
    ref = REF.systematic_resample(w, u0)
    cpu = CPU.systematic_resample(w, u0)
    np.testing.assert_array_equal(cpu, ref)
    assert cpu.dtype == np.int64
    assert np.all(np.diff(cpu) >= 0)
    assert np.all(w[cpu] > 0)  # zero-weight particles are never drawn
    counts = np.bincount(cpu, minlength=len(w))
    expected = len(w) * w / w.sum()
    assert np.all(counts >= np.floor(expected - 1e-9)) and np.all(
        counts <= np.ceil(expected + 1e-9)
    )


def test_systematic_resample_by_definition():
    """index i is the first j with (u0 + i) / P < cumsum(w)[j]: the filterpy loop, written out."""
    w = np.array([0.1, 0.0, 0.5, 0.15, 0.25])
    u0 = 0.3
    c = np.cumsum(w)
    want, j = [], 0
    for i in range(5):
        while (u0 + i) / 5 >= c[j]:
            j += 1
        want.append(j)
    np.testing.assert_array_equal(CPU.systematic_resample(w, u0), want)
    # scale does not matter
    np.testing.assert_array_equal(REF.systematic_resample(w * 7.0, u0), want)


def test_systematic_resample_matches_slamlib_resampling_when_present():
    resampling = pytest.importorskip("slamlib.resampling")
    fn = getattr(resampling, "systematic_resample", None)
    if fn is None:
        pytest.skip("slamlib.resampling has no systematic_resample")
    rng = np.random.default_rng(9)
    w = rng.random(200)
    w /= w.sum()
    try:
        theirs = fn(w, 0.37)
    except TypeError:
        pytest.skip("slamlib.resampling.systematic_resample takes another signature")
    np.testing.assert_array_equal(CPU.systematic_resample(w, 0.37), np.asarray(theirs))


@pytest.mark.parametrize("backend", [REF, CPU], ids=["numpy", "cpu"])
def test_systematic_resample_rejects_bad_weights(backend):
    for w in ([], [0.0, 0.0], [1.0, -0.5], [np.nan, 1.0]):
        with pytest.raises(ValueError):
            backend.systematic_resample(np.asarray(w, float), 0.5)
    with pytest.raises(ValueError):
        backend.systematic_resample(np.ones(3), 1.0)


def test_voxel_scores_are_the_sum_of_voxel_term_bit_for_bit():
    """The CPU voxel kernel looks each block's 8 corner slots up once for consecutive particles in it: the scores are
    still the plain sum of device.voxel_term, bit for bit (per chunk of POINT_CHUNK points in order, then the
    chunks in order), for particles spread over many blocks, a NaN point, one far outside and a point whose block
    starts below the key range (index -1)."""
    from slamlib.kernels import cpu
    from slamlib.kernels.device import PY

    rng = np.random.default_rng(8)
    vmap = _maps(rng)[0]
    lk = vmap.lookup()
    R, t = _particles(rng, 70, spread=0.05)
    t = t * 0.2
    pts = np.vstack([rng.uniform(-6, 6, (150, 3)), [[np.nan, 0, 0], [1e9, 0, 0]]]).astype(
        np.float32
    )
    far = VoxelHashMap(voxel_size=0.001, capacity=16, min_sigma=0.001)
    corner = np.float32(-(2**20) * 0.001 + 0.0004)
    far.merge(
        np.array(
            [[corner, corner, corner], [corner + 0.0001, corner, corner]], np.float32
        )
    )
    cases = [
        (R, t, pts, lk),
        (
            np.eye(3)[None].repeat(3, 0),
            np.zeros((3, 3)) + [[0, 0, 0], [2e-4, 0, 0], [0, 1e-4, 0]],
            np.array([[corner, corner, corner]], np.float32),
            far.lookup(),
        ),
    ]
    for R_, t_, p_, lk_ in cases:
        got = CPU.score_particles(R_, t_, p_, lk_)
        for i in range(len(R_)):
            total = 0.0
            for c in range(0, len(p_), cpu.POINT_CHUNK):
                acc = 0.0
                for x, y, z in p_[c : c + cpu.POINT_CHUNK].astype(np.float64):
                    wx, wy, wz = PY["world_point"](R_, t_, i, x, y, z)
                    acc += PY["voxel_term"](
                        wx,
                        wy,
                        wz,
                        lk_.keys,
                        lk_.mean,
                        lk_.icov,
                        lk_.inv_voxel_size,
                        lk_.log2_capacity,
                        lk_.max_probe,
                        lk_.m_max,
                    )
                total += acc
            assert got[i] == total, (i, got[i], total)


def test_shared_point_math_python_and_numba_builds_agree_bit_for_bit():
    """slamlib.kernels.device is one source compiled per target: its plain-Python build (the specification; the
    CUDA simulator runs the same code) and the njit build inside the CPU backend give identical bits."""
    from slamlib.kernels import cpu
    from slamlib.kernels.device import PY

    NB = cpu._F
    rng = np.random.default_rng(21)
    vmap, mmap = _maps(rng)[:2]
    vl, ml = vmap.lookup(), mmap.lookup()
    pts = np.vstack(
        [
            rng.uniform(-7, 7, (150, 3)),
            [[np.nan, 0.0, 0.0], [1e9, 0.0, 0.0], [0.0, -1e7, 3.0]],
        ]
    )
    r2 = ml.radius**2
    brute = mmap.points().astype(np.float64)
    for wx, wy, wz in pts:
        v = [
            f["voxel_term"](
                wx,
                wy,
                wz,
                vl.keys,
                vl.mean,
                vl.icov,
                vl.inv_voxel_size,
                vl.log2_capacity,
                vl.max_probe,
                vl.m_max,
            )
            for f in (PY, NB)
        ]
        assert v[0] == v[1]
        d = [
            f["morton_d2"](
                wx,
                wy,
                wz,
                ml.points,
                ml.cell_codes,
                ml.cell_start,
                ml.quantum,
                ml.cell_level,
                r2,
            )
            for f in (PY, NB)
        ]
        assert d[0] == d[1]
        if np.isfinite(
            wx
        ):  # the documented query is the exact truncated nearest neighbour
            want = min(np.min(np.sum((brute - [wx, wy, wz]) ** 2, axis=1)), r2)
            np.testing.assert_allclose(d[0], want, rtol=1e-12)
        c = [f["cell_block"](wx, wy, wz, ml.quantum, ml.cell_level) for f in (PY, NB)]
        assert c[0][3:] == c[1][3:] and (not c[0][6] or c[0][:3] == c[1][:3])
    R, t = _particles(rng, 3)
    for i in range(3):
        for x, y, z in pts[:20]:
            assert PY["world_point"](R, t, i, x, y, z) == NB["world_point"](
                R, t, i, x, y, z
            )
    out = [np.empty((3, 3)), np.empty((3, 3))]
    for r, p, y in rng.uniform(-np.pi, np.pi, (20, 3)):
        for f, o in zip((PY, NB), out):
            f["rpy_matrix"](r, p, y, o)
        # libm sin/cos on both sides
        np.testing.assert_allclose(out[0], out[1], rtol=0, atol=1e-15)
        np.testing.assert_allclose(
            out[0], geometry.rpy_to_matrix(np.array([r, p, y])), atol=1e-15
        )


def test_corner_weight_gradient_is_the_derivative_of_the_trilinear_weight():
    """``corner_weight_gradient`` (scan matching's Newton step) is the trilinear weight's gradient with respect to
    the world point: central differences of ``voxel_cell`` + ``corner_weight`` inside one block agree, the eight
    corners' gradients sum to zero (the weights sum to one), and the Python and njit builds agree bit for bit."""
    from slamlib.kernels import cpu
    from slamlib.kernels.device import PY

    NB = cpu._F
    rng = np.random.default_rng(22)
    inv_h, h = 2.0, 1e-6
    for wx, wy, wz in rng.uniform(-20, 20, (50, 3)):
        ux0, uy0, uz0, fx, fy, fz, ok = PY["voxel_cell"](wx, wy, wz, inv_h)
        assert ok
        if min(fx, fy, fz, 1 - fx, 1 - fy, 1 - fz) < 1e-4:
            continue  # a difference across a block boundary takes other corners
        total = np.zeros(3)
        for k in range(8):
            grad = PY["corner_weight_gradient"](fx, fy, fz, k, inv_h)
            assert grad == NB["corner_weight_gradient"](fx, fy, fz, k, inv_h)
            numeric = []
            for e in np.eye(3) * h:
                w = [
                    PY["corner_weight"](*PY["voxel_cell"](*(p + s * e), inv_h)[3:6], k)
                    for s in (1, -1)
                    for p in [np.array([wx, wy, wz])]
                ]
                numeric.append((w[0] - w[1]) / (2 * h))
            np.testing.assert_allclose(grad, numeric, rtol=1e-6, atol=1e-9)
            total += grad
        np.testing.assert_allclose(total, 0.0, atol=1e-12)


# ------------------------------------------------------------------ small inputs, value by value
# Chunk boundaries, messages, dtypes and the edges of the key range, against the reference and the definitions.
# Fast on purpose: `make mutate` runs these kernels as Python (NUMBA_DISABLE_JIT=1).
def _world(rng, n=900):
    """Points on the faces of two boxes and a slab, plus clutter, around the origin (float32, metres)."""
    out = []
    for c, size in (
        ([1.0, 0.5, 0.0], [2.0, 1.0, 1.5]),
        ([-1.5, -1.0, 0.5], [1.0, 2.5, 1.0]),
    ):
        p = rng.uniform(-0.5, 0.5, (n // 3, 3))
        ax = rng.integers(0, 3, n // 3)
        p[np.arange(n // 3), ax] = np.sign(p[np.arange(n // 3), ax]) * 0.5
        out.append(np.asarray(c) + p * size)
    out.append(rng.uniform(-3, 3, (n // 3, 3)) * [1, 1, 0.05])
    return np.vstack(out).astype(np.float32)


def _small_world_maps(rng):
    world = _world(rng)
    maps = [
        VoxelHashMap(voxel_size=0.5, capacity=2**11),
        MortonBVHMap(radius=0.3, sigma=0.15, dedup_level=2),
        MortonBVHMap(radius=0.8, sigma=0.3, quantum=0.02, dedup_level=0),
    ]
    for m in maps:
        m.merge(world)
    return maps


def _near_particles(rng, P, spread=0.05, shift=0.2):
    R = geometry.rpy_to_matrix(rng.uniform(-np.pi, np.pi, (P, 3)) * spread)
    t = rng.normal(0.0, shift, (P, 3))
    return R, t


@pytest.fixture(scope="module")
def small_maps():
    return _small_world_maps(np.random.default_rng(11))


@pytest.mark.parametrize(
    "chunks", [None, (5, 3, 4, 2)], ids=["default-chunks", "small-chunks"]
)
def test_score_particles_cpu_equals_reference_across_chunks(
    small_maps, monkeypatch, chunks
):
    """Per-particle scores of the fused kernel == the reference, with point and particle counts that are not
    multiples of the chunk sizes (several chunks each way, a partial last one), a small Morton leaf (the octree
    descent runs) and a tiny cell cache (collisions), and with the default constants."""
    if chunks:
        for name, v in zip(
            ("POINT_CHUNK", "PARTICLE_CHUNK", "MORTON_LEAF", "CELL_CACHE_BITS"), chunks
        ):
            monkeypatch.setattr(cpu, name, v)
    rng = np.random.default_rng(12)
    P, N = (7, 23) if chunks else (3, 70)
    R, t = _near_particles(rng, P)
    pts = np.vstack(
        [
            rng.uniform(-3, 3, (N - 3, 3)),
            [[1.0, 1.0, 0.75], [20.0, 0.0, 0.0], [-2.0, -1.0, 0.0]],
        ]
    ).astype(np.float32)
    for m in small_maps:
        lk = m.lookup()
        ref = REF.score_particles(R, t, pts, lk)
        got = CPU.score_particles(R, t, pts, lk)
        assert got.shape == (P,) and got.dtype == np.float64
        np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-9)
        # the particles are told apart: a mixed-up particle index shows
        assert np.ptp(ref) > 1.0


def test_score_particles_per_point_terms_by_definition(small_maps):
    """One particle at the identity, one point at a time: the CPU score is the reference's per-point term, and
    for the Morton maps it is ``-0.5 min(d_nn, r)^2 / sigma^2`` by brute force; the sum over points adds up."""
    rng = np.random.default_rng(13)
    I, z = np.eye(3)[None], np.zeros((1, 3))
    queries = np.vstack(
        [rng.uniform(-3, 3, (25, 3)), _world(rng)[:15] + rng.normal(0, 0.05, (15, 3))]
    )
    queries = queries.astype(np.float32)
    for m in small_maps:
        lk = m.lookup()
        terms = reference.point_terms(queries.astype(np.float64), lk)
        got = np.array([CPU.score_particles(I, z, q[None], lk)[0] for q in queries])
        np.testing.assert_allclose(got, terms, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(
            CPU.score_particles(I, z, queries, lk)[0], terms.sum(), rtol=1e-9
        )
        if isinstance(m, MortonBVHMap):
            stored = m.points().astype(np.float64)
            d2 = np.min(
                np.sum((stored[None] - queries.astype(np.float64)[:, None]) ** 2, axis=2),
                axis=1,
            )
            np.testing.assert_allclose(
                got,
                -0.5 * np.minimum(d2, m.radius**2) / m.sigma**2,
                rtol=1e-9,
                atol=1e-12,
            )
            assert np.any(d2 < m.radius**2) and np.any(d2 > m.radius**2)


def _garbage_stack(cell_level):
    """``morton_nn_nb``'s scratch stack filled with an entry it must never read: a node that covers everything
    (level 62) holding the run ``[10**6, 10**6 + 1)`` past the end of the points (read as Python: IndexError)."""
    stack = np.empty((8 * (cell_level + 2), 6), np.int64)
    stack[:] = [10**6, 10**6 + 1, 62, 0, 0, 0]
    return stack


def test_morton_nn_is_exact_with_warm_starts_and_a_small_leaf(small_maps):
    """``morton_nn_nb`` returns ``(min(d_nn^2, best), index of that point)`` by brute force, cold and warm started
    from another point, with leaves of 1, 4 and 64 points (deep and shallow descent)."""
    m = small_maps[1]
    lk = m.lookup()
    stored = lk.points.astype(np.float64)
    rng = np.random.default_rng(14)
    queries = np.vstack(
        [
            stored[rng.integers(0, len(stored), 20)] + rng.normal(0, 0.1, (20, 3)),
            rng.uniform(-3, 3, (20, 3)),
        ]
    )
    r2 = lk.radius**2
    for leaf in (1, 4, 64):
        stack = _garbage_stack(lk.cell_level)
        cache_code = np.full(1 << 3, -1, np.int64)
        cache_k = np.empty(1 << 3, np.int64)
        for q in queries:
            d2 = np.sum((stored - q) ** 2, axis=1)
            j = int(np.argmin(d2))
            args = (
                lk.codes,
                lk.points,
                lk.cell_codes,
                lk.cell_start,
                lk.cell_lo,
                lk.cell_hi,
                lk.quantum,
                lk.cell_level,
            )
            best, best_j = cpu.morton_nn_nb(
                *q, *args, r2, -1, stack, leaf, cache_code, cache_k, 3
            )
            if d2[j] < r2:
                assert best_j == j and best == pytest.approx(d2[j], rel=1e-12)
            else:
                assert best_j == -1 and best == r2
            # warm start from the second-nearest point, at its distance
            k = int(np.argsort(d2)[1])
            if d2[k] < r2:
                best, best_j = cpu.morton_nn_nb(
                    *q, *args, d2[k], k, stack, leaf, cache_code, cache_k, 3
                )
                assert best == pytest.approx(d2[j], rel=1e-12) and d2[
                    best_j
                ] == pytest.approx(best, rel=1e-12)


def test_move_particles_cpu_equals_reference_on_two_blocks(monkeypatch):
    """The particle loop in blocks: with a block of 4, 10 particles take three blocks (the last partial)."""
    from slamlib.noise import LutNoise, make_tables

    monkeypatch.setattr(cpu, "PARTICLE_BLOCK", 4)
    rng = np.random.default_rng(15)
    R, t = _near_particles(rng, 10, spread=0.3, shift=3.0)
    sigma = rng.uniform(0.05, 0.3, 6)
    args = ([0.02, -0.01, 0.3], [1.1, 0.2, -0.1])
    noise = rng.normal(size=(10, 6))
    for nz in (
        noise,
        LutNoise(make_tables(5, bits=2), 3, 4),
        LutNoise(make_tables(5, bits=6), 3, 4),
    ):
        R_c, t_c = CPU.move_particles(R, t, *args, nz, sigma)
        R_r, t_r = REF.move_particles(R, t, *args, nz, sigma)
        np.testing.assert_allclose(R_c, R_r, atol=1e-12)
        np.testing.assert_allclose(t_c, t_r, atol=1e-12)


def test_transform_points_cpu_in_spans(monkeypatch):
    """The transform loop in spans: 11 points in spans of 4, allocating and in place, against float64 maths."""
    monkeypatch.setattr(cpu, "TRANSFORM_CHUNK", 4)
    rng = np.random.default_rng(16)
    T = np.eye(4)
    T[:3, :3] = geometry.rpy_to_matrix(np.array([0.3, -0.2, 1.1]))
    T[:3, 3] = [1.0, -2.0, 0.5]
    pts = rng.uniform(-5, 5, (11, 3)).astype(np.float32)
    want = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(CPU.transform_points(T, pts), want, rtol=1e-5, atol=1e-5)
    x = pts.copy()
    assert CPU.transform_points(T, x, out=x) is x
    np.testing.assert_allclose(x, want, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("backend", [REF, CPU], ids=["numpy", "cpu"])
def test_systematic_resample_checks_and_messages(backend):
    """Each bad input alone is refused with the documented message (infinite weights, 2-D weights, empty, negative,
    zero sum, ``u0`` outside [0, 1)); the result is int64."""
    msg = r"^weights must be a non-empty 1-D array of finite non-negative numbers with positive sum$"
    for w in (
        [np.inf, 1.0],
        [[0.5, 0.5], [0.5, 0.5]],
        [],
        [1.0, -0.5],
        [0.0, 0.0],
        [np.nan, 1.0],
    ):
        with pytest.raises(ValueError, match=msg):
            backend.systematic_resample(np.asarray(w, float), 0.5)
    for u0 in (1.0, -0.1):
        with pytest.raises(ValueError, match=rf"^u0 must be in \[0, 1\), got {u0}$"):
            backend.systematic_resample(np.ones(3), u0)
    idx = backend.systematic_resample([1, 0, 3], 0.0)
    assert idx.dtype == np.int64 and idx.tolist() == [0, 2, 2]


def test_reference_scores_every_voxel_and_rounds_points_to_float32():
    """The reference's sorted-key search finds every stored voxel, the one with the largest key too (per-point
    terms at each voxel's mean == the CPU kernel's); float64 points are scored as their float32 values."""
    rng = np.random.default_rng(25)
    m = VoxelHashMap(voxel_size=1.0, capacity=64)
    m.merge(
        (rng.integers(-3, 3, (6, 3)) + rng.uniform(0.3, 0.7, (30, 6, 3)))
        .reshape(-1, 3)
        .astype(np.float32)
    )
    lk = m.lookup()
    occ = np.flatnonzero(lk.keys != -1)
    q = lk.mean[occ]
    I, z = np.eye(3)[None], np.zeros((1, 3))
    ref = np.array([REF.score_particles(I, z, p[None], lk)[0] for p in q])
    cpu_ = np.array([CPU.score_particles(I, z, p[None], lk)[0] for p in q])
    np.testing.assert_allclose(ref, cpu_, rtol=1e-9, atol=1e-9)
    assert np.all(ref > -0.5 * lk.m_max)
    p64 = rng.uniform(-3, 3, (40, 3))
    R, t = _near_particles(rng, 3)
    for backend in (REF, CPU):
        for mm in (m, MortonBVHMap(radius=0.5)):
            if isinstance(mm, MortonBVHMap):
                mm.merge(q)
            np.testing.assert_array_equal(
                backend.score_particles(R, t, p64, mm.lookup()),
                backend.score_particles(R, t, p64.astype(np.float32), mm.lookup()),
            )


def test_reference_at_the_far_corner_of_the_key_range():
    """The voxel with packed key 0 (index -2**20 on every axis) is a stored voxel like any other, and points whose
    interpolation corners leave the key range are scored without error: the reference equals the CPU kernel."""
    h = 0.001
    corner = np.float32(-(2**20) * h + 0.0004)
    m = VoxelHashMap(voxel_size=h, capacity=16, min_sigma=0.001)
    m.merge(
        np.array(
            [[corner, corner, corner], [corner + 0.0001, corner, corner]], np.float32
        )
    )
    lk = m.lookup()
    assert 0 in lk.keys.tolist()
    q = np.array(
        [
            [corner, corner, corner],
            [corner + 0.0002, corner + 0.0001, corner],
            [1e4, 0, 0],
        ],
        np.float32,
    )
    I, z = np.eye(3)[None], np.zeros((1, 3))
    ref = np.array([REF.score_particles(I, z, p[None], lk)[0] for p in q])
    np.testing.assert_allclose(
        ref, [CPU.score_particles(I, z, p[None], lk)[0] for p in q], rtol=1e-9, atol=1e-9
    )
    assert ref[0] > -0.5 * lk.m_max and ref[2] == -0.5 * lk.m_max


def test_point_terms_work_in_float64_and_name_an_unknown_kind(small_maps):
    rng = np.random.default_rng(26)
    w = rng.uniform(-3, 3, (30, 3)).astype(np.float32)
    for m in small_maps:
        np.testing.assert_array_equal(
            reference.point_terms(w, m.lookup()),
            reference.point_terms(w.astype(np.float64), m.lookup()),
        )
    bad = small_maps[0].lookup()._replace(kind=7)
    for fn in (
        lambda: reference.point_terms(w, bad),
        lambda: CPU.score_particles(np.eye(3)[None], np.zeros((1, 3)), w, bad),
    ):
        with pytest.raises(ValueError, match=r"^unknown lookup kind 7$"):
            fn()


def test_out_may_be_another_view_of_the_input():
    """``out=`` given as a different view object of the same memory counts as in place (not as an overlap)."""
    rng = np.random.default_rng(27)
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    x = rng.uniform(-1, 1, (5, 3)).astype(np.float32)
    want = x + np.float32([1, 2, 3])
    assert np.shares_memory(CPU.transform_points(T, x, out=x.view()), x)
    np.testing.assert_allclose(x, want, rtol=1e-6)
    R, t = _near_particles(rng, 4)
    R_ref, t_ref = CPU.move_particles(
        R, t, [0.1, 0, 0], [1, 0, 0], np.zeros((4, 6)), np.zeros(6)
    )
    CPU.move_particles(
        R,
        t,
        [0.1, 0, 0],
        [1, 0, 0],
        np.zeros((4, 6)),
        np.zeros(6),
        out=(R.view(), t.view()),
    )
    np.testing.assert_array_equal(R, R_ref)
    np.testing.assert_array_equal(t, t_ref)


def test_reference_transform_points_dtype_and_out_checks():
    """float64 points are transformed as their float32 values; the result is float32; ``out`` must be a float32
    array of the result's shape (each condition alone), with the documented message."""
    rng = np.random.default_rng(28)
    T = np.eye(4)
    T[:3, :3] = geometry.rpy_to_matrix(np.array([0.3, -0.2, 1.1]))
    T[:3, 3] = [100.3, -20.7, 3.1]
    p64 = rng.uniform(-50, 50, (20, 3))
    got = REF.transform_points(T, p64)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, REF.transform_points(T, p64.astype(np.float32)))
    with pytest.raises(
        ValueError,
        match=r"^out must be a float32 array of shape \(20, 3\), got float64 \(20, 3\)$",
    ):
        REF.transform_points(T, p64, out=np.empty((20, 3)))
    with pytest.raises(
        ValueError,
        match=r"^out must be a float32 array of shape \(20, 3\), got float32 \(19, 3\)$",
    ):
        REF.transform_points(T, p64, out=np.empty((19, 3), np.float32))


@pytest.mark.parametrize("quantum, leaf", [(0.1, 1), (0.05, 4)])
def test_morton_nn_exact_on_coarse_quanta(quantum, leaf):
    """With coarse quanta (a node's gap of one quantum is 5-10 cm) and deep descent, queries a centimetre from
    stored points still find the true nearest one: the node holding the query is never pruned."""
    rng = np.random.default_rng(29)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=quantum, dedup_level=0)
    m.merge(rng.uniform(-1, 1, (3000, 3)).astype(np.float32))
    lk = m.lookup()
    stored = lk.points.astype(np.float64)
    stack = _garbage_stack(lk.cell_level)
    cache_code, cache_k = np.full(8, -1, np.int64), np.empty(8, np.int64)
    for q in stored[rng.integers(0, len(stored), 60)] + rng.normal(0, 0.01, (60, 3)):
        d2 = np.sum((stored - q) ** 2, axis=1)
        best, best_j = cpu.morton_nn_nb(
            *q,
            lk.codes,
            lk.points,
            lk.cell_codes,
            lk.cell_start,
            lk.cell_lo,
            lk.cell_hi,
            lk.quantum,
            lk.cell_level,
            lk.radius**2,
            -1,
            stack,
            leaf,
            cache_code,
            cache_k,
            3,
        )
        assert best_j == int(np.argmin(d2)) and best == pytest.approx(d2.min(), rel=1e-12)


@pytest.mark.parametrize("quantum", [0.6, 0.3, 0.2])
def test_morton_scoring_exact_when_the_cells_are_one_to_four_quanta(quantum):
    """Quanta so coarse that ``cell_level`` (edge ``quantum 2**cell_level >= 2 radius``) is 0, 1 or 2: the scoring
    kernel's search stack (``8 (cell_level + 2)`` rows) is at its smallest and the scores are still exact."""
    rng = np.random.default_rng(35)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=quantum, dedup_level=0)
    m.merge(rng.uniform(-2, 2, (2000, 3)).astype(np.float32))
    lk = m.lookup()
    assert lk.cell_level == {0.6: 0, 0.3: 1, 0.2: 2}[quantum]
    stored = lk.points.astype(np.float64)
    q = stored[rng.integers(0, len(stored), 30)] + rng.normal(0, 0.05, (30, 3))
    R, t = (
        np.repeat(np.eye(3)[None], 2, axis=0),
        np.array([[0.0, 0.0, 0.0], [0.05, -0.02, 0.01]]),
    )
    got = CPU.score_particles(R, t, q.astype(np.float32), lk)
    for i in range(2):
        w = q.astype(np.float32).astype(np.float64) + t[i]
        d2 = np.minimum(((w[:, None, :] - stored[None]) ** 2).sum(-1).min(1), 0.3**2)
        assert got[i] == pytest.approx(np.sum(-0.5 * d2 / 0.1**2), rel=1e-6)


def test_cpu_transform_points_dtype_and_messages():
    """float64 points give a float32 result (the points are converted first); bad shapes and a bad ``out`` are
    refused with the documented messages, naming ``out``."""
    T = np.eye(4)
    T[:3, 3] = [1.0, 2.0, 3.0]
    p64 = np.arange(12, dtype=np.float64).reshape(4, 3) * 0.1
    got = CPU.transform_points(T, p64)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, CPU.transform_points(T, p64.astype(np.float32)))
    with pytest.raises(
        ValueError,
        match=r"^need T \(4, 4\) and points \(N, 3\), got \(3, 3\) and \(4, 3\)$",
    ):
        CPU.transform_points(np.eye(3), p64)
    pts = p64.astype(np.float32)
    for out in (np.empty((4, 3)), pts[::-1]):
        with pytest.raises(
            ValueError,
            match=r"^out must be a writeable C-contiguous float32 array of shape \(4, 3\)$",
        ):
            CPU.transform_points(T, pts, out=out)


def test_cpu_move_and_score_refuse_bad_input_with_messages():
    """Each check of the CPU backend alone, with its message: particle shapes, ``out`` arrays (named), LUT noise
    step / seed (0 allowed) and tables, the noise shape, scan point shapes."""
    from slamlib.noise import LutNoise, make_tables

    rng = np.random.default_rng(30)
    R, t = _near_particles(rng, 4)
    args = ([0.0, 0.0, 0.1], [1.0, 0.0, 0.0])
    noise, sigma = np.zeros((4, 6)), np.full(6, 0.1)
    with pytest.raises(
        ValueError,
        match=r"^particles need R \(P, 3, 3\) and t \(P, 3\), got \(4, 3, 3\) and \(3, 3\)$",
    ):
        CPU.move_particles(R, t[:3], *args, noise, sigma)
    with pytest.raises(
        ValueError,
        match=r"^particles need R \(P, 3, 3\) and t \(P, 3\), got \(4, 3, 2\) and \(4, 3\)$",
    ):
        CPU.move_particles(R[:, :, :2], t, *args, noise, sigma)
    with pytest.raises(
        ValueError,
        match=r"^out\[0\] must be a writeable C-contiguous float64 array of shape \(4, 3, 3\)$",
    ):
        CPU.move_particles(
            R, t, *args, noise, sigma, out=(R.astype(np.float32), t.copy())
        )
    with pytest.raises(
        ValueError,
        match=r"^out\[1\] must be a writeable C-contiguous float64 array of shape \(4, 3\)$",
    ):
        CPU.move_particles(R, t, *args, noise, sigma, out=(R.copy(), t[:, :2].copy()))
    tables = make_tables(5, bits=4)
    for step, seed in ((-1, 0), (0, -1)):
        with pytest.raises(ValueError, match=r"^LutNoise step and seed must be >= 0$"):
            CPU.move_particles(R, t, *args, LutNoise(tables, step, seed), sigma)
    CPU.move_particles(R, t, *args, LutNoise(tables, 0, 0), sigma)
    bad = LutNoise(tables._replace(perm=tables.perm[:, :8]), 1, 1)
    with pytest.raises(
        ValueError,
        match=r"^LutNoise tables need normal \(T,\) and perm \(6, T\) with T = 2\*\*bits$",
    ):
        CPU.move_particles(R, t, *args, bad, sigma)
    with pytest.raises(
        ValueError, match=r"^noise must have shape \(P, 6\) = \(4, 6\), got \(4, 5\)$"
    ):
        CPU.move_particles(R, t, *args, noise[:, :5], sigma)
    lk = VoxelHashMap(capacity=16).lookup()
    for pts in (np.zeros(3, np.float32), np.zeros((4, 2), np.float32)):
        with pytest.raises(
            ValueError,
            match=rf"^points must have shape \(N, 3\), got {re.escape(str(pts.shape))}$",
        ):
            CPU.score_particles(R, t, pts, lk)
    with pytest.raises(ValueError, match=r"^particles need R"):
        CPU.score_particles(R, t[:3], np.zeros((2, 3), np.float32), lk)


def test_cpu_transform_in_place_refuses_a_read_only_array():
    x = np.ones((4, 3), np.float32)
    x.setflags(write=False)
    with pytest.raises(
        ValueError,
        match=r"^out must be a writeable C-contiguous float32 array of shape \(4, 3\)$",
    ):
        CPU.transform_points(np.eye(4), x, out=x)


def test_reference_move_particles_returns_the_out_arrays():
    rng = np.random.default_rng(31)
    R, t = _near_particles(rng, 3)
    R_o, t_o = np.empty_like(R), np.empty_like(t)
    res = REF.move_particles(
        R, t, [0.1, 0, 0], [1, 0, 0], np.zeros((3, 6)), np.zeros(6), out=(R_o, t_o)
    )
    assert res[0] is R_o and res[1] is t_o


def test_morton_search_at_the_low_corner_of_the_range():
    """Points in the first cells of the 21-bit range (-10,485.76 m at 1 cm quanta): the query's 2x2x2 block includes
    cells at index -1 (skipped) and 0 on each axis, and the ones at 0 are searched: exact nearest neighbours."""
    rng = np.random.default_rng(32)
    lo = -(2**20) * 0.01
    pts = (lo + rng.uniform(0.0, 0.5, (300, 3))).astype(np.float32)
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=0.01, dedup_level=0)
    m.merge(pts)
    lk = m.lookup()
    assert len(m) > 200 and np.any(lk.cell_codes == 0)
    stored = lk.points.astype(np.float64)
    I = np.eye(3)[None]
    for q in stored[:40] + rng.normal(0, 0.02, (40, 3)):
        d2 = min(np.min(np.sum((stored - q) ** 2, axis=1)), 0.3**2)
        got = CPU.score_particles(I, q[None], np.zeros((1, 3), np.float32), lk)[0]
        assert got == pytest.approx(-0.5 * d2 / 0.1**2, rel=1e-9, abs=1e-12)


def test_morton_search_finds_the_cell_whose_code_is_one():
    """Points in the first two cells along x of the 21-bit range: cell (1, 0, 0) has Morton code 1, the one code
    next to the cell cache's "empty" marker (-1); queries there, made first in a fresh kernel call, find their exact
    nearest neighbours in that cell (a cache whose empty entries read as code 1 would hand back an unset index)."""
    rng = np.random.default_rng(34)
    lo = -(2**20) * 0.01
    m = MortonBVHMap(radius=0.3, sigma=0.1, quantum=0.01, dedup_level=0)
    edge = 0.01 * 2**m.cell_level  # 0.64 m
    near = rng.uniform(0.0, 0.3, (100, 3))
    far = near + [edge + 0.3, 0.0, 0.0]  # x in [0.94, 1.24): cell 1
    m.merge((lo + np.concatenate([near, far])).astype(np.float32))
    lk = m.lookup()
    assert lk.cell_codes.tolist() == [0, 1]
    stored = lk.points.astype(np.float64)
    I = np.eye(3)[None]
    for q in lo + far[:20] + rng.normal(0, 0.02, (20, 3)):
        d2 = min(np.min(np.sum((stored - q) ** 2, axis=1)), 0.3**2)
        assert d2 < 0.01
        got = CPU.score_particles(I, q[None], np.zeros((1, 3), np.float32), lk)[0]
        assert got == pytest.approx(-0.5 * d2 / 0.1**2, rel=1e-9, abs=1e-12)


def test_morton_warm_start_from_the_last_stored_point():
    """Two particles at the same pose and a scan point whose nearest neighbour is the last stored point (in Morton
    order): the second particle warm-starts from that point alone and both score the same."""
    rng = np.random.default_rng(33)
    m = MortonBVHMap(radius=0.3, sigma=0.1, dedup_level=0)
    m.merge(rng.uniform(-1, 1, (200, 3)).astype(np.float32))
    last = m.lookup().points[-1]
    R, t = np.repeat(np.eye(3)[None], 2, axis=0), np.zeros((2, 3))
    s = CPU.score_particles(R, t, (last + 0.001).astype(np.float32)[None], m.lookup())
    assert s[0] == s[1] == pytest.approx(-0.5 * 3e-6 / 0.01, rel=1e-3)


def test_reference_transform_is_float64_arithmetic_rounded_once():
    """The numpy reference of transform_points: float32 points, float64 arithmetic, one rounding to float32
    (float32 arithmetic differs by an ulp on about half the coordinates of a typical pose)."""
    from slamlib.geometry import make_pose, rpy_to_matrix
    from slamlib.kernels import reference

    rng = np.random.default_rng(11)
    pts = rng.uniform(-80, 80, (10_000, 3)).astype(np.float32)
    T = make_pose(
        rpy_to_matrix(np.array([0.01, -0.02, 1.3])), np.array([123.4, -56.7, 1.9])
    )
    exact = (pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]).astype(np.float32)
    np.testing.assert_array_equal(reference.transform_points(T, pts), exact)


def test_launch_runs_one_task_on_one_thread_and_restores_the_thread_count():
    """``kernels.cpu._launch(kernel, n, chunk, *args)`` calls ``kernel(*args, chunk)``: on one thread when
    ``n <= chunk`` (a single task), on the pool's threads otherwise, and leaves the thread count as it found it."""
    threads = numba.get_num_threads()
    seen = []

    def spy(a, chunk):
        seen.append((a, chunk, numba.get_num_threads()))
        return a + chunk

    assert cpu._launch(spy, 5, 5, 10) == 15
    assert numba.get_num_threads() == threads
    assert cpu._launch(spy, 6, 5, 20) == 25
    assert seen == [(10, 5, 1), (20, 5, threads)]
    assert numba.get_num_threads() == threads


def test_ceil_div_counts_the_tasks_that_cover_n_items():
    """``kernels.cpu._ceil_div(n, chunk) = ceil(n / chunk)``: the task count of every ``prange`` in the CPU backend."""
    for n, chunk in [
        (0, 4),
        (1, 4),
        (3, 4),
        (4, 4),
        (5, 4),
        (8, 4),
        (9, 4),
        (7, 1),
        (1, 1),
        (100, 64),
    ]:
        assert cpu._ceil_div(n, chunk) == -(-n // chunk), (n, chunk)


def test_move_particles_takes_float32_particles_and_returns_float64():
    """``move_particles`` converts ``R``, ``t`` to float64 before the kernel (its documented ``(P, 3, 3) f8`` result):
    float32 particles give the float64 result of the same poses, not a float32 one."""
    rng = np.random.default_rng(4)
    P = 5
    R = np.stack(
        [geometry.rpy_to_matrix(a) for a in rng.uniform(-0.5, 0.5, (P, 3))]
    ).astype(np.float32)
    t = rng.normal(size=(P, 3)).astype(np.float32)
    noise = rng.normal(size=(P, 6))
    sigma = np.array([0.1, 0.2, 0.05, 0.01, 0.02, 0.03])
    args = ([0.01, -0.02, 0.03], [1.0, 0.1, 0.0], noise, sigma)
    R_new, t_new = cpu.move_particles(R, t, *args)
    R_ref, t_ref = cpu.move_particles(R.astype(np.float64), t.astype(np.float64), *args)
    assert R_new.dtype == t_new.dtype == np.float64
    np.testing.assert_array_equal(R_new, R_ref)
    np.testing.assert_array_equal(t_new, t_ref)


@pytest.mark.parametrize("which", ["rpy_delta", "trans_delta", "sigma"])
def test_move_particles_names_a_vector_of_the_wrong_length(which):
    """``move_particles`` needs 3 (``rpy_delta``, ``trans_delta``) and 6 (``sigma``) values: one more is an error
    naming the argument, not silently ignored (the kernels read only the first 3 or 6)."""
    P = 2
    R, t = np.tile(np.eye(3), (P, 1, 1)), np.zeros((P, 3))
    args = {"rpy_delta": np.zeros(3), "trans_delta": np.zeros(3), "sigma": np.ones(6)}
    args[which] = np.zeros(args[which].size + 1)
    with pytest.raises(
        ValueError, match=rf"{which} must have {args[which].size - 1} values"
    ):
        cpu.move_particles(
            R, t, args["rpy_delta"], args["trans_delta"], np.zeros((P, 6)), args["sigma"]
        )


def test_systematic_resample_normalises_float32_weights_in_float64():
    """``systematic_resample`` accumulates the weights in float64 whatever their dtype: on a pointer that falls
    between the float32 and the float64 cumulative sums of the same weights, float32 weights pick the index the
    reference picks from their float64 values."""
    P = 10
    w32 = np.full(P, 0.1, np.float32)
    w64 = w32.astype(np.float64)
    c32 = np.cumsum(w32 / w32.sum())
    c64 = np.cumsum(w64 / w64.sum())
    u0s = np.linspace(0.0, 0.999, 99901)
    pointers = (u0s[:, None] + np.arange(P)) / P
    differ = np.any(
        np.searchsorted(c32, pointers, side="right")
        != np.searchsorted(c64, pointers, side="right"),
        1,
    )
    assert differ.any(), (
        "no pointer separates the float32 and float64 sums: the test needs another weight"
    )
    u0 = u0s[np.argmax(differ)]
    np.testing.assert_array_equal(
        cpu.systematic_resample(w32, u0), reference.systematic_resample(w64, u0)
    )


def test_move_kernels_built_afresh_equal_the_reference(monkeypatch):
    """``_make_move_kernels`` (the factory that runs at import) rebuilt here and put in place of ``_MOVE``: both
    layouts, drawn noise and LUT noise with and without the cos/sin table, over three particle blocks (the last
    partial), equal the numpy reference, in place too. A test on the import-time build alone could not see a
    change to the factory made after import (as in ``make mutate``, whose mutants switch on after the import)."""
    from slamlib.kernels.cpu import move_particles_soa
    from slamlib.noise import LutNoise, make_tables

    fresh = {soa: cpu._make_move_kernels(soa) for soa in (False, True)}
    assert all(len(kernels) == 3 for kernels in fresh.values())
    monkeypatch.setattr(cpu, "_MOVE", fresh)
    monkeypatch.setattr(cpu, "PARTICLE_BLOCK", 4)
    P = 10
    rng = np.random.default_rng(29)
    R, t = _near_particles(rng, P, spread=0.3, shift=3.0)
    sigma = rng.uniform(0.05, 0.3, 6)
    args = ([0.02, -0.01, 0.3], [1.1, 0.2, -0.1])
    noise = rng.normal(size=(P, 6))
    Rs, ts = np.ascontiguousarray(R.transpose(1, 2, 0)), np.ascontiguousarray(t.T)
    for nz, nz_soa in (
        (noise, np.ascontiguousarray(noise.T)),
        (LutNoise(make_tables(5, bits=2), 3, 4),) * 2,  # P > table: the trig table
        (LutNoise(make_tables(5, bits=6), 3, 4),) * 2,  # P < table: cos/sin per call
    ):
        R_r, t_r = REF.move_particles(R, t, *args, nz, sigma)
        R_c, t_c = CPU.move_particles(R, t, *args, nz, sigma)
        np.testing.assert_allclose(R_c, R_r, atol=1e-12)
        np.testing.assert_allclose(t_c, t_r, atol=1e-12)
        R_s, t_s = move_particles_soa(Rs, ts, *args, nz_soa, sigma)
        np.testing.assert_allclose(R_s.transpose(2, 0, 1), R_r, atol=1e-12)
        np.testing.assert_allclose(t_s.T, t_r, atol=1e-12)
        # in place, each particle moved exactly once: blocks that overlapped would move some twice
        R_i, t_i = R.copy(), t.copy()
        CPU.move_particles(R_i, t_i, *args, nz, sigma, out=(R_i, t_i))
        np.testing.assert_array_equal(R_i, R_c)
        np.testing.assert_array_equal(t_i, t_c)
        R_j, t_j = Rs.copy(), ts.copy()
        move_particles_soa(R_j, t_j, *args, nz_soa, sigma, out=(R_j, t_j))
        np.testing.assert_array_equal(R_j, R_s)
        np.testing.assert_array_equal(t_j, t_s)


#: What a run compiles: the filter in both motion modes (crop and down-sampling, the move, scoring, merging, the
#: LIDAR-only scan match) and the move kernels in both layouts with drawn and LUT noise (with and without the
#: per-call trig table: 40 particles, tables of 16 and 256 entries).
_CACHE_WORKLOAD = """
import dataclasses, sys
import numpy as np
sys.path.insert(0, {tests!r})
from world3d import simulate, tiny_config
from slamlib.kernels import cpu
from slamlib.noise import LutNoise, make_tables
from slamlib.slam3d import ParticleSLAM3D
frames, _ = simulate(n=4)
for lidar_only in (False, True):
    slam = ParticleSLAM3D(tiny_config())
    for f in frames:
        slam.register_frame(dataclasses.replace(f, velocity=None) if lidar_only else f)
P = 40
R, t, sigma, zero = np.tile(np.eye(3), (P, 1, 1)), np.zeros((P, 3)), np.full(6, 0.01), np.zeros(3)
drawn = np.random.default_rng(0).standard_normal((P, 6))
for noise, noise_soa in [(drawn, drawn.T)] + [
    (lut, lut) for lut in (LutNoise(make_tables(3, bits=b), 1, 2) for b in (4, 8))
]:
    cpu.move_particles(R, t, zero, zero, noise, sigma)
    cpu.move_particles_soa(R.transpose(1, 2, 0), t.T, zero, zero, noise_soa, sigma)
"""


def test_a_second_run_loads_every_kernel_from_numbas_cache(tmp_path):
    """Two fresh processes run the same work with one Numba cache: the second compiles nothing. A kernel whose
    cache key changes between processes (a closure over a jitted function: Numba pickles the closure's cells
    into the key) is compiled by every run, seconds of a warm start, and grows its cache index each time."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    workload = _CACHE_WORKLOAD.format(tests=str(Path(__file__).parent))
    env = {
        **os.environ,
        "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache"),
        "NUMBA_DEBUG_CACHE": "1",
    }
    env.pop("NUMBA_DISABLE_JIT", None)

    def saved_by_a_run() -> set:
        done = subprocess.run(
            [sys.executable, "-c", workload],
            env=env,
            capture_output=True,
            text=True,
            timeout=900,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        lines = (done.stdout + done.stderr).splitlines()
        return {
            line.split("'")[1].rsplit("/", 1)[-1].split("-")[0]
            for line in lines
            if "[cache] data saved" in line
        }

    first = saved_by_a_run()
    for kernel in ("_move_nb", "_move_lut_nb", "_crop_keys_nb", "_score_voxel_nb"):
        assert any(kernel in name for name in first), (kernel, sorted(first))
    assert saved_by_a_run() == set()
