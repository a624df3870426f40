"""The 3D filter's settings (:mod:`slamlib.slam3d.config`): the groups' checks and the defaults ``of`` keeps."""

import functools
import json
import math
import re
from pathlib import Path

import pytest

from slamlib.slam3d import SLAM3DConfig
from slamlib.slam3d.config import _PATHS


def test_config_rejects_bad_values():
    for bad, message in (
        (dict(kind="octree"), "map kind"),
        (dict(kind="voxel"), "now called 'voxel_hash'"),
        (dict(particles=0), "particles"),
        (dict(particles="many"), "particles must be an integer or 'auto'"),
        (dict(match_tolerance=0.0), "match_tolerance must be > 0"),
        (dict(match_gate=-1.0), "match_gate must be >= 0"),
        (dict(temperature=0.0), "temperature"),
        (dict(pose_estimate="median"), "pose_estimate"),
        (dict(min_range=5.0, max_range=4.0), "min_range"),
        (dict(voxel_sise=0.3), "unknown SLAM3D setting 'voxel_sise'"),
        (dict(tilt_sigma=-0.01), "tilt_sigma"),
        (dict(tilt_window=0.0), "tilt_window"),
        (dict(transient_span=-1), "transient_span must be >= 0"),
        (dict(tilt_heading_bins=0), "tilt_heading_bins must be >= 1"),
        (dict(tilt_up="gps"), "tilt_up must be one of 'velocity', 'positions'"),
        (dict(tilt_bias="median"), "tilt_bias must be one of 'sectors', 'kalman'"),
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
    assert (c.filter.pose_estimate, c.backend, c.upkeep.prune_every) == (
        "best",
        "cpu",
        20,
    )
    assert c.filter.particle_count() == c.filter.particle_count(lidar_only=True) == 7
    d = c.as_dict()
    assert d["filter"]["particles"] == 7
    assert d["motion"]["sigma_xyz_per_m"] == [0.02, 0.02, 0.01]
    assert d["scan"]["min_range"] == 3.0 and d["map"]["morton_bvh"]["radius"] == 0.3
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
        (dict(anneal_rounds=-1), "anneal_rounds"),
        (dict(anneal_rounds=10**6), "anneal_rounds"),
        (dict(ess_fraction=math.nan), "ess_fraction"),
        (dict(ess_fraction=1.5), "ess_fraction"),
        (dict(self_tuning="yes"), "self_tuning"),
        (dict(tuning_gain=0), "tuning_gain"),
        (dict(tuning_memory=math.inf), "tuning_memory"),
        (dict(tuning_noise_memory=-1), "tuning_noise_memory"),
        (dict(tuning_warmup=0), "tuning_warmup"),
        (dict(tuning_floor=(0.01,) * 5), "tuning_floor"),
        (dict(tuning_floor=(-0.01,) * 6), "tuning_floor"),
        (dict(tilt_sigma="strong"), "tilt_sigma"),
        (dict(tilt_sigma="adaptiv"), "'adaptive'"),
        (dict(collapse_ess=1.5), "collapse_ess"),
        (dict(collapse_rounds=-1), "collapse_rounds"),
        ({"constant_velocity.start_line": "yes"}, "start_line must be"),
        (dict(voxel_size=-1), "voxel_size"),
        (dict(voxel_hash={"voxel_size": math.inf}), "voxel_size"),
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


def test_settings_by_stage_group_nested_group_and_dotted_name():
    c = SLAM3DConfig.of(
        anneal_rounds=2,
        tilt_sigma=0.003,
        scan_match=True,
        constant_velocity={"window": 3},
        **{"constant_velocity.ground_share": 0.5},
        radius=0.2,
    )
    assert (c.search.anneal_rounds, c.prior.tilt_sigma, c.polish.scan_match) == (
        2,
        0.003,
        True,
    )
    cv = c.motion.constant_velocity
    assert (cv.window, cv.ground_share, cv.start_rounds) == (3, 0.5, 8)
    assert cv.start_line is True  # the forward line at the start, on by default
    off = SLAM3DConfig.of(**{"constant_velocity.start_line": False})
    assert off.motion.constant_velocity.start_line is False
    assert c.map.morton_bvh.radius == 0.2 and c.map.params == c.map.voxel_hash.__dict__
    # the constructor's default
    assert SLAM3DConfig.of(kind="morton_bvh").map.make().radius == 0.3
    with pytest.raises(ValueError, match="deskew must be True, False or 'auto'"):
        SLAM3DConfig.of(deskew="yes")


@pytest.mark.parametrize(
    "old,value,new,get",
    [
        ("refine", 2, "anneal_rounds", lambda c: c.search.anneal_rounds),
        ("refine_shrink", 0.3, "anneal_shrink", lambda c: c.search.anneal_shrink),
        ("estimate", "mean", "pose_estimate", lambda c: c.filter.pose_estimate),
        (
            "cv_window",
            3,
            "constant_velocity.window",
            lambda c: c.motion.constant_velocity.window,
        ),
        (
            "cv_start_rounds",
            0,
            "constant_velocity.start_rounds",
            lambda c: c.motion.constant_velocity.start_rounds,
        ),
        (
            "lidar_only_ground_share",
            1.0,
            "constant_velocity.ground_share",
            lambda c: c.motion.constant_velocity.ground_share,
        ),
        (
            "params",
            {"voxel_size": 0.3},
            "voxel_hash",
            lambda c: {"voxel_size": c.map.voxel_hash.voxel_size},
        ),
    ],
)
def test_the_names_before_the_stages_still_work_with_a_deprecation_warning(
    old, value, new, get
):
    with pytest.warns(DeprecationWarning, match=new):
        c = SLAM3DConfig.of(**{old: value})
    assert get(c) == value


@pytest.mark.parametrize("name", ["deskew", "scan_match"])
def test_none_for_a_tri_state_is_auto_with_a_deprecation_warning(name):
    with pytest.warns(DeprecationWarning, match=f"{name}='auto'"):
        c = SLAM3DConfig.of(**{name: None})
    assert getattr(c.scan if name == "deskew" else c.polish, name) == "auto"


def _reference_entries() -> dict[str, str]:
    """``book/defaults.md``'s definition list: each term's setting names -> the definition's text."""
    text = (Path(__file__).resolve().parents[1] / "book" / "defaults.md").read_text(
        encoding="utf-8"
    )
    entries = {}
    for term, definition in re.findall(
        r"^(`[^\n]+)\n: (.*?)(?=\n\n|\Z)", text, re.M | re.S
    ):
        for name in re.findall(r"`([\w.]+)`", term):
            entries[name] = " ".join(definition.split())
    return entries


def _shown(value) -> list[str]:
    """The ways the reference may print a default: each element of a tuple, numbers as written or with
    thousands separators, strings quoted."""
    if isinstance(value, tuple):
        return [s for v in value for s in _shown(v)]
    if isinstance(value, str):
        return [f'"{value}"']
    if isinstance(value, bool):
        return [str(value)]
    return [f"{value:g}".replace("e-05", "e-5"), f"{value:,}"]


def test_the_settings_reference_lists_every_setting_with_its_default():
    """``book/defaults.md`` has an entry for every name :meth:`SLAM3DConfig.setting_names` takes (a map
    parameter by its own name), and each entry states the default: every element of it, as written."""
    config, entries = SLAM3DConfig(), _reference_entries()
    names = [
        n
        for n in SLAM3DConfig.setting_names()
        if not n.startswith(("voxel_hash.", "morton_bvh."))
    ]
    missing = [n for n in names if n not in entries]
    assert not missing, f"book/defaults.md lacks {missing}"
    for name in names:
        value = functools.reduce(getattr, _PATHS.get(name, (name,)), config)
        elements = value if isinstance(value, tuple) else (value,)
        for element in elements:
            assert any(s in entries[name] for s in _shown(element)), (
                f"book/defaults.md's entry of {name} does not state its default {value!r}"
            )
    unknown = sorted(set(entries) - set(SLAM3DConfig.setting_names()))
    assert not unknown, f"book/defaults.md lists settings that do not exist: {unknown}"
