"""Synthetic drives in the exact KITTI raw layout: routes, a procedural town, an HDL-64E model, OXTS packets.

Quick start::

    from slamlib.synth import default_drive
    import pykitti
    basedir, date, drive = default_drive()          # generated once into slamlib.paths.cache_dir()
    data = pykitti.raw(str(basedir), date, f"{drive:04d}")

Modules: :mod:`~slamlib.synth.routes` (trajectories), :mod:`~slamlib.synth.oxts` (30-field packets, IMU
noise), :mod:`~slamlib.synth.scene` (town mesh), :mod:`~slamlib.synth.lidar` (ray casting),
:mod:`~slamlib.synth.writer` (files), :mod:`~slamlib.synth.drive` (whole drives, cache),
:mod:`~slamlib.synth.traffic` (moving cars, cyclists and pedestrians). The default drive has traffic, swept scans and
wandering IMU biases; ``default_drive(realism=False)`` is the still one.
"""

from slamlib.synth.drive import (
    DEFAULT_FRAMES,
    GENERATOR_VERSION,
    default_drive,
    drive_traffic,
    resolve_route,
    write_drive,
    write_sequence,
)
from slamlib.synth.lidar import Hdl64, hdl64_elevations, ray_directions, simulate_scan
from slamlib.synth.oxts import WANDERING_BIASES, ZERO_NOISE, ImuNoise, oxts_packets
from slamlib.synth.routes import (
    ROUTE_NAMES,
    Route,
    get_route,
    kitti_route,
    loop_route,
    straight_route,
)
from slamlib.synth.scene import Scene, build_scene
from slamlib.synth.traffic import KITTI_CITY, Traffic, TrafficConfig, build_traffic

__all__ = [
    "default_drive",
    "drive_traffic",
    "write_drive",
    "write_sequence",
    "resolve_route",
    "DEFAULT_FRAMES",
    "GENERATOR_VERSION",
    "Hdl64",
    "hdl64_elevations",
    "ray_directions",
    "simulate_scan",
    "ImuNoise",
    "ZERO_NOISE",
    "WANDERING_BIASES",
    "oxts_packets",
    "Route",
    "get_route",
    "kitti_route",
    "loop_route",
    "straight_route",
    "ROUTE_NAMES",
    "Scene",
    "build_scene",
    "TrafficConfig",
    "Traffic",
    "build_traffic",
    "KITTI_CITY",
]
