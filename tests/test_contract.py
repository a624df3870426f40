"""The twelve-step contract (slamlib.contract) at every dimension: the steps' signatures, what they return when
called, the filter's per-frame step (step 12) and the one loop 1D and 2D share; and each checker can fail."""

import importlib
import inspect
import types
from dataclasses import replace
from fractions import Fraction
from types import SimpleNamespace

import numpy as np
import pytest

import slamlib.sim1d.steps as steps1d
import slamlib.sim2d.steps as steps2d
import slamlib.slam3d.steps as steps3d
from slamlib.contract import (
    FILTER_STEP,
    KINDS,
    LOOP_ORDER,
    STEPS,
    ParticleFilter,
    StepInfo,
    StepsExample,
    StepsFilter,
    check_filter_step,
    check_steps_module,
    check_steps_run,
)
from slamlib.geometry import make_pose, rpy_to_matrix
from slamlib.maps import VoxelHashMap
from slamlib.resampling import normalise_log_weights
from slamlib.sim1d import OccupancyGrid1D, ParticleSLAM1D
from slamlib.sim1d import make_world as make_world_1d
from slamlib.sim1d import simulate as simulate_1d
from slamlib.sim2d import (
    OccupancyGrid2D,
    ParticleMaps2D,
    ParticleMapsSLAM2D,
    ParticleSLAM2D,
)
from slamlib.sim2d import make_world as make_world_2d
from slamlib.sim2d import simulate as simulate_2d
from slamlib.slam3d import FilterConfig, ParticleSLAM3D, SLAM3DConfig

MODULES = [steps1d, steps2d, steps3d]
IDS = ["1D", "2D", "3D"]


# ------------------------------------------------------------------------------------------ tiny examples
@pytest.fixture(scope="module")
def recording_1d():
    return simulate_1d(make_world_1d(seed=0), n_frames=12, seed=0)


@pytest.fixture(scope="module")
def recording_2d():
    return simulate_2d(make_world_2d(seed=0), laps=0.1, seed=0)


def _scan_3d(n=300, seed=0):
    """A ring of returns 5-30 m around the sensor, (N, 4) float32 (x, y, z, reflectance)."""
    rng = np.random.default_rng(seed)
    az = rng.uniform(-np.pi, np.pi, n)
    r = rng.uniform(5.0, 30.0, n)
    xyz = np.column_stack([r * np.cos(az), r * np.sin(az), rng.uniform(-1.5, 1.0, n)])
    return np.column_stack([xyz, np.zeros(n)]).astype(np.float32)


def _frame_3d(seed=0, dt=0.1):
    return SimpleNamespace(
        scan=_scan_3d(seed=seed),
        velocity=np.array([8.0, 0.0, 0.0]),
        angular_rate=np.array([0.0, 0.0, 0.1]),
        dt=dt,
    )


def _example(module, recording_1d, recording_2d) -> StepsExample:
    """Each dimension's tiny input for check_steps_run: a moving frame, a fresh map, a spread, a start pose."""
    if module is steps1d:
        return StepsExample(
            frame=recording_1d.frames[5],
            new_map=lambda: OccupancyGrid1D.empty(-30.0, 90.0, 0.05),
            map_size=lambda m: m.total,
            sigma=0.05,
            pose0=1.5,
        )
    if module is steps2d:
        lo, hi = recording_2d.world.bounds
        return StepsExample(
            frame=recording_2d.frames[5],
            new_map=lambda: OccupancyGrid2D.empty(
                np.subtract(lo, 14), np.add(hi, 14), 0.1
            ),
            map_size=lambda m: m.total,
            sigma=np.array([0.05, 0.02, 0.01]),
            pose0=np.array([1.0, -2.0, 0.3]),
        )
    return StepsExample(
        frame=_frame_3d(),
        new_map=lambda: VoxelHashMap(voxel_size=0.5, capacity=2**12),
        map_size=len,
        sigma=np.array([0.05, 0.05, 0.02, 0.005, 0.005, 0.01]),
        pose0=make_pose(rpy_to_matrix([0.01, -0.02, 0.3]), [1.0, 2.0, 0.5]),
    )


@pytest.fixture(params=MODULES, ids=IDS)
def module_and_example(request, recording_1d, recording_2d):
    return request.param, _example(request.param, recording_1d, recording_2d)


def _copy_of(module, **replaced) -> types.ModuleType:
    """A module with every step of ``module`` and some replaced: where a test plants a break."""
    fake = types.ModuleType(f"planted_{module.__name__.rsplit('.', 2)[-2]}")
    for spec in STEPS:
        setattr(fake, spec.name, getattr(module, spec.name))
    for name, fn in replaced.items():
        setattr(fake, name, fn)
    return fake


