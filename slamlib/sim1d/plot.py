"""Figures for the 1D particle SLAM chapter and the ``slamlib sim1d --plot`` command (matplotlib, imported lazily).

Every function draws on axes it is given (or creates a figure) and returns the figure; nothing is shown or saved
here, so callers decide (``fig.savefig``, notebook display, ``plt.close``).
"""

from __future__ import annotations

import numpy as np

from slamlib.plotstyle import BOOK_DPI, MAX_FIGURE_WIDTH_IN, legend_below

__all__ = ["animate_run", "plot_map", "plot_result", "plot_world"]


def plot_world(recording, ax=None, frame: int | None = None):
    """The line world: landmarks (ticks), the colonnade span, the vehicle's path and, optionally, one frame's scan."""
    import matplotlib.pyplot as plt

    fig, ax = (
        (ax.figure, ax)
        if ax is not None
        else plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 2.6))
    )
    world = recording.world
    c0, c1, spacing = world.colonnade
    if spacing > 0:
        ax.axvspan(
            c0 - spacing / 2,
            c1 + spacing / 2,
            color="0.9",
            label="colonnade (repetitive)",
        )
    ax.vlines(
        world.landmarks,
        0,
        1,
        color="k",
        lw=1.5,
        label="landmarks (unknown to the filter)",
    )
    x = recording.true_positions
    height = np.linspace(0.15, 0.85, x.size)
    ax.plot(x, height, color="C0", lw=1, label="vehicle path (height = time)")
    if frame is not None:
        xk = x[frame]
        ax.plot(
            [xk],
            [height[frame]],
            "o",
            color="C3",
            ms=8,
            label=f"vehicle at frame {frame}",
        )
        scan = recording.frames[frame].scan
        ax.plot(
            xk + scan,
            np.full(scan.size, height[frame]),
            "x",
            color="C3",
            ms=8,
            mew=2,
            label="its scan returns",
        )
        r = recording.sensors.max_range
        ax.axvspan(xk - r, xk + r, color="C3", alpha=0.08, label="sensor range")
    ax.set_yticks([])
    ax.set_xlabel("x (m)")
    ax.legend(loc="upper left", ncol=2, framealpha=0.9)
    ax.set_ylim(0, 1.35)
    return fig


def plot_map(
    grid,
    ax=None,
    landmarks_true=None,
    landmarks_estimated=None,
    xlim=None,
    label="map counts",
):
    """The occupancy-count grid as a bar plot, with true (black) and extracted (orange) landmarks."""
    import matplotlib.pyplot as plt

    fig, ax = (
        (ax.figure, ax)
        if ax is not None
        else plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 2.8))
    )
    nz = grid.counts > 0
    ax.bar(
        grid.centres[nz], grid.counts[nz], width=grid.resolution, color="C0", label=label
    )
    if landmarks_true is not None:
        ax.vlines(
            landmarks_true,
            0,
            -0.08 * max(1, grid.counts.max()),
            color="k",
            lw=1.5,
            label="true landmarks",
        )
    if landmarks_estimated is not None and len(landmarks_estimated):
        ax.plot(
            landmarks_estimated,
            np.zeros(len(landmarks_estimated)),
            "^",
            color="C1",
            ms=6,
            label="landmarks read off the map",
        )
    if xlim is not None:
        ax.set_xlim(*xlim)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("returns per cell")
    legend_below(ax)  # the bars fill the axes: no corner is free
    return fig


