"""``slamlib sim1d``: simulate the 1D world, run particle SLAM over it and compare with dead reckoning."""

from __future__ import annotations

from pathlib import Path

NAME = "sim1d"
HELP = (
    "Run 1D particle SLAM on a simulated line world; print SLAM vs dead-reckoning errors."
)


def add_arguments(parser) -> None:
    from slamlib.commands import parameter_default

    # from the defining modules: tests replace the names in slamlib.sim1d to check that main() stops early
    from slamlib.sim1d.filter import run_slam_1d
    from slamlib.sim1d.world import SensorModel1D, simulate

    particles = parameter_default(run_slam_1d, "n_particles")
    frames = parameter_default(simulate, "n_frames")
    parser.add_argument(
        "--particles",
        type=int,
        default=particles,
        help=f"number of particles P (default {particles})",
    )
    parser.add_argument(
        "--frames",
        type=int,
        default=frames,
        help=f"number of ~10 Hz frames (default {frames}, {frames * SensorModel1D.period:g} s)",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the world, the sensors and the filter",
    )
    parser.add_argument(
        "--motion-noise",
        type=float,
        default=SensorModel1D.velocity_noise,
        help="velocity sensor noise sigma_v in m/s (default "
        f"{SensorModel1D.velocity_noise:g}); the filter assumes the same",
    )
    parser.add_argument(
        "--sensor-noise",
        type=float,
        default=SensorModel1D.range_noise,
        help=f"range sensor noise sigma_r in m (default {SensorModel1D.range_noise:g}); the filter "
        "assumes the same",
    )
    parser.add_argument(
        "--bias",
        type=float,
        default=SensorModel1D.velocity_bias,
        help=f"velocity sensor bias in m/s (default {SensorModel1D.velocity_bias:g})",
    )
    parser.add_argument(
        "--plot",
        type=Path,
        default=None,
        metavar="PATH",
        help="write a figure of the run here",
    )
    parser.add_argument("--progress", action="store_true", help="show a progress bar")


#: Most particles and frames the command accepts: memory and time stay bounded (20,000 frames = 2,000 s of drive).
MAX_PARTICLES = 1_000_000
MAX_FRAMES = 20_000


def save_plot(fig, path: Path, command: str) -> None:
    """Write ``fig`` to ``path`` (its folder created) and close it; a write error exits with one line naming
    ``--plot``. Shared by the ``sim1d`` and ``sim2d`` commands."""
    import matplotlib.pyplot as plt

    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    except OSError as exc:
        raise SystemExit(
            f"slamlib {command}: --plot: could not write {path}: {exc}"
        ) from None
    finally:
        plt.close(fig)
    print(f"wrote {path}")


def check_plot_path(path: Path) -> None:
    """ValueError unless ``path`` can take a figure: a format matplotlib writes, not a folder, and a parent that
    exists or can be created under a writable folder. Checked before the run, not after it."""
    import os

    from matplotlib.figure import Figure

    formats = Figure().canvas.get_supported_filetypes()
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in formats:
        raise ValueError(
            f"{path}: unknown figure format {path.suffix or '(none)'!r}; use one of "
            f"{', '.join('.' + k for k in sorted(formats))}"
        )
    if path.is_dir():
        raise ValueError(f"{path} is a folder")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir() or not os.access(parent, os.W_OK):
        raise ValueError(f"cannot write {path}: {parent} is not a writable folder")


def main(args) -> int:
    import math

    import numpy as np

    from slamlib.sim1d import SensorModel1D, make_world, run_slam_1d, simulate

    if not 1 <= args.particles <= MAX_PARTICLES:
        raise SystemExit(
            f"slamlib sim1d: --particles must be in [1, {MAX_PARTICLES:,}], got {args.particles}"
        )
    if not 2 <= args.frames <= MAX_FRAMES:
        raise SystemExit(
            f"slamlib sim1d: --frames must be in [2, {MAX_FRAMES:,}], got {args.frames}"
        )
    if args.seed < 0:
        raise SystemExit(f"slamlib sim1d: --seed must be >= 0, got {args.seed}")
    for option, value in (
        ("--motion-noise", args.motion_noise),
        ("--sensor-noise", args.sensor_noise),
        ("--bias", args.bias),
    ):
        if not math.isfinite(value):
            raise SystemExit(f"slamlib sim1d: {option} must be finite, got {value}")
    if args.motion_noise < 0 or args.sensor_noise <= 0:
        raise SystemExit("slamlib sim1d: need --motion-noise >= 0 and --sensor-noise > 0")
    if args.plot is not None:
        try:
            check_plot_path(args.plot)
        except ValueError as exc:
            raise SystemExit(f"slamlib sim1d: --plot: {exc}") from None
    try:
        sensors = SensorModel1D(
            velocity_noise=args.motion_noise,
            range_noise=args.sensor_noise,
            velocity_bias=args.bias,
        )
        recording = simulate(
            make_world(seed=args.seed),
            n_frames=args.frames,
            seed=args.seed,
            sensors=sensors,
        )
        result = run_slam_1d(
            recording,
            n_particles=args.particles,
            seed=args.seed,
            progress=args.progress,
            keep_history=False,
        )
    except ValueError as exc:
        raise SystemExit(f"slamlib sim1d: {exc}") from None
    s = result.summary()
    lm = result.landmark_errors()
    print(
        f"1D particle SLAM: {args.particles} particles, {s['frames']} frames "
        f"({result.times[-1]:.1f} s, {result.true_positions[-1]:.1f} m), seed {args.seed}"
    )
    print(f"{'':18s}{'final |error| (m)':>20s}{'mean |error| (m)':>20s}")
    print(
        f"{'particle SLAM':18s}{s['slam_final_error_m']:20.3f}{s['slam_mean_error_m']:20.3f}"
    )
    print(
        f"{'dead reckoning':18s}{s['dead_reckoning_final_error_m']:20.3f}{s['dead_reckoning_mean_error_m']:20.3f}"
    )
    print(
        f"resampled on {s['resamplings']} of {s['frames']} frames; map: {result.landmarks_estimated.size} "
        f"landmarks, median error {np.median(lm) if lm.size else float('nan'):.3f} m "
        f"over {lm.size} observed"
    )
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")

        from slamlib.sim1d.plot import plot_result

        save_plot(plot_result(result, recording.sensors.max_range), args.plot, "sim1d")
    return 0