# ---------------------------------------------------------------------------------------------- the specs
def test_the_contract_numbers_its_twelve_steps_and_names_every_kind():
    assert [s.number for s in STEPS] == list(range(1, 12)) and FILTER_STEP.number == 12
    assert FILTER_STEP.name == "step" and FILTER_STEP.params == ("frame",)
    assert all(kind in KINDS for s in STEPS + (FILTER_STEP,) for kind in s.returns)
    assert sorted(LOOP_ORDER) == [n for n in range(2, 12) if n != 7]
    assert STEPS[8].returns_text == "(pose, index)" and STEPS[1].returns_text == "points"


# ------------------------------------------------------------------------------------------- signatures
@pytest.mark.parametrize("module", MODULES, ids=IDS)
def test_steps_module_keeps_the_signatures(module):
    assert check_steps_module(module) == []


def test_the_signature_checker_finds_a_missing_step_a_wrong_order_and_an_extra_required_parameter():
    fake = types.ModuleType("fake")
    for spec in STEPS:
        setattr(fake, spec.name, eval(f"lambda {', '.join(spec.params)}: None"))  # noqa: S307 (built here)
    assert check_steps_module(fake) == []
    fake.pick_best_particle = lambda log_weights, particles: None
    del fake.read_imu
    fake.merge_scan = lambda world_map, pose, points, backend: None
    problems = "\n".join(check_steps_module(fake))
    assert "step 3 read_imu is missing" in problems
    assert (
        "pick_best_particle: leading parameters ('log_weights', 'particles')" in problems
    )
    assert "merge_scan: extra parameters without defaults: ['backend']" in problems


@pytest.mark.parametrize("module", MODULES, ids=IDS)
def test_the_signature_checker_finds_a_swapped_leading_parameter_in_a_real_module(module):
    def resample_particles(log_weights, particles, rng, ess_fraction=0.5):
        return module.resample_particles(particles, log_weights, rng, ess_fraction)

    planted = _copy_of(module, resample_particles=resample_particles)
    assert check_steps_module(planted) == [
        f"{planted.__name__}.resample_particles: leading parameters "
        "('log_weights', 'particles', 'rng'), contract ('particles', 'log_weights', 'rng')"
    ]


@pytest.mark.parametrize("package", ["slamlib.sim1d", "slamlib.sim2d", "slamlib.slam3d"])
def test_every_step_is_exported_by_its_package(package):
    pkg, steps = (
        importlib.import_module(package),
        importlib.import_module(f"{package}.steps"),
    )
    for spec in STEPS:
        assert getattr(pkg, spec.name) is getattr(steps, spec.name)
        assert spec.name in steps.__all__ and spec.name in pkg.__all__


# ---------------------------------------------------------------------------------------------- returns
def test_steps_return_what_the_contract_says(module_and_example):
    module, example = module_and_example
    assert check_steps_run(module, example) == []


def _next_index(m, ex):
    def pick_best_particle(p, lw):
        return m.pick_best_particle(p, lw)[0], int((np.argmax(lw) + 1) % len(lw))

    return pick_best_particle


def _in_place(m, ex):
    def offset_by_motion(p, imu, dt):
        p[...] = m.offset_by_motion(p, imu, dt)
        return p

    return offset_by_motion


#: Breaks planted one at a time into a copy of a real steps module: (step function, the replacement made from
#: the real module ``m`` and the example ``ex``, what the checker must say).
BREAKS = {
    "11 returns two values": (
        "resample_particles",
        lambda m, ex: lambda p, lw, rng: m.resample_particles(p, lw, rng)[:2],
        "step 11): returns 2 values, the contract says (particles, log_weights, resampled)",
    ),
    "11 numpy bool": (
        "resample_particles",
        lambda m, ex: (
            lambda p, lw, rng: (*m.resample_particles(p, lw, rng)[:2], np.True_)
        ),
        "step 11): resampled is numpy.bool, not bool",
    ),
    "11 never resamples": (
        "resample_particles",
        lambda m, ex: lambda p, lw, rng: (p, normalise_log_weights(lw), False),
        "step 11): resampled is False for ESS",
    ),
    "1 linear weights": (
        "initialise_particles",
        lambda m, ex: (
            lambda n, pose0=None: (m.initialise_particles(n)[0], np.full(n, 1 / n))
        ),
        "step 1): log_weights are not normalised",
    ),
    "1 ignores pose0": (
        "initialise_particles",
        lambda m, ex: lambda n, pose0=None: m.initialise_particles(n),
        "step 1): particles do not start at pose0",
    ),
    "9 numpy index": (
        "pick_best_particle",
        lambda m, ex: (
            lambda p, lw: (m.pick_best_particle(p, lw)[0], np.int64(np.argmax(lw)))
        ),
        "step 9): index is numpy.int64, not int",
    ),
    "9 wrong index": (
        "pick_best_particle",
        _next_index,
        "step 9): index 1 is not the argmax 0",
    ),
    "10 merges into a copy": (
        "merge_scan",
        lambda m, ex: lambda world_map, pose, pts: m.merge_scan(ex.new_map(), pose, pts),
        "step 10): did not change the map it was given (in place)",
    ),
    "8 one score short": (
        "score_particles",
        lambda m, ex: lambda p, pts, world_map: m.score_particles(p, pts, world_map)[:-1],
        "step 8): scores are not (6,) finite floats",
    ),
    "5 does not move": (
        "offset_by_motion",
        lambda m, ex: lambda p, imu, dt: p,
        "step 5): did not move the particles",
    ),
    "6 drops a particle": (
        "perturb_with_noise",
        lambda m, ex: lambda p, sigma, rng: m.perturb_with_noise(p, sigma, rng)[:-1],
        "step 6): returns",
    ),
}