def plot_result(result, max_range: float | None = None):
    """Three panels: position over time (true, SLAM, dead reckoning), ``|error|`` over time, map vs true landmarks."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        3,
        1,
        figsize=(MAX_FIGURE_WIDTH_IN, 8.6),
        gridspec_kw={"height_ratios": [2, 1.4, 1.4]},
    )
    t = result.times
    ax = axes[0]
    ax.plot(t, result.true_positions, "k", lw=2, label="true")
    ax.plot(t, result.estimated, "C0", lw=1.2, label="particle SLAM (best particle)")
    ax.plot(
        t, result.dead_reckoned, "C3--", lw=1.2, label="dead reckoning (velocity only)"
    )
    ax.set_ylabel("x (m)")
    ax.legend()
    ax.set_title("position")
    ax = axes[1]
    floor = 1e-3  # log axis: errors below 1 mm drawn at 1 mm
    ax.plot(
        t,
        np.maximum(result.slam_error, floor),
        "C0",
        label=f"SLAM (mean {result.slam_error.mean():.3f} m)",
    )
    ax.plot(
        t,
        np.maximum(result.dead_reckoning_error, floor),
        "C3--",
        label=f"dead reckoning (mean {result.dead_reckoning_error.mean():.3f} m)",
    )
    ax.set_yscale("log")
    ax.set_ylabel("|error| (m, log)")
    ax.set_xlabel("t (s)")
    legend_below(ax, ncols=2)
    lo = result.true_positions.min() - (max_range or 10.0)
    hi = result.true_positions.max() + (max_range or 10.0)
    plot_map(
        result.grid,
        axes[2],
        result.landmarks_true,
        result.landmarks_estimated,
        xlim=(lo, hi),
        label="final map (counts)",
    )
    fig.tight_layout()
    return fig


def animate_run(
    result,
    n_frames: int = 60,
    figsize=(MAX_FIGURE_WIDTH_IN, 4.2),
    interval: int = 100,
    dpi: int = BOOK_DPI,
    window: float = 0.5,
):
    """A ``FuncAnimation`` of the filter: particles (weighted), truth, estimate and the map growing.

    Uses ``result.particle_history``, ``weight_history`` and ``map_history`` (run with ``keep_history=True``),
    subsampled to ``n_frames`` frames; ``window`` is the half-width (m) of the particle panel around the truth,
    ``dpi`` the resolution of the frames (the book's, so that its fonts read at 10 pt or more; ``to_jshtml`` embeds
    every frame as a PNG, so keep ``n_frames`` modest). The caller
    closes the figure (``plt.close(anim._fig)``) after rendering, e.g. with ``anim.to_jshtml()``.
    """
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    if result.particle_history is None or result.map_history is None:
        raise ValueError(
            "animate_run needs a result from run_slam_1d(..., keep_history=True)"
        )
    ks = np.unique(np.linspace(0, result.times.size - 1, n_frames).round().astype(int))
    grid = result.grid
    lo = result.true_positions.min() - 10.0
    hi = result.true_positions.max() + 10.0
    cells = slice(
        max(0, int(grid.cell_of(lo))), min(grid.counts.size, int(grid.cell_of(hi)) + 1)
    )
    centres = grid.centres[cells]
    ymax = max(1, int(result.map_history[-1, cells].max()))
    fig, (ax_p, ax_m) = plt.subplots(
        2, 1, figsize=figsize, dpi=dpi, gridspec_kw={"height_ratios": [1, 1.2]}
    )
    # persistent artists, updated per frame (much faster than redrawing the axes)
    cloud = ax_p.scatter(
        np.zeros(0), np.zeros(0), s=6, c="C0", alpha=0.6, label="particles (weight x P)"
    )
    ax_p.axvline(0, color="k", lw=1.5, label="truth")
    best_line = ax_p.axvline(0, color="C2", lw=1.2, label="best particle")
    dr_line = ax_p.axvline(0, color="C3", ls="--", lw=1.2, label="dead reckoning")
    ax_p.set_xlim(-window, window)
    ax_p.set_ylim(0, 6.5)  # headroom for the legend above the cloud
    ax_p.set_xlabel("position relative to truth (m)")
    ax_p.legend(loc="upper left", ncol=2)
    (map_line,) = ax_m.plot(
        centres, np.zeros(centres.size), color="C0", lw=0.8, label="map counts"
    )
    ax_m.vlines(
        result.landmarks_true, -0.08 * ymax, 0, color="k", lw=1, label="true landmarks"
    )
    vehicle = ax_m.axvline(0, color="C3", lw=1, label="vehicle")
    ax_m.set_xlim(lo, hi)
    ax_m.set_ylim(-0.08 * ymax, ymax * 1.05)
    ax_m.set_xlabel("x (m)")
    ax_m.legend(loc="upper right", ncol=3)
    title = fig.suptitle("\n")  # two lines, as in draw(), so tight_layout leaves room
    fig.tight_layout()

    def draw(i):
        k = ks[i]
        x_true = result.true_positions[k]
        p = result.particle_history[k].astype(np.float64) - x_true
        cloud.set_offsets(np.column_stack([p, result.weight_history[k] * p.size]))
        best_line.set_xdata([result.estimated[k] - x_true] * 2)
        dr_line.set_xdata([result.dead_reckoned[k] - x_true] * 2)
        map_line.set_ydata(result.map_history[k, cells])
        vehicle.set_xdata([x_true] * 2)
        title.set_text(
            f"frame {k}, t = {result.times[k]:.1f} s: best particle off by "
            f"{result.estimated[k] - x_true:+.3f} m,\ndead reckoning by "
            f"{result.dead_reckoned[k] - x_true:+.2f} m"
        )
        return [cloud, best_line, dr_line, map_line, vehicle, title]

    return FuncAnimation(fig, draw, frames=len(ks), interval=interval, blit=False)
