"""CUDA kernels (slamlib.kernels.cuda) against the numpy reference, in Numba's CUDA simulator (tiny sizes), or on
the card with ``SLAMLIB_REAL_CUDA=1`` (tests/conftest.py; benchmarks/gpu_check.sh)."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from slamlib import geometry
from slamlib import noise as N
from slamlib.errors import BackendUnavailableError
from slamlib.kernels import cpu, get_backend
from slamlib.kernels import cuda as kc
from slamlib.kernels import reference as ref
from slamlib.maps import MortonBVHMap, VoxelHashMap


def _particles(rng, P):
    return geometry.rpy_to_matrix(rng.normal(0, 0.4, (P, 3))), rng.normal(0, 5, (P, 3))


SIGMA = np.array([0.1, 0.2, 0.05, 0.01, 0.02, 0.03])

# The behaviour without a GPU (refusals, error messages) cannot be seen on a card: the simulator stands in for
# "no GPU" in these tests, and on a real GPU they would run the full benchmark instead of refusing.
without_a_gpu = pytest.mark.skipif(
    os.environ.get("SLAMLIB_REAL_CUDA") == "1", reason="checks what happens without a GPU"
)
# The filter's own sizes and default launch settings (many blocks, several scan levels), which the simulator
# (~1 s per 10k threads) cannot run in CI: on a GPU only.
on_a_gpu = pytest.mark.skipif(
    os.environ.get("SLAMLIB_REAL_CUDA") != "1", reason="real sizes: a GPU only"
)


def test_move_particles_equals_reference_with_passed_noise():
    rng = np.random.default_rng(1)
    R, t = _particles(rng, 70)
    noise = rng.standard_normal((70, 6))
    got = kc.move_particles(
        R, t, [0.1, -0.05, 0.2], [1.0, 0.2, 0.01], noise, SIGMA, threads=32
    )
    want = ref.move_particles(R, t, [0.1, -0.05, 0.2], [1.0, 0.2, 0.01], noise, SIGMA)
    np.testing.assert_allclose(got[0], want[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match="noise"):
        kc.move_particles(R, t, [0, 0, 0], [0, 0, 0], noise[:5], SIGMA)


def test_move_particles_with_device_lut_noise_equals_reference_with_host_draws():
    rng = np.random.default_rng(2)
    R, t = _particles(rng, 40)
    lut = N.LutNoise(N.make_tables(seed=5), step=3, seed=9)
    got = kc.move_particles(R, t, [0.0, 0.01, -0.1], [0.5, 0.0, 0.0], lut, SIGMA)
    want = ref.move_particles(
        R, t, [0.0, 0.01, -0.1], [0.5, 0.0, 0.0], lut.draw(40), SIGMA
    )
    np.testing.assert_allclose(got[0], want[0], atol=1e-12)
    np.testing.assert_allclose(got[1], want[1], atol=1e-12)
    other = kc.move_particles(
        R, t, [0.0, 0.01, -0.1], [0.5, 0.0, 0.0], lut._replace(step=4), SIGMA
    )
    assert not np.allclose(other[1], got[1])  # the next frame draws new noise
    # tables uploaded once
    on_device = lut._replace(tables=kc.tables_to_device(lut.tables))
    again = kc.move_particles(R, t, [0.0, 0.01, -0.1], [0.5, 0.0, 0.0], on_device, SIGMA)
    np.testing.assert_array_equal(again[1], got[1])


def test_device_arrays_stay_on_device():
    rng = np.random.default_rng(3)
    R, t = _particles(rng, 16)
    noise = rng.standard_normal((16, 6))
    R_d, t_d = kc.move_particles(
        kc.to_device(R),
        kc.to_device(t),
        [0, 0, 0.1],
        [1, 0, 0],
        kc.to_device(noise),
        SIGMA,
    )
    assert kc.is_device_array(R_d) and kc.is_device_array(t_d)
    want = ref.move_particles(R, t, [0, 0, 0.1], [1, 0, 0], noise, SIGMA)
    np.testing.assert_allclose(kc.to_host(R_d), want[0], atol=1e-12)
    np.testing.assert_allclose(kc.to_host(t_d), want[1], atol=1e-12)
    idx = kc.systematic_resample(kc.to_device(rng.random(16)), 0.5)
    assert kc.is_device_array(idx) and kc.to_host(idx).dtype == np.int64


def test_transform_points_grid_stride():
    rng = np.random.default_rng(4)
    R, t = _particles(rng, 1)
    T = geometry.make_pose(R[0], t[0])
    pts = rng.normal(0, 20, (300, 3)).astype(np.float32)
    # 48 threads, ~6 points each
    got = kc.transform_points(T, pts, threads=16, max_blocks=3)
    assert got.dtype == np.float32 and got.shape == pts.shape
    np.testing.assert_allclose(got, ref.transform_points(T, pts), rtol=1e-6, atol=2e-5)
    dev = kc.transform_points(T, kc.to_device(pts))
    assert kc.is_device_array(dev)
    np.testing.assert_allclose(kc.to_host(dev), got, atol=1e-5)
    # out= on the host, on the device, and in place on the device
    host_out = np.full_like(pts, np.nan)
    assert kc.transform_points(T, pts, out=host_out, threads=16, max_blocks=3) is host_out
    assert np.array_equal(host_out, got)
    d = kc.to_device(pts)
    assert kc.transform_points(T, d, out=d, threads=16, max_blocks=3) is d
    assert np.array_equal(kc.to_host(d), got)
    with pytest.raises(ValueError, match="out"):
        kc.transform_points(T, pts, out=np.empty((299, 3), np.float32))


@pytest.mark.parametrize("which", [0, 1], ids=["voxel_hash", "morton_bvh"])
def test_score_particles_equals_reference_and_cpu(street_maps, which):
    world, lookups = street_maps
    lookup = lookups[which]
    rng = np.random.default_rng(6 + which)
    P = 5
    R = geometry.rpy_to_matrix(rng.normal(0, 0.05, (P, 3)))
    t = rng.normal(0, 0.3, (P, 3))
    pts = world[rng.choice(len(world), 100, replace=False)] + rng.normal(
        0, 0.05, (100, 3)
    ).astype(np.float32)
    got = kc.score_particles(R, t, pts, lookup, threads=32)
    want = ref.score_particles(R, t, pts, lookup)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        got, cpu.score_particles(R, t, pts, lookup), rtol=1e-9, atol=1e-9
    )
    assert np.ptp(got) > 1.0  # the particles are told apart
    dev = kc.score_particles(
        kc.to_device(R),
        kc.to_device(t),
        kc.to_device(pts),
        kc.lookup_to_device(lookup),
        threads=16,
    )
    np.testing.assert_allclose(kc.to_host(dev), want, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("kind", ["voxel_hash", "morton_bvh"])
def test_score_particles_uploads_the_map_once_per_version(monkeypatch, kind):
    """Scoring twice on an unchanged map copies its lookup arrays to the device once; a merge or a prune (new
    version) uploads them again, and the scores follow the changed map."""
    from numba import cuda

    rng = np.random.default_rng(12)
    world = rng.normal(0, 2, (600, 3)).astype(np.float32)
    m = (
        VoxelHashMap(voxel_size=1.0, capacity=2**10)
        if kind == "voxel_hash"
        else MortonBVHMap(radius=0.5)
    )
    m.merge(world)
    R, t = _particles(rng, 2)
    t *= 0.02
    pts = world[:24]
    uploaded = []
    real_to_device = cuda.to_device

    def counting_to_device(a, *args, **kwargs):
        uploaded.append(a)
        return real_to_device(a, *args, **kwargs)

    def map_uploads(lookup):
        fields = [v for v in lookup if isinstance(v, np.ndarray)]
        return sum(any(np.shares_memory(a, f) for f in fields) for a in uploaded)

    monkeypatch.setattr(cuda, "to_device", counting_to_device)
    kc.clear_lookup_cache()
    lk = m.lookup()
    n_arrays = sum(isinstance(v, np.ndarray) for v in lk)
    first = kc.score_particles(R, t, pts, lk, threads=8)
    second = kc.score_particles(R, t, pts, m.lookup(), threads=8)
    assert map_uploads(lk) == n_arrays  # once, by the first call
    assert len(uploaded) == n_arrays + 2 * 3  # and R, t, points per call
    np.testing.assert_array_equal(first, second)
    if kind == "voxel_hash":
        m.merge(world[:300] + np.float32(0.3))
    else:
        assert m.prune(world[0], 2.0) > 0
    lk2 = m.lookup()
    assert lk2.version != lk.version
    uploaded.clear()
    got = kc.score_particles(R, t, pts, lk2, threads=8)
    assert map_uploads(lk2) == n_arrays
    np.testing.assert_allclose(
        got, ref.score_particles(R, t, pts, lk2), rtol=1e-9, atol=1e-9
    )
    assert not np.allclose(got, first)
    uploaded.clear()
    # no version: uploaded, not kept
    kc.score_particles(R, t, pts, lk2._replace(version=0), threads=8)
    kc.score_particles(R, t, pts, lk2._replace(version=0), threads=8)
    assert map_uploads(lk2) == 2 * n_arrays


def test_inclusive_scan_multi_level():
    x = np.random.default_rng(7).random(150)
    # 19 blocks -> 3 -> 1: two levels of recursion
    got = kc.inclusive_scan(x, threads=8).copy_to_host()
    np.testing.assert_allclose(got, np.cumsum(x), rtol=1e-12)


@pytest.mark.parametrize("P,threads", [(1, 8), (37, 8), (100, 32)])
def test_systematic_resample_equals_reference(P, threads):
    rng = np.random.default_rng(P)
    w = rng.random(P) ** 3
    w[rng.random(P) < 0.3] = 0.0
    if w.sum() == 0:
        w[0] = 1.0
    for u0 in (0.0, 0.37, 0.999):
        np.testing.assert_array_equal(
            kc.systematic_resample(w, u0, threads=threads), ref.systematic_resample(w, u0)
        )


def test_systematic_resample_rejects_bad_input():
    with pytest.raises(ValueError):
        kc.systematic_resample(np.array([0.0, 0.0]), 0.1)
    with pytest.raises(ValueError):
        kc.systematic_resample(np.array([1.0, 2.0]), 1.0)


def test_get_backend_cuda_in_simulator():
    b = get_backend("cuda")
    assert b.name == "cuda" and b.score_particles is kc.score_particles
    w = np.array([0.0, 1.0, 0.0, 3.0])
    np.testing.assert_array_equal(
        b.systematic_resample(w, 0.2), ref.systematic_resample(w, 0.2)
    )
    # launch sizes are keywords of the module functions
    np.testing.assert_array_equal(
        kc.systematic_resample(w, 0.2, threads=32), ref.systematic_resample(w, 0.2)
    )


def test_no_gpu_gives_backend_unavailable_error_with_the_fix():
    code = textwrap.dedent("""
        from numba import cuda
        if cuda.is_available():
            print("HAS_GPU")
            raise SystemExit(0)
        import numpy as np
        from slamlib.errors import BackendUnavailableError
        from slamlib.kernels import get_backend
        from slamlib.kernels import cuda as kc
        for make in (lambda: get_backend("cuda"), lambda: kc.systematic_resample(np.ones(2), 0.5)):
            try:
                make()
            except BackendUnavailableError as exc:
                print("MSG", exc)
            else:
                print("NO ERROR")
    """)
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    res = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    if "HAS_GPU" in res.stdout:
        pytest.skip("this machine has a GPU")
    assert res.returncode == 0, res.stderr
    lines = [ln for ln in res.stdout.splitlines() if ln.startswith(("MSG", "NO ERROR"))]
    assert len(lines) == 2 and all(ln.startswith("MSG") for ln in lines), res.stdout
    for ln in lines:
        assert "numba-cuda[cu12]" in ln and 'backend="cpu"' in ln
    assert "Traceback" not in res.stdout + res.stderr
    assert issubclass(BackendUnavailableError, RuntimeError)


@without_a_gpu
def test_bench_cuda_refuses_without_gpu_and_runs_in_simulator_when_asked():
    from slamlib.commands.bench import load_benchmark

    bench_cuda = load_benchmark("cuda")  # benchmarks/cuda.py of this checkout

    with pytest.raises(SystemExit, match="no GPU"):
        bench_cuda.run(quick=True)  # the simulator is on in the tests: no timings
    d = bench_cuda.run(
        allow_simulator=True,
        sizes={
            "P": [2],
            "move": [2],
            "N": [20],
            "points": [50],
            "resample": [10],
            "map": 500,
        },
    )
    assert d["simulator"] is True
    assert {r["kernel"] for r in d["rows"]} == {
        "move_particles",
        "lut_noise_fill",
        "transform_points",
        "score_particles",
        "systematic_resample",
    }


@without_a_gpu
def test_bench_cuda_cli_exits_non_zero_without_gpu(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "slamlib.cli",
            "bench",
            "cuda",
            "--out",
            str(tmp_path / "c.json"),
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    if res.returncode == 0:
        pytest.skip("this machine has a GPU")
    assert "no GPU" in res.stderr and "numba-cuda[cu12]" in res.stderr
    assert not (tmp_path / "c.json").exists()


@settings(max_examples=10, deadline=None)
@given(
    w=st.lists(st.floats(0.0, 10.0), min_size=1, max_size=40).filter(
        lambda v: sum(v) > 1e-3
    ),
    u0=st.floats(0.0, 0.999999),
)
def test_systematic_resample_copy_counts(w, u0):
    """Systematic resampling copies particle j either floor(P w_j) or floor(P w_j) + 1 times (w normalised)."""
    w = np.asarray(w)
    idx = kc.systematic_resample(w, u0, threads=8)
    P = len(w)
    counts = np.bincount(idx, minlength=P)
    expected = P * w / w.sum()
    assert counts.sum() == P and np.all(np.diff(idx) >= 0)
    assert np.all(counts >= np.floor(expected - 1e-9)) and np.all(
        counts <= np.floor(expected + 1e-9) + 1
    )
    assert np.all(counts[w == 0] == 0)


@settings(max_examples=10, deadline=None)
@given(
    rpy=st.lists(st.floats(-3.1, 3.1), min_size=3, max_size=3),
    sig=st.lists(st.floats(0.0, 0.5), min_size=6, max_size=6),
    step=st.integers(0, 2**31),
)
def test_move_particles_keeps_rotations_orthonormal(rpy, sig, step):
    rng = np.random.default_rng(step % 1000)
    R, t = _particles(rng, 8)
    lut = N.LutNoise(N.make_tables(seed=0, bits=8), step=step, seed=1)
    R_new, t_new = kc.move_particles(
        R, t, rpy, [0.3, -0.1, 0.0], lut, np.asarray(sig), threads=8
    )
    np.testing.assert_allclose(
        R_new @ np.swapaxes(R_new, 1, 2),
        np.broadcast_to(np.eye(3), R_new.shape),
        atol=1e-12,
    )
    np.testing.assert_allclose(np.linalg.det(R_new), 1.0, atol=1e-12)
    want = ref.move_particles(R, t, rpy, [0.3, -0.1, 0.0], lut.draw(8), np.asarray(sig))
    np.testing.assert_allclose(t_new, want[1], atol=1e-12)


@on_a_gpu
@pytest.mark.parametrize("layout", kc.SCORE_LAYOUTS)
@pytest.mark.parametrize("which", [0, 1], ids=["voxel_hash", "morton_bvh"])
def test_the_filters_sizes_on_a_gpu_equal_the_cpu_backend(street_maps, which, layout):
    """Default launch settings at the filter's sizes (300 particles, 1,000 scored points; 10,000 particles
    moved; 100,003 weights resampled, several blocks and scan levels): the same numbers as the CPU backend."""
    world, lookups = street_maps
    rng = np.random.default_rng(11)
    P, n = 300, 1000
    R, t = geometry.rpy_to_matrix(rng.normal(0, 0.05, (P, 3))), rng.normal(0, 0.3, (P, 3))
    pts = (world[rng.choice(len(world), n)] + rng.normal(0, 0.05, (n, 3))).astype(
        np.float32
    )
    got = kc.score_particles(R, t, pts, lookups[which], layout=layout)
    np.testing.assert_allclose(
        got, cpu.score_particles(R, t, pts, lookups[which]), rtol=1e-9
    )
    assert np.ptp(got) > 1.0

    R, t = _particles(rng, 10_000)
    noise = rng.standard_normal((10_000, 6))
    want_R, want_t = ref.move_particles(R, t, [0, 0, 0.01], [1, 0, 0], noise, SIGMA)
    got_R, got_t = kc.move_particles(R, t, [0, 0, 0.01], [1, 0, 0], noise, SIGMA)
    np.testing.assert_allclose(got_R, want_R, atol=1e-12)
    np.testing.assert_allclose(got_t, want_t, atol=1e-9)

    w = rng.random(100_003) ** 3
    np.testing.assert_array_equal(
        kc.systematic_resample(w, 0.37), ref.systematic_resample(w, 0.37)
    )
