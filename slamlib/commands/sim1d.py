"""``slamlib sim1d``: simulate the 1D world, run particle SLAM over it and compare with dead reckoning."""

from __future__ import annotations

from pathlib import Path

NAME = "sim1d"
HELP = "Run 1D particle SLAM on a simulated line world; print SLAM vs dead-reckoning errors."


def add_arguments(parser) -> None:
    parser.add_argument("--particles", type=int, default=200, help="number of particles P (default 200)")
    parser.add_argument("--frames", type=int, default=300, help="number of ~10 Hz frames (default 300, 30 s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the world, the sensors and the filter")
    parser.add_argument("--motion-noise", type=float, default=0.2,
                        help="velocity sensor noise sigma_v in m/s (default 0.2); the filter assumes the same")
    parser.add_argument("--sensor-noise", type=float, default=0.05,
                        help="range sensor noise sigma_r in m (default 0.05); the filter assumes the same")
    parser.add_argument("--bias", type=float, default=0.1, help="velocity sensor bias in m/s (default 0.1)")
    parser.add_argument("--plot", type=Path, default=None, metavar="PATH", help="write a figure of the run here")
    parser.add_argument("--progress", action="store_true", help="show a progress bar")


def main(args) -> int:
    import numpy as np

    from slamlib.sim1d import SensorModel1D, make_world, run_slam_1d, simulate

    if args.particles < 1 or args.frames < 2:
        raise SystemExit("slamlib sim1d: need --particles >= 1 and --frames >= 2")
    if args.motion_noise < 0 or args.sensor_noise <= 0:
        raise SystemExit("slamlib sim1d: need --motion-noise >= 0 and --sensor-noise > 0")
    sensors = SensorModel1D(velocity_noise=args.motion_noise, range_noise=args.sensor_noise,
                            velocity_bias=args.bias)
    recording = simulate(make_world(seed=args.seed), n_frames=args.frames, seed=args.seed, sensors=sensors)
    result = run_slam_1d(recording, n_particles=args.particles, seed=args.seed, progress=args.progress,
                         keep_history=False)
    s = result.summary()
    lm = result.landmark_errors()
    print(f"1D particle SLAM: {args.particles} particles, {s['frames']} frames "
          f"({result.times[-1]:.1f} s, {result.true_positions[-1]:.1f} m), seed {args.seed}")
    print(f"{'':18s}{'final |error| (m)':>20s}{'mean |error| (m)':>20s}")
    print(f"{'particle SLAM':18s}{s['slam_final_error_m']:20.3f}{s['slam_mean_error_m']:20.3f}")
    print(f"{'dead reckoning':18s}{s['dead_reckoning_final_error_m']:20.3f}{s['dead_reckoning_mean_error_m']:20.3f}")
    print(f"resampled on {s['resamplings']} of {s['frames']} frames; map: {result.landmarks_estimated.size} "
          f"landmarks, median error {np.median(lm) if lm.size else float('nan'):.3f} m "
          f"over {lm.size} observed")
    if args.plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from slamlib.sim1d.plot import plot_result

        fig = plot_result(result, recording.sensors.max_range)
        args.plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.plot, dpi=110)
        plt.close(fig)
        print(f"wrote {args.plot}")
    return 0
