"""Figures for the 2D particle SLAM chapter (matplotlib, imported lazily).

Every function draws on axes it is given (or creates a figure sized for a ~700 px column: at most 9 in wide at
100 dpi) and returns the figure; nothing is shown or saved here.
"""

from __future__ import annotations

import numpy as np

from slamlib.plotstyle import BOOK_DPI, MAX_FIGURE_WIDTH_IN, legend_below

__all__ = [
    "animate_run",
    "draw_world",
    "plot_errors",
    "plot_heading_lever",
    "plot_map",
    "plot_particles",
    "plot_trajectories",
    "plot_world",
]


def draw_world(world, ax, color="k", lw=1.2, alpha=1.0, label="walls and pillars"):
    """Walls (segments) and pillars (circles) of ``world`` on ``ax`` (m, equal aspect)."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Circle

    ax.add_collection(
        LineCollection(
            world.segments, colors=color, linewidths=lw, alpha=alpha, label=label
        )
    )
    for cx, cy, r in world.circles:
        ax.add_patch(Circle((cx, cy), r, fill=False, ec=color, lw=lw, alpha=alpha))
    lo, hi = world.bounds
    ax.set_xlim(lo[0] - 1, hi[0] + 1)
    ax.set_ylim(lo[1] - 1, hi[1] + 1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")


def _vehicle(ax, pose, color="C3", size=0.8, label=None):
    x, y, th = pose
    ax.plot([x], [y], "o", color=color, ms=6, label=label)
    ax.arrow(
        x,
        y,
        size * np.cos(th),
        size * np.sin(th),
        color=color,
        width=0.06,
        length_includes_head=True,
    )


def plot_world(recording, frame: int | None = None, ax=None, rays: bool = True):
    """The world, the route driven and, for ``frame``, the vehicle with its LIDAR scan (beams and returns)."""
    import matplotlib.pyplot as plt

    from slamlib.sim2d.steps import transform_scan

    fig, ax = (
        (ax.figure, ax)
        if ax is not None
        else plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 4.8))
    )
    draw_world(recording.world, ax)
    ax.plot(*recording.true_poses[:, :2].T, color="C0", lw=1, label="route (true path)")
    if frame is not None:
        pose = recording.true_poses[frame]
        pts = transform_scan(pose, recording.frames[frame].scan)
        if rays:
            for p in pts[::3]:
                ax.plot([pose[0], p[0]], [pose[1], p[1]], color="C3", lw=0.3, alpha=0.4)
        ax.plot(*pts.T, ".", color="C3", ms=3, label=f"LIDAR returns, frame {frame}")
        _vehicle(ax, pose, label="vehicle (heading arrow)")
    legend_below(
        ax, fontsize=10
    )  # the route and the scan reach every corner of the world
    return fig


def plot_heading_lever(recording, frame: int, dtheta_deg: float = 2.0, dxy: float = 0.1):
    """Why heading noise dominates: one scan placed with a heading error ``dtheta`` and with a shift ``dxy``.

    Left: the scan at the true pose (black), rotated by ``dtheta`` about the vehicle (red) and shifted by ``dxy``
    metres sideways (blue). Right: each point's displacement against its range: ``r dtheta`` for the heading
    error, a constant ``dxy`` for the shift.
    """
    import matplotlib.pyplot as plt

    from slamlib.sim2d.steps import transform_scan

    pose = recording.true_poses[frame]
    q = recording.frames[frame].scan
    dth = np.radians(dtheta_deg)
    truth = transform_scan(pose, q)
    rotated = transform_scan(pose + [0, 0, dth], q)
    side = np.array([-np.sin(pose[2]), np.cos(pose[2])]) * dxy
    shifted = truth + side
    fig, (ax0, ax1) = plt.subplots(
        1, 2, figsize=(MAX_FIGURE_WIDTH_IN, 4.2), gridspec_kw={"width_ratios": [1.4, 1]}
    )
    draw_world(recording.world, ax0, color="0.6", lw=0.8)
    ax0.plot(*truth.T, ".", color="k", ms=3, label="scan at the true pose")
    ax0.plot(
        *rotated.T, ".", color="C3", ms=3, label=f"heading off by {dtheta_deg:g} deg"
    )
    ax0.plot(*shifted.T, ".", color="C0", ms=2, label=f"position off by {dxy * 100:g} cm")
    _vehicle(ax0, pose)
    legend_below(ax0, ncols=2, fontsize=10)
    r = np.hypot(*q.T)
    ax1.plot(
        r,
        np.hypot(*(rotated - truth).T) * 100,
        ".",
        color="C3",
        ms=3,
        label="heading error: r dtheta",
    )
    ax1.plot(
        r,
        np.hypot(*(shifted - truth).T) * 100,
        ".",
        color="C0",
        ms=3,
        label="position error",
    )
    ax1.set_xlabel("range r of the return (m)")
    ax1.set_ylabel("displacement of the return (cm)")
    legend_below(ax1, ncols=1, fontsize=10)
    fig.tight_layout()
    return fig


def plot_map(world_map, ax=None, world=None, title: str | None = None, window=None):
    """The map as its ``kind`` scores it: saturated hit density (density grid) or the likelihood field ``F``."""
    import matplotlib.pyplot as plt

    fig, ax = (
        (ax.figure, ax)
        if ax is not None
        else plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 4.8))
    )
    img = world_map.density() if world_map.kind == "density" else world_map.field
    im = ax.imshow(
        img,
        origin="lower",
        extent=world_map.extent,
        cmap="Greys",
        vmin=0,
        vmax=1,
        interpolation="nearest",
    )
    if world is not None:
        draw_world(world, ax, color="C1", lw=0.6, alpha=0.8, label="true structure")
    if window is not None:
        (x0, x1), (y0, y1) = window
        ax.set_xlim(x0, x1)
        ax.set_ylim(y0, y1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        title
        or (
            "density grid: min(n, n_sat) / n_sat"
            if world_map.kind == "density"
            else "likelihood field F"
        ),
        fontsize=10,
    )
    fig.colorbar(im, ax=ax, shrink=0.8)
    return fig


def plot_particles(
    particles, weights, truth, ax=None, title: str | None = None, best: int | None = None
):
    """Particle positions relative to the truth (cm), coloured by weight (the heavier drawn on top)."""
    import matplotlib.pyplot as plt

    fig, ax = (ax.figure, ax) if ax is not None else plt.subplots(figsize=(4.5, 4))
    d = (np.asarray(particles)[:, :2] - truth[:2]) * 100
    order = np.argsort(weights)
    sc = ax.scatter(
        d[order, 0], d[order, 1], c=np.asarray(weights)[order], s=12, cmap="viridis"
    )
    ax.plot([0], [0], "k+", ms=14, mew=2, label="truth")
    if best is not None:
        ax.plot(*d[best], "o", mfc="none", mec="C3", ms=12, mew=2, label="best particle")
    ax.set_xlabel("x - x_true (cm)")
    ax.set_ylabel("y - y_true (cm)")
    ax.set_aspect("equal")
    ax.legend(fontsize=10, loc="upper right")
    if title:
        ax.set_title(title, fontsize=10)
    fig.colorbar(sc, ax=ax, shrink=0.8, label="weight")
    return fig


def plot_trajectories(result, world=None, ax=None, label: str = "particle SLAM"):
    """True path, SLAM estimate and dead reckoning in the plane."""
    import matplotlib.pyplot as plt

    fig, ax = (
        (ax.figure, ax)
        if ax is not None
        else plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 4.8))
    )
    if world is not None:
        draw_world(world, ax, color="0.6", lw=0.8)
    ax.plot(*result.true_poses[:, :2].T, "k", lw=2.5, label="truth")
    ax.plot(
        *result.estimated[:, :2].T,
        "C0",
        lw=1.2,
        label=f"{label} (ATE {result.ate * 100:.1f} cm)",
    )
    ax.plot(
        *result.dead_reckoned[:, :2].T,
        "C3--",
        lw=1.2,
        label=f"dead reckoning (ATE {result.ate_dead_reckoning:.2f} m)",
    )
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    legend_below(ax, ncols=2, fontsize=10)  # the lap fills the world: no corner is free
    return fig


def plot_errors(results: dict, dead_reckoning=None):
    """Position error (log) and heading error over time for named results (and dead reckoning)."""
    import matplotlib.pyplot as plt

    fig, (ax0, ax1) = plt.subplots(2, 1, figsize=(MAX_FIGURE_WIDTH_IN, 4.6), sharex=True)
    for i, (name, res) in enumerate(results.items()):
        ax0.plot(
            res.times, np.maximum(res.slam_error, 1e-3), color=f"C{i}", lw=1, label=name
        )
        ax1.plot(
            res.times, np.degrees(res.slam_heading_error), color=f"C{i}", lw=1, label=name
        )
    if dead_reckoning is not None:
        ax0.plot(
            dead_reckoning.times,
            dead_reckoning.dead_reckoning_error,
            "C3--",
            lw=1,
            label="dead reckoning",
        )
        ax1.plot(
            dead_reckoning.times,
            np.degrees(dead_reckoning.dead_reckoning_heading_error),
            "C3--",
            lw=1,
            label="dead reckoning",
        )
    ax0.set_yscale("log")
    ax0.set_ylabel("position error (m)")
    ax1.set_yscale("log")
    ax1.set_ylabel("heading error (deg)")
    ax1.set_xlabel("t (s)")
    ax0.legend(fontsize=10, ncol=3)
    fig.tight_layout()
    return fig


def animate_run(
    result,
    recording,
    n_frames: int = 40,
    figsize=(MAX_FIGURE_WIDTH_IN, 3.6),
    dpi: int = BOOK_DPI,
    interval: int = 150,
    window: float = 0.3,
    span: tuple | None = None,
    label: str = "SLAM",
):
    """A ``FuncAnimation``: the paths and the current scan (placed by the estimate) over the world, and the
    particle cloud relative to the truth (``window`` metres half-width). Needs ``keep_history=True``; the caller
    renders it (``anim.to_jshtml()``) and closes the figure (``plt.close(anim._fig)``). Keep
    ``n_frames`` low: every frame is embedded as a PNG (at the book's ``dpi``, so the fonts stay legible).
    ``span = (k0, k1)``: only frames ``k0`` to ``k1`` (default the whole run); ``label`` names the estimate."""
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    from slamlib.sim2d.steps import transform_scan

    if result.particle_history is None:
        raise ValueError(
            "animate_run needs a result from run_slam_2d(..., keep_history=True)"
        )
    k0, k1 = span or (1, result.times.size - 1)
    ks = np.unique(np.linspace(k0, k1, n_frames).round().astype(int))
    fig, (ax0, ax1) = plt.subplots(
        1, 2, figsize=figsize, dpi=dpi, gridspec_kw={"width_ratios": [1.6, 1]}
    )
    draw_world(recording.world, ax0, color="0.6", lw=0.8)
    (truth_line,) = ax0.plot([], [], "k", lw=2, label="truth")
    (slam_line,) = ax0.plot([], [], "C0", lw=1.2, label=label)
    (dr_line,) = ax0.plot([], [], "C3--", lw=1.2, label="dead reckoning")
    (scan_pts,) = ax0.plot([], [], ".", color="C2", ms=2, label="scan at the estimate")
    legend_below(ax0, ncols=2, fontsize=10)  # off the world, which fills the panel
    cloud = ax1.scatter(np.zeros(0), np.zeros(0), s=8, c="C0")
    ax1.plot([0], [0], "k+", ms=12, mew=2)
    (best_pt,) = ax1.plot([], [], "o", mfc="none", mec="C2", ms=10, mew=2)
    ax1.set_xlim(-window * 100, window * 100)
    ax1.set_ylim(-window * 100, window * 100)
    ax1.set_aspect("equal")
    ax1.set_xlabel("x - x_true (cm)")
    ax1.set_ylabel("y - y_true (cm)")
    title = fig.suptitle("", fontsize=10)
    fig.tight_layout()

    def draw(i):
        k = ks[i]
        truth_line.set_data(*result.true_poses[: k + 1, :2].T)
        slam_line.set_data(*result.estimated[: k + 1, :2].T)
        dr_line.set_data(*result.dead_reckoned[: k + 1, :2].T)
        scan_pts.set_data(
            *transform_scan(result.estimated[k], recording.frames[k].scan).T
        )
        d = (
            result.particle_history[k, :, :2].astype(np.float64)
            - result.true_poses[k, :2]
        ) * 100
        cloud.set_offsets(d)
        best_pt.set_data(
            [(result.estimated[k, 0] - result.true_poses[k, 0]) * 100],
            [(result.estimated[k, 1] - result.true_poses[k, 1]) * 100],
        )
        title.set_text(
            f"t = {result.times[k]:.1f} s: {label} off by {result.slam_error[k] * 100:.1f} cm, "
            f"dead reckoning by {result.dead_reckoning_error[k]:.2f} m"
        )
        return [truth_line, slam_line, dr_line, scan_pts, cloud, best_pt, title]

    return FuncAnimation(fig, draw, frames=len(ks), interval=interval, blit=False)