def test_the_returns_checker_passes_an_unchanged_copy(module_and_example):
    module, example = module_and_example
    assert check_steps_run(_copy_of(module), example) == []


@pytest.mark.parametrize("which", list(BREAKS))
def test_the_returns_checker_finds_each_planted_break(module_and_example, which):
    module, example = module_and_example
    name, make, message = BREAKS[which]
    problems = check_steps_run(_copy_of(module, **{name: make(module, example)}), example)
    assert any(message in p for p in problems), problems


@pytest.mark.parametrize("module", [steps1d, steps2d], ids=IDS[:2])
def test_the_returns_checker_finds_a_step_that_changes_its_input(
    module, recording_1d, recording_2d
):
    """Step 5 must return a new particle set (1D and 2D particles are arrays that can be changed in place)."""
    example = _example(module, recording_1d, recording_2d)
    planted = _copy_of(module, offset_by_motion=_in_place(module, example))
    assert "step 5): changed its input particles" in "\n".join(
        check_steps_run(planted, example)
    )


@pytest.mark.parametrize("module", MODULES, ids=IDS)
def test_shared_parameters_alone_run_a_step_at_every_dimension(module):
    """Steps 1, 5, 9 and 11 called with the contract's parameters only; log-weights in and out."""
    particles, log_w = module.initialise_particles(8)
    assert len(particles) == 8 and np.allclose(np.exp(log_w).sum(), 1.0)
    imu = {
        steps1d: 2.0,
        steps2d: (2.0, 0.0),
        steps3d: (np.array([2.0, 0, 0]), np.zeros(3)),
    }
    moved = module.offset_by_motion(particles, imu[module], 0.5)
    pose, i = module.pick_best_particle(moved, log_w)
    assert i == 0  # ties go to the lowest index
    x = {steps1d: lambda p: p, steps2d: lambda p: p[0], steps3d: lambda p: p[0, 3]}
    assert x[module](pose) == pytest.approx(1.0)  # 2 m/s for 0.5 s along x
    peaked = np.log(np.r_[1.0, np.full(7, 1e-9)])
    out, out_log_w, resampled = module.resample_particles(
        moved, peaked, np.random.default_rng(0)
    )
    assert resampled and len(out) == 8 and np.allclose(out_log_w, -np.log(8))


# ------------------------------------------------------------------------------------- step 12: step(frame)
def _filter_1d(recording_1d, recording_2d, ess_fraction):
    slam = ParticleSLAM1D(
        12,
        OccupancyGrid1D.empty(-30.0, 90.0, 0.05),
        0.4,
        np.random.default_rng(1),
        ess_fraction,
        likelihood_sigma=0.07,
    )
    return slam, recording_1d.frames[:8], steps1d, True


def _filter_2d(recording_1d, recording_2d, ess_fraction):
    lo, hi = recording_2d.world.bounds
    world_map = OccupancyGrid2D.empty(np.subtract(lo, 14), np.add(hi, 14), 0.1)
    slam = ParticleSLAM2D(
        12, world_map, [0.1, 0.05, 0.02], np.random.default_rng(1), ess_fraction, 60
    )
    return slam, recording_2d.frames[:8], steps2d, True


def _filter_2d_maps(recording_1d, recording_2d, ess_fraction):
    lo, hi = recording_2d.world.bounds
    grid = OccupancyGrid2D.empty(np.subtract(lo, 14), np.add(hi, 14), 0.1)
    slam = ParticleMapsSLAM2D(
        12,
        ParticleMaps2D(grid, 12),
        [0.1, 0.05, 0.02],
        np.random.default_rng(1),
        ess_fraction,
        60,
    )
    return slam, recording_2d.frames[:8], steps2d, True


def _filter_3d(recording_1d, recording_2d, ess_fraction):
    config = SLAM3DConfig(
        filter=FilterConfig(
            particles=12,
            scored_points=100,
            ess_fraction=1.0 if ess_fraction is None else ess_fraction,
        )
    )
    frames = [_frame_3d(seed=0, dt=0.0)] + [_frame_3d(seed=k) for k in range(1, 5)]
    return ParticleSLAM3D(config), frames, steps3d, False  # 3D may refine step 9's pose


