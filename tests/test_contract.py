"""The twelve-step contract (slamlib.contract): every dimension's steps module keeps it, the checker can fail, and
the 1D and 2D filters share one loop (StepsFilter.step) and one StepInfo."""

import inspect
import types

import numpy as np
import pytest

import slamlib.sim1d.steps as steps1d
import slamlib.sim2d.steps as steps2d
import slamlib.slam3d.steps as steps3d
from slamlib.contract import LOOP_ORDER, STEPS, StepInfo, StepsFilter, check_steps_module
from slamlib.resampling import normalise_log_weights
from slamlib.sim1d import OccupancyGrid1D, ParticleSLAM1D
from slamlib.sim1d import make_world as make_world_1d
from slamlib.sim1d import simulate as simulate_1d
from slamlib.sim2d import OccupancyGrid2D, ParticleSLAM2D
from slamlib.sim2d import make_world as make_world_2d
from slamlib.sim2d import simulate as simulate_2d

IDS = ["1D", "2D", "3D"]


@pytest.fixture(scope="module")
def recording_1d():
    return simulate_1d(make_world_1d(seed=0), n_frames=12, seed=0)


@pytest.fixture(scope="module")
def recording_2d():
    return simulate_2d(make_world_2d(seed=0), laps=0.1, seed=0)


@pytest.mark.parametrize("module", [steps1d, steps2d, steps3d], ids=["1D", "2D", "3D"])
def test_steps_module_keeps_the_contract(module):
    assert check_steps_module(module) == []
    assert [s.number for s in STEPS] == list(range(1, 12))


def test_the_checker_finds_a_missing_step_a_wrong_order_and_an_extra_required_parameter():
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


@pytest.mark.parametrize("module", [steps1d, steps3d], ids=["1D", "3D"])
def test_shared_parameters_alone_run_a_step_at_every_dimension(module):
    """Steps 1, 5, 9 and 11 called with the contract's parameters only; log-weights in and out."""
    particles, log_w = module.initialise_particles(8)
    assert len(particles) == 8 and np.allclose(np.exp(log_w).sum(), 1.0)
    imu = 2.0 if module is steps1d else (np.array([2.0, 0, 0]), np.zeros(3))
    moved = module.offset_by_motion(particles, imu, 0.5)
    pose, i = module.pick_best_particle(moved, log_w)
    assert i == 0  # ties go to the lowest index
    x = pose if module is steps1d else pose[0, 3]
    assert x == pytest.approx(1.0)  # 2 m/s for 0.5 s along x
    peaked = np.log(np.r_[1.0, np.full(7, 1e-9)])
    out, out_log_w, resampled = module.resample_particles(
        moved, peaked, np.random.default_rng(0)
    )
    assert resampled and len(out) == 8 and np.allclose(out_log_w, -np.log(8))


# ------------------------------------------------------------------------------------------ the filters
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


# ------------------------------------------------------------------------------- the loop 1D and 2D share
def test_1d_and_2d_filters_share_the_loop_the_state_and_the_constructor():
    for cls in (ParticleSLAM1D, ParticleSLAM2D):
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
    slam.steps = recorder = _Recorder(
        module
    )  # on the instance: the class keeps its module
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
