"""The 3D filter's settings (:mod:`slamlib.slam3d.config`): the groups' checks and the defaults ``of`` keeps."""

import json
import math

import pytest

from slamlib.slam3d import SLAM3DConfig


def test_config_rejects_bad_values():
    for bad, message in (
        (dict(kind="octree"), "map kind"),
        (dict(kind="voxel"), "now called 'voxel_hash'"),
        (dict(particles=0), "particles"),
        (dict(temperature=0.0), "temperature"),
        (dict(estimate="median"), "estimate"),
        (dict(min_range=5.0, max_range=4.0), "min_range"),
        (dict(voxel_size=0.3), "unknown SLAM3D setting 'voxel_size'"),
        (dict(tilt_sigma=-0.01), "tilt_sigma"),
        (dict(tilt_window=0.0), "tilt_window"),
        (dict(transient_span=-1), "transient_span must be >= 0"),
        (dict(tilt_heading_bins=0), "tilt_heading_bins must be >= 1"),
        (dict(transient_span=2.5), "transient_span must be an integer"),
        (
            dict(transient_span=10, kind="morton_bvh"),
            "transient_span needs the 'voxel_hash'",
        ),
    ):
        with pytest.raises(ValueError, match=message):
            SLAM3DConfig.of(**bad)


def test_config_changes_settings_by_name_and_keeps_the_other_defaults():
    """``of`` changes the named settings in their groups; the others keep their default values (written out here:
    tests/test_defaults.py checks that every signature repeating a setting has the config's value)."""
    c = SLAM3DConfig.of(particles=7, max_range=30.0, kind="morton_bvh", seed=4)
    assert (c.filter.particles, c.scan.max_range, c.map.kind, c.seed) == (
        7,
        30.0,
        "morton_bvh",
        4,
    )
    assert (c.scan.min_range, c.filter.scored_points, c.filter.ess_fraction) == (
        3.0,
        1000,
        0.5,
    )
    assert (c.filter.estimate, c.backend, c.map.prune_every) == ("best", "cpu", 20)
    d = c.as_dict()
    assert d["filter"]["particles"] == 7
    assert d["motion"]["sigma_xyz_per_m"] == [0.02, 0.02, 0.01]
    assert d["scan"]["min_range"] == 3.0 and d["map"]["params"] == {}
    json.dumps(d)


# ------------------------------------------------------------------ settings out of range
def test_min_range_above_max_range_is_refused():
    with pytest.raises(ValueError, match="min_range < max_range"):
        SLAM3DConfig.of(min_range=50.0, max_range=10.0)


@pytest.mark.parametrize(
    "kw,needle",
    [
        (dict(temperature=0), "temperature"),
        (dict(temperature=-1), "temperature"),
        (dict(temperature=math.nan), "temperature"),
        (dict(temperature=math.inf), "temperature"),
        (dict(seed=-1), "seed"),
        (dict(particles=10**9), "particles"),
        (dict(refine=-1), "refine"),
        (dict(refine=10**6), "refine"),
        (dict(ess_fraction=math.nan), "ess_fraction"),
        (dict(ess_fraction=1.5), "ess_fraction"),
        (dict(params={"voxel_size": -1}), "voxel_size"),
        (dict(params={"voxel_size": math.inf}), "voxel_size"),
        (dict(sigma_xyz_per_m=(-0.1, 0, 0)), "sigma_xyz_per_m"),
        (dict(sigma_rpy_per_s=(math.nan, 0, 0)), "sigma_rpy_per_s"),
        (dict(sigma_xyz_per_s=(math.inf, 0, 0)), "sigma_xyz_per_s"),
        (dict(downsample_voxel=-1), "downsample_voxel"),
        (dict(min_range=math.nan), "min_range"),
        (dict(particles=1_000_000, scored_points=1_000_000), "point scores"),
    ],
)
def test_config_rejects_out_of_range_settings(kw, needle):
    with pytest.raises(ValueError, match=needle):
        SLAM3DConfig.of(**kw)


def test_motion_noise_scaled_by_inf_is_refused():
    with pytest.raises(ValueError, match="finite"):
        SLAM3DConfig().motion.scaled(math.inf)