FILTERS = [_filter_1d, _filter_2d, _filter_2d_maps, _filter_3d]
FILTER_IDS = ["1D", "2D", "2D-per-particle-maps", "3D"]


@pytest.mark.parametrize("ess_fraction", [None, 0.0], ids=["always", "never"])
@pytest.mark.parametrize("make", FILTERS, ids=FILTER_IDS)
def test_filter_step_keeps_the_contract(make, ess_fraction, recording_1d, recording_2d):
    """Every frame's ``step`` returns a StepInfo the contract describes and leaves the state it says, both when
    step 11 resamples every frame and when it never does."""
    slam, frames, module, estimate_is_best = make(
        recording_1d, recording_2d, ess_fraction
    )
    assert isinstance(slam, ParticleFilter)
    for frame in frames:
        assert check_filter_step(slam, frame, module, estimate_is_best) == []


class _Planted:
    """A filter whose step() returns the real StepInfo with fields replaced (``change``: field -> function of the
    real StepInfo giving the planted value)."""

    def __init__(self, slam, **change):
        self.slam, self.change = slam, change

    particles = property(lambda self: self.slam.particles)
    log_weights = property(lambda self: self.slam.log_weights)

    def step(self, frame):
        info = self.slam.step(frame)
        return replace(info, **{k: f(info) for k, f in self.change.items()})


@pytest.mark.parametrize("make", [_filter_1d, _filter_2d], ids=IDS[:2])
def test_the_filter_step_checker_finds_a_broken_step_info(
    make, recording_1d, recording_2d
):
    def planted(**change):
        slam, frames, module, _ = make(recording_1d, recording_2d, 0.0)
        slam.step(frames[0])  # a map to score against: frame 1's log-weights differ
        return "\n".join(check_filter_step(_Planted(slam, **change), frames[1], module))

    assert planted() == ""
    assert "is not the argmax of log_weights (an int)" in planted(
        best=lambda i: (i.best + 1) % len(i.weights)
    )
    assert "is not the argmax of log_weights (an int)" in planted(
        best=lambda i: np.int64(i.best)
    )
    assert "estimate is not the pose of moved[best]" in planted(
        estimate=lambda i: i.estimate + 1.0
    )
    assert "weights are not exp(log_weights)" in planted(weights=lambda i: i.weights * 2)
    assert "info.log_weights are not normalised" in planted(
        log_weights=lambda i: i.log_weights + 1.0
    )
    assert "scores are not (12,) finite floats" in planted(scores=lambda i: i.scores[1:])
    assert "ess 1.0 is not 1 / sum(weights^2)" in planted(ess=lambda i: 1.0)
    assert "resampled is numpy.bool, not bool" in planted(resampled=lambda i: np.False_)
    assert "resampled, but its log-weights are not -log P" in planted(
        resampled=lambda i: True
    )
    assert "moved holds 11 particles, not 12" in planted(moved=lambda i: i.moved[1:])
    slam, frames, module, _ = make(recording_1d, recording_2d, 0.0)
    assert check_filter_step(object(), frames[0], module) == [
        "object is not a ParticleFilter (step, particles, log_weights)"
    ]


# ------------------------------------------------------------------------------- the loop 1D and 2D share
def test_1d_and_2d_filters_share_the_loop_the_state_and_the_constructor():
    for cls in (ParticleSLAM1D, ParticleSLAM2D, ParticleMapsSLAM2D):
        assert issubclass(cls, StepsFilter) and cls.step is StepsFilter.step
        params = list(inspect.signature(cls).parameters)
        assert params[:5] == [
            "n_particles",
            "world_map",
            "motion_noise",
            "rng",
            "ess_fraction",
        ]
    from slamlib.sim1d import StepInfo as StepInfo1D
    from slamlib.sim2d import StepInfo2D

    assert StepInfo1D is StepInfo2D is StepInfo


class _Recorder:
    """A steps module that records the number of every step it is asked for, then runs the real one."""

    def __init__(self, module):
        self.module, self.calls = module, []

    def __getattr__(self, name):
        number = {s.name: s.number for s in STEPS}[name]
        fn = getattr(self.module, name)

        def run(*args, **kwargs):
            self.calls.append(number)
            return fn(*args, **kwargs)

        return run


@pytest.mark.parametrize("make", [_filter_1d, _filter_2d], ids=IDS[:2])
def test_the_loop_calls_the_steps_in_order_once_each(make, recording_1d, recording_2d):
    slam, frames, module, _ = make(recording_1d, recording_2d, 0.5)
    # on the instance: the class keeps its module
    slam.steps = recorder = _Recorder(module)
    slam.step(frames[0])
    slam.step(frames[1])
    assert recorder.calls == list(LOOP_ORDER) * 2


