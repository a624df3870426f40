"""The 3D filter's settings (:mod:`slamlib.slam3d.config`): the groups' checks and the defaults ``of`` keeps."""

import json

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
