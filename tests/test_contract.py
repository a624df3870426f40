"""The twelve-step contract (slamlib.contract): every dimension's steps module keeps it, and the checker can fail."""

import types

import numpy as np
import pytest

import slamlib.sim1d.steps as steps1d
import slamlib.sim2d.steps as steps2d
import slamlib.slam3d.steps as steps3d
from slamlib.contract import STEPS, check_steps_module


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