@pytest.mark.parametrize("make", [_filter_1d, _filter_2d], ids=IDS[:2])
def test_the_loop_weighs_prior_times_likelihood(make, recording_1d, recording_2d):
    """With no resampling, each frame's log-weights are the last ones plus its scores, normalised: the prior
    weight times the new likelihood."""
    slam, frames, module, _ = make(recording_1d, recording_2d, 0.0)
    before = slam.log_weights
    for frame in frames:
        info = slam.step(frame)
        assert not info.resampled
        np.testing.assert_allclose(
            info.log_weights, normalise_log_weights(before + info.scores), atol=1e-12
        )
        before = slam.log_weights
    assert np.ptp(info.log_weights) > 1e-3  # the scores told the particles apart


@pytest.mark.parametrize("make", [_filter_1d, _filter_2d], ids=IDS[:2])
def test_the_loop_merges_the_scan_at_the_estimate(make, recording_1d, recording_2d):
    """Step 10 adds the frame's scan (step 2, with the filter's options) placed by step 9's pose, and nothing else."""
    slam, frames, module, _ = make(recording_1d, recording_2d, 0.5)
    for frame in frames[:4]:
        want = slam.world_map.copy()
        info = slam.step(frame)
        module.merge_scan(
            want, info.estimate, module.read_scan(frame, **slam.scan_options())
        )
        np.testing.assert_array_equal(slam.world_map.counts, want.counts)
    assert slam.world_map.total > 0


def test_the_1d_filter_still_takes_its_map_as_grid(recording_1d):
    grid = OccupancyGrid1D.empty(-30.0, 90.0, 0.05)
    slam = ParticleSLAM1D(5, grid=grid, motion_noise=0.4, rng=np.random.default_rng(0))
    assert slam.world_map is grid and slam.grid is grid
    with pytest.raises(TypeError, match="got the map twice"):
        ParticleSLAM1D(5, grid, grid=grid, motion_noise=0.4, rng=np.random.default_rng(0))


# ------------------------------------------------------------------------------- the checkers' own helpers
def test_type_name_gives_builtins_bare_and_others_with_their_module():
    from slamlib.contract import _type_name

    assert _type_name(True) == "bool" and _type_name(1.0) == "float"
    assert (
        _type_name(np.True_) == "numpy.bool" and _type_name(np.int64(1)) == "numpy.int64"
    )


def test_close_reads_both_sides_as_float64_and_holds_to_one_part_in_a_billion():
    from slamlib.contract import _close

    assert _close(["0.5", "1"], [0.5, 1.0]) and _close([0.5, 1.0], ["0.5", "1"])
    assert not _close([1.0, 2.0], [1.0, 2.0, 3.0])
    assert _close(0.0, 5e-10) and not _close(0.0, 5e-9)  # absolute 1e-9
    assert _close(1e6, 1e6 + 1e-4) and not _close(1e6, 1e6 + 1.0)  # relative 1e-9


def test_log_weights_problem_says_exactly_what_is_wrong():
    from slamlib.contract import _log_weights_problem as problem

    assert problem(np.full(3, -np.log(3)), 3) is None
    assert problem(np.zeros(3, np.float32), 3) == (
        "log_weights ndarray float32 (3,), not (3,) float64"
    )
    assert problem(np.zeros(2), 3) == "log_weights ndarray float64 (2,), not (3,) float64"
    assert problem([0.0], 1) == "log_weights list  None, not (1,) float64"
    assert problem(np.array([0.0, np.nan]), 2) == "log_weights hold NaN or +inf"
    assert problem(np.array([0.0, np.inf]), 2) == "log_weights hold NaN or +inf"
    assert problem(np.array([1e-9]), 1) == (
        "log_weights are not normalised: logsumexp = 1e-09, not 0"
    )
    assert problem(np.array([5e-10]), 1) is None


def _raise(*args):
    raise ValueError("boom")


def _shifted_pose(m, ex):
    def pick_best_particle(p, lw):
        pose, i = m.pick_best_particle(p, lw)
        return pose + 1.0, i

    return pick_best_particle


def _peak_at_3(m, ex):
    def score_particles(p, pts, world_map):
        return np.where(np.arange(len(p)) == 3, 5.0, 0.0)

    return score_particles


def _in_place_noise(m, ex):
    def perturb_with_noise(p, sigma, rng):
        out = m.perturb_with_noise(p, sigma, rng)
        p[...] = out
        return out.copy()

    return perturb_with_noise


def _merge_then_copy(m, ex):
    def merge_scan(world_map, pose, pts):
        return m.merge_scan(world_map, pose, pts).copy()

    return merge_scan


