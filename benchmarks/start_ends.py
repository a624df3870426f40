"""The LIDAR-only start's two searches on given drives: where each ended, how it scored, which the filter kept.

``python -m benchmarks.start_ends --data DIR --out FILE ROUTE:SEED[:TRAFFIC] ...`` generates (or reuses, in
``DIR``) each synthetic odometry drive of ``slamlib sweep`` (key frames 0:1000, KITTI-city traffic times
``TRAFFIC``, 1 by default), runs the default filter over its first three frames, and records the start search's
choice (:attr:`slamlib.slam3d.stages.Annealing.last_start`) beside the true motion over the first frame: the
positions in the start pose's frame (body axes, x forward, metres), the raw step-8 scores, and which search was
kept (``slamlib.slam3d.stages.search``, "The start's line"). A study of the start, not a timing: the drives it was
run on are named in the file, which ``book/defaults_record.md`` quotes.
"""

from __future__ import annotations

import argparse
import itertools
import json

import numpy as np

START_FRAMES = 3  # the first builds the map, the second is the start search's, the third the first held motion


def start_ends(route: str, seed: int, traffic: float, data) -> dict:
    """One drive's start: the searches' ends, scores and choice, and the true motion over the first frame."""
    from slamlib.experiments.sweep import DriveOptions, SweepTask, _frames_of, drive_task
    from slamlib.slam3d import SLAM3DConfig, run_drive

    task = SweepTask(
        route, (0, 1000), seed, "odometry", "slamlib", {}, DriveOptions(traffic=traffic)
    )
    frames = _frames_of(task, drive_task(task, data))
    gt = frames.ground_truth_poses()
    truth = (np.linalg.inv(gt[0]) @ gt[1])[:3, 3]
    run = run_drive(
        list(itertools.islice(iter(frames), START_FRAMES)),
        SLAM3DConfig.of(seed=seed),
        T_velo_imu=getattr(frames, "T_velo_imu", None),
        progress=False,
    )
    start = dict(run.slam.search.last_start)
    to_start = np.linalg.inv(run.slam.T0)  # world -> the start pose's frame
    for k in ("drawn", "line", "standstill"):
        start[k] = to_start[:3, :3] @ start[k] + to_start[:3, 3]
    return {
        "route": route,
        "seed": seed,
        "traffic": traffic,
        "truth": truth.round(4).tolist(),
        **{
            k: np.round(v, 4).tolist() if isinstance(v, np.ndarray) else v
            for k, v in start.items()
        },
    }


def main(argv=None) -> int:
    from slamlib.machine import describe

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("drives", nargs="+", help="ROUTE:SEED[:TRAFFIC]")
    parser.add_argument("--data", required=True, help="folder for the synthetic drives")
    parser.add_argument("--out", required=True, help="JSON file to write")
    args = parser.parse_args(argv)
    rows = []
    for spec in args.drives:
        route, seed, *traffic = spec.split(":")
        rows.append(
            start_ends(route, int(seed), float(traffic[0]) if traffic else 1.0, args.data)
        )
        print(json.dumps(rows[-1]), flush=True)
    out = {"benchmark": "start_ends", "machine": describe(), "rows": rows}
    with open(args.out, "w", encoding="utf-8") as f:
        json.dump(out, f, indent=1)
        f.write("\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
