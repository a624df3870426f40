"""``slamlib sim2d``: simulate the planar courtyard, run 2D particle SLAM with either map, compare with dead
reckoning."""

from __future__ import annotations

from pathlib import Path

NAME = "sim2d"
HELP = "Run 2D particle SLAM (density grid or likelihood field) on a simulated courtyard; print ATE vs dead reckoning."


def add_arguments(parser) -> None:
    from slamlib.commands import parameter_default

    # from the defining modules: tests replace the names in slamlib.sim2d to check that main() stops early
    from slamlib.sim2d.filter import run_slam_2d
    from slamlib.sim2d.world import SensorModel2D, simulate

    particles = parameter_default(run_slam_2d, "n_particles")
    laps = parameter_default(simulate, "laps")
    resolution = parameter_default(run_slam_2d, "resolution")
    parser.add_argument(
        "--particles",
        type=int,
        default=particles,
        help=f"number of particles P (default {particles})",
    )
    parser.add_argument(
        "--laps",
        type=float,
        default=laps,
        help=f"laps of the ~76 m loop (default {laps:g})",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the world, the sensors and the filter",
    )
    parser.add_argument(
        "--map",
        choices=("likelihood", "density", "both"),
        default="both",
        help="map kind: likelihood field, the seed's density grid, or both (default)",
    )
    parser.add_argument(
        "--resolution",
        type=float,
        default=resolution,
        help=f"map cell size in m (default {resolution:g})",
    )
    parser.add_argument(
        "--beams",
        type=int,
        default=SensorModel2D.n_beams,
        help=f"LIDAR beams over 360 degrees (default {SensorModel2D.n_beams})",
    )
    parser.add_argument(
        "--plot",
        type=Path,
        default=None,
        metavar="PATH",
        help="write a figure of the paths here",
    )
    parser.add_argument("--progress", action="store_true", help="show a progress bar")


#: Option bounds that keep time and memory bounded (the world is a ~76 m loop: at 1 cm a grid is ~10 million cells).
MAX_PARTICLES = 100_000
MAX_LAPS = 50.0
MIN_RESOLUTION_M, MAX_RESOLUTION_M = 0.01, 5.0
MAX_BEAMS = 3600


def main(args) -> int:
    from slamlib.commands.sim1d import check_plot_path, save_plot
    from slamlib.sim2d import SensorModel2D, make_world, run_slam_2d, simulate

    for option, value, low, high in (
        ("--particles", args.particles, 1, MAX_PARTICLES),
        ("--laps", args.laps, 0.0, MAX_LAPS),
        ("--resolution", args.resolution, MIN_RESOLUTION_M, MAX_RESOLUTION_M),
        ("--beams", args.beams, 1, MAX_BEAMS),
    ):
        if not (low <= value <= high) or (option == "--laps" and value == 0):
            what = "in (0, " if option == "--laps" else f"in [{low:g}, "
            raise SystemExit(
                f"slamlib sim2d: {option} must be {what}{high:g}], got {value}"
            )
    if args.seed < 0:
        raise SystemExit(f"slamlib sim2d: --seed must be >= 0, got {args.seed}")
    if args.plot is not None:
        try:
            check_plot_path(args.plot)
        except ValueError as exc:
            raise SystemExit(f"slamlib sim2d: --plot: {exc}") from None
    world = make_world(seed=args.seed)
    recording = simulate(
        world, laps=args.laps, seed=args.seed, sensors=SensorModel2D(n_beams=args.beams)
    )
    kinds = ("density", "likelihood") if args.map == "both" else (args.map,)
    results = {
        kind: run_slam_2d(
            recording,
            n_particles=args.particles,
            seed=args.seed,
            map_kind=kind,
            resolution=args.resolution,
            progress=args.progress,
        )
        for kind in kinds
    }
    first = next(iter(results.values()))
    print(
        f"2D particle SLAM: {args.particles} particles, {len(recording)} frames ({recording.times[-1]:.1f} s, "
        f"{args.laps:g} lap(s)), {args.resolution:g} m cells, seed {args.seed}"
    )
    print(f"{'':26s}{'ATE (m)':>10s}{'final error (m)':>18s}{'final heading (deg)':>22s}")
    for kind, res in results.items():
        s = res.summary()
        print(
            f"{'SLAM, ' + kind:26s}{s['slam_ate_m']:10.3f}{s['slam_final_error_m']:18.3f}"
            f"{s['slam_final_heading_error_deg']:22.2f}"
        )
    s = first.summary()
    print(
        f"{'dead reckoning':26s}{s['dead_reckoning_ate_m']:10.3f}{s['dead_reckoning_final_error_m']:18.3f}"
        f"{s['dead_reckoning_final_heading_error_deg']:22.2f}"
    )
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")

        from slamlib.sim2d.plot import plot_trajectories

        save_plot(
            plot_trajectories(
                first, world, label=f"particle SLAM, {next(iter(results))}"
            ),
            args.plot,
            "sim2d",
        )
    return 0