def _score_and_merge(m, ex):
    def score_particles(p, pts, world_map):
        m.merge_scan(world_map, 0.0, pts)
        return m.score_particles(p, pts, world_map)

    return score_particles


def _resample_in_place(m, ex):
    def resample_particles(p, lw, rng):
        out, out_lw, resampled = m.resample_particles(p, lw, rng)
        p[...] = out[::-1]
        return out, out_lw, resampled

    return resample_particles


def _resample_keeps_particles(m, ex):
    def resample_particles(p, lw, rng):
        out, out_lw, resampled = m.resample_particles(p, lw, rng)
        return p.copy(), out_lw, resampled

    return resample_particles


def _keep_reversed(m, ex):
    def resample_particles(p, lw, rng):
        out, out_lw, resampled = m.resample_particles(p, lw, rng)
        return (out if resampled else p[::-1].copy()), out_lw, resampled

    return resample_particles


#: Breaks planted into a copy of the 1D steps module, and every problem the checker must report for each,
#: word for word (``{m}`` stands for the planted module's name).
EXACT_BREAKS_1D = {
    "3 raises": ("read_imu", lambda m, ex: _raise, []),
    "9 returns one value": ("pick_best_particle", lambda m, ex: lambda p, lw: 0, []),
    "9 pose not of the index": ("pick_best_particle", _shifted_pose, []),
    "9 always index 0": (
        "pick_best_particle",
        lambda m, ex: lambda p, lw: (m.pick_best_particle(p, lw)[0], 0),
        [],
    ),
    "9 pose no pose": (
        "pick_best_particle",
        lambda m, ex: lambda p, lw: (object(), 0),
        [],
    ),
    "8 peak at 3, 9 always index 0": ("score_particles", _peak_at_3, []),
    "1 drops a particle": (
        "initialise_particles",
        lambda m, ex: (
            lambda n, pose0=None: (
                m.initialise_particles(n - 1)[0],
                m.initialise_particles(n)[1],
            )
        ),
        [],
    ),
    "1 not uniform": (
        "initialise_particles",
        lambda m, ex: (
            lambda n, pose0=None: (
                m.initialise_particles(n, *([] if pose0 is None else [pose0]))[0],
                normalise_log_weights(np.arange(n, dtype=float)),
            )
        ),
        [],
    ),
    "1 default not the origin": (
        "initialise_particles",
        lambda m, ex: (
            lambda n, pose0=None: m.initialise_particles(
                n, 1.0 if pose0 is None else pose0
            )
        ),
        [],
    ),
    "2 empty": ("read_scan", lambda m, ex: lambda frame: np.zeros(0), []),
    "2 one NaN": (
        "read_scan",
        lambda m, ex: lambda frame: np.r_[m.read_scan(frame), np.nan],
        [],
    ),
    "2 one point": ("read_scan", lambda m, ex: lambda frame: m.read_scan(frame)[:1], []),
    "3 a fraction": (
        "read_imu",
        lambda m, ex: lambda frame: Fraction(m.read_imu(frame)).limit_denominator(1000),
        [],
    ),
    "3 text": ("read_imu", lambda m, ex: lambda frame: "fast", []),
    "4 int": ("read_timing", lambda m, ex: lambda frame: 1, []),
    "4 negative": ("read_timing", lambda m, ex: lambda frame: -0.1, []),
    "4 zero": ("read_timing", lambda m, ex: lambda frame: 0.0, []),
    "7 NaN": (
        "transform_scan",
        lambda m, ex: lambda p, pts: np.full(np.shape(m.transform_scan(p, pts)), np.nan),
        [],
    ),
    "5 drops a particle": (
        "offset_by_motion",
        lambda m, ex: lambda p, imu, dt: m.offset_by_motion(p, imu, dt)[:-1],
        [],
    ),
    "5 returns None": ("offset_by_motion", lambda m, ex: lambda p, imu, dt: None, []),
    "6 drops a particle": (
        "perturb_with_noise",
        lambda m, ex: lambda p, sigma, rng: m.perturb_with_noise(p, sigma, rng)[:-1],
        [],
    ),
    "6 changes its input": ("perturb_with_noise", _in_place_noise, []),
    "6 does not move": (
        "perturb_with_noise",
        lambda m, ex: lambda p, s, rng: p.copy(),
        [],
    ),
    "10 returns a copy": ("merge_scan", _merge_then_copy, []),
    "8 changes the map": ("score_particles", _score_and_merge, []),
    "11 drops a particle": (
        "resample_particles",
        lambda m, ex: (
            lambda p, lw, rng: (
                m.resample_particles(p, lw, rng)[0][:-1],
                *m.resample_particles(p, lw, rng)[1:],
            )
        ),
        [],
    ),
    "11 changes its input": ("resample_particles", _resample_in_place, []),
    "11 linear weights": (
        "resample_particles",
        lambda m, ex: (
            lambda p, lw, rng: (
                m.resample_particles(p, lw, rng)[0],
                np.exp(m.resample_particles(p, lw, rng)[1]),
                m.resample_particles(p, lw, rng)[2],
            )
        ),
        [],
    ),
    "11 keeps the particles": ("resample_particles", _resample_keeps_particles, []),
    "11 reverses a kept set": ("resample_particles", _keep_reversed, []),
}


#: What check_steps_run says for each of EXACT_BREAKS_1D, word for word.
EXACT_MESSAGES_1D = {
    "3 a fraction": [],  # numbers float64 reads as finite are finite numbers
    "3 raises": ["{m}.read_imu (step 3): raised ValueError: boom"],
    "9 returns one value": [
        "{m}.pick_best_particle (step 9): returns int, the contract says (pose, index)"
    ],
    "9 pose not of the index": [
        "{m}.initialise_particles (step 1): particles do not start at pose0",
        "{m}.pick_best_particle (step 9): pose does not place the scan as particle 0 does (step 7)",
        "{m}.initialise_particles (step 1): the default start pose is not the origin (step 7 moves the scan)",
        "{m}.pick_best_particle (step 9): pose does not place the scan as particle 4 does (step 7)",
    ],
    "9 always index 0": ["{m}.pick_best_particle (step 9): index 0 is not the argmax 4"],
    "9 pose no pose": [
        "{m}: the check stopped, TypeError: float() argument must be a string or a real number, not 'object'"
    ],
    "8 peak at 3, 9 always index 0": [
        "{m}.pick_best_particle (step 9): index 0 is not the argmax 3"
    ],
    "1 drops a particle": [
        "{m}.initialise_particles (step 1): returns ndarray, not 6 particles"
    ],
    "1 not uniform": [
        "{m}.initialise_particles (step 1): log-weights are not uniform (-log P)"
    ],
    "1 default not the origin": [
        "{m}.initialise_particles (step 1): the default start pose is not the origin (step 7 moves the scan)"
    ],
    "2 empty": [
        "{m}.read_scan (step 2): points are not a non-empty finite array: array([], dtype=float64)"
    ],
    "2 one NaN": [
        "{m}.read_scan (step 2): points are not a non-empty finite array: "
        "array([-6.59493873, -5.44902106, -0.32019322,  1.76871635,  "
    ],
    "2 one point": [],
    "3 text": [
        "{m}.read_imu (step 3): imu is not finite numbers: 'fast'",
        "{m}.offset_by_motion (step 5): raised ValueError: could not convert string to float: 'fast'",
    ],
    "4 int": ["{m}.read_timing (step 4): dt is 1 (int), not a float >= 0"],
    "4 negative": ["{m}.read_timing (step 4): dt is -0.1 (float), not a float >= 0"],
    "4 zero": ["{m}.offset_by_motion (step 5): did not move the particles"],
    "7 NaN": ["{m}.transform_scan (step 7): world points (6, 6), not (6, 6, ...)"],
    "5 drops a particle": [
        "{m}.offset_by_motion (step 5): returns ndarray of 5 particles, not 6 ndarray"
    ],
    "5 returns None": [
        "{m}.offset_by_motion (step 5): returns NoneType of None particles, not 6 ndarray"
    ],
    "6 drops a particle": [
        "{m}.perturb_with_noise (step 6): returns ndarray of 5 particles, not 6 ndarray"
    ],
    "6 changes its input": [
        "{m}.perturb_with_noise (step 6): changed its input particles"
    ],
    "6 does not move": ["{m}.perturb_with_noise (step 6): did not move the particles"],
    "10 returns a copy": [
        "{m}.merge_scan (step 10): returns OccupancyGrid1D, not the map it was given"
    ],
    "8 changes the map": ["{m}.score_particles (step 8): changed the map"],
    "11 drops a particle": [
        "{m}.resample_particles (step 11): returns ndarray of 5 particles, not 6 ndarray"
    ],
    "11 changes its input": [
        "{m}.resample_particles (step 11): changed its input particles",
        "{m}.resample_particles (step 11): changed its input particles",
        "{m}.resample_particles (step 11): a set that needs no resampling changed",
    ],
    "11 linear weights": [
        "{m}.resample_particles (step 11): log_weights are not normalised: logsumexp = 1.9584261358947217, not 0",
        "{m}.resample_particles (step 11): log_weights are not normalised: logsumexp = 1.9584261358947217, not 0",
    ],
    "11 keeps the particles": [
        "{m}.resample_particles (step 11): "
        "a resampled degenerate set is not P copies of its heaviest particle at -log P"
    ],
    "11 reverses a kept set": [
        "{m}.resample_particles (step 11): a set that needs no resampling changed"
    ],
}


@pytest.mark.parametrize("which", list(EXACT_BREAKS_1D))
def test_the_returns_checker_says_word_for_word_what_each_planted_break_is(
    which, recording_1d, recording_2d
):
    example = _example(steps1d, recording_1d, recording_2d)
    name, make, _ = EXACT_BREAKS_1D[which]
    messages = EXACT_MESSAGES_1D[which]
    replaced = {name: make(steps1d, example)}
    if which.startswith("8 peak at 3"):
        replaced["pick_best_particle"] = lambda p, lw: (
            steps1d.pick_best_particle(p, lw)[0],
            0,
        )
    planted = _copy_of(steps1d, **replaced)
    assert check_steps_run(planted, example) == [
        m.replace("{m}", planted.__name__) for m in messages
    ]


class _PlantedAfter(_Planted):
    """A _Planted filter whose state read after its step is replaced (``after``: name -> function of the real
    value)."""

    def __init__(self, slam, after, **change):
        super().__init__(slam, **change)
        self.after, self.stepped = after, False

    particles = property(
        lambda self: (
            self.after.get("particles", lambda v: v)(self.slam.particles)
            if self.stepped
            else self.slam.particles
        )
    )
    log_weights = property(
        lambda self: (
            self.after.get("log_weights", lambda v: v)(self.slam.log_weights)
            if self.stepped
            else self.slam.log_weights
        )
    )

    def step(self, frame):
        self.stepped = True
        return super().step(frame)


def test_the_filter_step_checker_says_word_for_word_what_is_broken(
    recording_1d, recording_2d
):
    def run(after=None, estimate_is_best=True, **change):
        slam, frames, module, _ = _filter_1d(recording_1d, recording_2d, 0.0)
        slam.step(frames[0])
        filt = _PlantedAfter(slam, after or {}, **change)
        return check_filter_step(filt, frames[1], module, estimate_is_best)

    n = 12
    assert run() == []

    class _Dict(_Planted):
        def step(self, frame):
            return vars(self.slam.step(frame))

    slam, frames, module, _ = _filter_1d(recording_1d, recording_2d, 0.0)
    assert check_filter_step(_Dict(slam), frames[0], module) == [
        "_Dict.step returns dict, not StepInfo"
    ]
    problems = run(estimate=lambda i: object())
    assert len(problems) == 1 and problems[0].startswith(
        "_PlantedAfter.step: estimate is not a pose (TypeError: float() argument"
    ), problems
    # 3D may refine the estimate: then it need not be moved[best]
    assert run(estimate=lambda i: i.estimate + 1.0, estimate_is_best=False) == []
    # a best that is no int is reported as such, not looked up in moved
    assert run(best=lambda i: np.int64(i.best), estimate=lambda i: i.estimate + 1.0) == [
        "_PlantedAfter.step: best np.int64(10) is not the argmax of log_weights (an int)"
    ]
    assert run(best=lambda i: 0, estimate=lambda i: i.moved[0] + 1.0) == [
        "_PlantedAfter.step: best 0 is not the argmax of log_weights (an int)",
        "_PlantedAfter.step: estimate is not the pose of moved[best]",
    ]
    assert "_PlantedAfter.step: estimate is not the pose of moved[best]" not in run(
        best=lambda i: 0, estimate=lambda i: i.moved[0]
    )
    assert run(best=lambda i: n, estimate=lambda i: i.moved[0]) == [
        f"_PlantedAfter.step: best {n} is not the argmax of log_weights (an int)"
    ]
    problems = run(ess=lambda i: i.ess * (1 + 1e-7))
    assert len(problems) == 1 and problems[0].startswith("_PlantedAfter.step: ess ")
    assert problems[0].endswith(" is not 1 / sum(weights^2)")
    assert run(after={"particles": lambda p: p[1:]}) == [
        f"_PlantedAfter: holds {n - 1} particles after step, not {n}"
    ]
    assert run(after={"log_weights": lambda lw: lw + 1.0}) == [
        "_PlantedAfter: after step, log_weights are not normalised: "
        "logsumexp = 0.9999999999999998, not 0"
    ]
    assert run(
        after={"log_weights": lambda lw: normalise_log_weights(lw + np.arange(n))}
    ) == ["_PlantedAfter: not resampled, but its log-weights are not info.log_weights"]


def test_the_shared_constructor_reads_motion_noise_as_float64():
    """Any numbers are taken (ints, fractions); what float64 reads as NaN (None) is refused with a ValueError."""

    class Filter1D(StepsFilter):
        steps = steps1d

    for noise in ([1, 2, 0], Fraction(1, 10)):
        assert Filter1D(3, None, noise, np.random.default_rng(0)).motion_noise is noise
    for noise in (None, [0.1, -1]):
        with pytest.raises(ValueError, match="motion_noise must be finite and >= 0"):
            Filter1D(3, None, noise, np.random.default_rng(0))
