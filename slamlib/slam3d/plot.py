"""Figures of a 3D SLAM run: trajectories with and without SLAM against ground truth, top-down maps, animation.

All functions take arrays (poses ``(F, 4, 4)`` ``T_world_body``, map points ``(M, 3)``, world frame, metres) and
return a matplotlib ``Figure`` (or ``FuncAnimation``); nothing is shown or saved here.
"""

from __future__ import annotations

import numpy as np

from slamlib.plotstyle import BOOK_DPI, MAX_FIGURE_WIDTH_IN

__all__ = [
    "plot_trajectories",
    "plot_map_topdown",
    "animate_map_building",
    "plot_error_over_distance",
    "plot_maps_side_by_side",
    "show_map_render",
    "draw_snapshot",
]


def _subsample(points: np.ndarray, max_points: int, seed: int = 0) -> np.ndarray:
    if len(points) <= max_points:
        return points
    return points[
        np.random.default_rng(seed).choice(len(points), max_points, replace=False)
    ]


def plot_trajectories(
    poses,
    dead_reckoning=None,
    ground_truth=None,
    map_points=None,
    ax=None,
    title=None,
    loop_closed=None,
    closures=(),
):
    """Top-down (x, y) plot of the SLAM trajectory, dead reckoning and ground truth, over a faint map.

    Parameters
    ----------
    poses : (F, 4, 4) SLAM poses; dead_reckoning, ground_truth : (F, 4, 4) or None.
    map_points : (M, 3) or None, drawn as light grey dots (at most 60,000).
    loop_closed : (F, 4, 4) or None, the poses re-anchored by loop closure (:mod:`slamlib.loops`).
    closures : ``(query frame, reference frame, kept)`` positions into ``loop_closed``: each drawn as a line
        between the two (solid when the pose graph kept it, dotted when it did not).
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(7, 6))
    else:
        fig = ax.figure
    if map_points is not None and len(map_points):
        m = _subsample(np.asarray(map_points), 60_000)
        ax.scatter(m[:, 0], m[:, 1], s=0.2, c="0.8", lw=0, rasterized=True)
        # legend proxy (the dots are tiny)
        ax.plot([], [], "o", color="0.8", ms=4, label="map")
    if ground_truth is not None:
        ax.plot(
            ground_truth[:, 0, 3],
            ground_truth[:, 1, 3],
            "k-",
            lw=2.0,
            label="ground truth",
        )
    if dead_reckoning is not None:
        ax.plot(
            dead_reckoning[:, 0, 3],
            dead_reckoning[:, 1, 3],
            "-",
            color="tab:red",
            lw=1.3,
            label="dead reckoning (IMU only)",
        )
    paths = [(poses, "tab:blue", "particle SLAM")]
    if loop_closed is not None:
        paths.append((loop_closed, "tab:green", "particle SLAM + loop closure"))
    for T, color, label in paths:
        ax.plot(T[:, 0, 3], T[:, 1, 3], "-", color=color, lw=1.3, label=label)
    if loop_closed is not None:
        for n, (q, r, kept) in enumerate(closures):
            ax.plot(
                [loop_closed[q, 0, 3], loop_closed[r, 0, 3]],
                [loop_closed[q, 1, 3], loop_closed[r, 1, 3]],
                "-" if kept else ":",
                color="tab:purple",
                lw=2.5,
                marker="o",
                ms=5,
                label=None if n else "loop closure",
            )
    ax.plot(poses[0, 0, 3], poses[0, 1, 3], "go", ms=6, label="start")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m, world = first IMU pose)")
    ax.set_ylabel("y (m)")
    ax.legend(loc="best", fontsize=10)
    ax.set_title(title or "Trajectory with and without SLAM")
    return fig


def plot_map_topdown(
    map_points, poses=None, ax=None, max_points: int = 200_000, title=None, zlim=None
):
    """Top-down view of the map coloured by height ``z`` (m), with the trajectory on top.

    ``zlim`` (lo, hi) clips the colour scale (default: 2nd and 98th percentiles of z).
    """
    import matplotlib.pyplot as plt

    if ax is None:
        fig, ax = plt.subplots(figsize=(MAX_FIGURE_WIDTH_IN, 6.1))
    else:
        fig = ax.figure
    m = _subsample(np.asarray(map_points), max_points)
    lo, hi = (
        zlim
        if zlim is not None
        else (np.percentile(m[:, 2], [2, 98]) if len(m) else (0.0, 1.0))
    )
    order = np.argsort(m[:, 2])  # high points drawn last (walls, trees over the ground)
    sc = ax.scatter(
        m[order, 0],
        m[order, 1],
        c=m[order, 2],
        s=0.3,
        lw=0,
        cmap="viridis",
        vmin=lo,
        vmax=hi,
        rasterized=True,
    )
    fig.colorbar(sc, ax=ax, label="height z (m)", shrink=0.8)
    if poses is not None:
        ax.plot(poses[:, 0, 3], poses[:, 1, 3], "r-", lw=1.2, label="SLAM trajectory")
        ax.legend(loc="best", fontsize=10)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(
        title or f"Map, top-down, coloured by height ({len(map_points):,} elements)"
    )
    return fig


def draw_snapshot(
    snapshots, j, poses, ground_truth, scatter, line, gt_line, max_points: int
) -> int:
    """Point the artists at snapshot ``j`` ``(position k, map points, pose)``: the map so far (``scatter``, at most
    ``max_points`` points, coloured by height), the SLAM trajectory (``line``) and the ground truth (``gt_line``)
    up to ``k``. Shared by :func:`animate_map_building` and :mod:`slamlib.experiments.video`; returns ``k``."""
    k, pts, _ = snapshots[j]
    pts = _subsample(np.asarray(pts), max_points, seed=j)
    scatter.set_offsets(pts[:, :2])
    scatter.set_array(pts[:, 2])
    line.set_data(poses[: k + 1, 0, 3], poses[: k + 1, 1, 3])
    if ground_truth is not None:
        gt_line.set_data(ground_truth[: k + 1, 0, 3], ground_truth[: k + 1, 1, 3])
    return k


def animate_map_building(
    snapshots,
    poses,
    ground_truth=None,
    max_points: int = 15_000,
    interval: int = 200,
    figsize=(6, 5),
    dpi: int = BOOK_DPI,
):
    """``FuncAnimation`` of the map growing: one frame per snapshot ``(position k, map points, pose)``.

    Each frame shows the map so far (top-down, coloured by height, at most ``max_points`` points), the SLAM
    trajectory up to ``k`` and the ground truth. Render with ``anim.to_jshtml()``.
    """
    import matplotlib.pyplot as plt
    from matplotlib.animation import FuncAnimation

    fig, ax = plt.subplots(figsize=figsize, dpi=dpi)
    allp = np.asarray(snapshots[-1][1])
    lo, hi = np.percentile(allp[:, 2], [2, 98]) if len(allp) else (0.0, 1.0)
    pad = 20.0
    xy = poses[:, :2, 3]
    ax.set_xlim(xy[:, 0].min() - pad, xy[:, 0].max() + pad)
    ax.set_ylim(xy[:, 1].min() - pad, xy[:, 1].max() + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    sc = ax.scatter([], [], s=0.4, c=[], cmap="viridis", vmin=lo, vmax=hi, lw=0)
    (gt_line,) = ax.plot([], [], "k-", lw=1.0, label="ground truth")
    (line,) = ax.plot([], [], "r-", lw=1.5, label="SLAM")
    ax.legend(loc="upper left", fontsize=10)

    def update(j):
        k = draw_snapshot(
            snapshots, j, poses, ground_truth, sc, line, gt_line, max_points
        )
        ax.set_title(f"map after frame {k}: {len(snapshots[j][1]):,} elements")
        return sc, line, gt_line

    anim = FuncAnimation(
        fig, update, frames=len(snapshots), interval=interval, blit=False
    )
    plt.close(fig)
    return anim


def plot_error_over_distance(
    poses, dead_reckoning=None, ground_truth=None, ax=None, log: bool = True, title=None
):
    """Position error ``|p_est - p_gt|`` (m) of SLAM (and dead reckoning) against the distance travelled along the
    ground truth (m, :func:`slamlib.metrics.trajectory_distances`)."""
    import matplotlib.pyplot as plt

    from slamlib.metrics import trajectory_distances

    if ground_truth is None:
        raise ValueError("the error over distance needs the ground truth")
    if ax is None:
        fig, ax = plt.subplots(figsize=(6.5, 3.5))
    else:
        fig = ax.figure
    dist = trajectory_distances(ground_truth)
    if dead_reckoning is not None:
        ax.plot(
            dist,
            np.linalg.norm(dead_reckoning[:, :3, 3] - ground_truth[:, :3, 3], axis=1),
            color="tab:red",
            label="dead reckoning (IMU only)",
        )
    ax.plot(
        dist,
        np.linalg.norm(poses[:, :3, 3] - ground_truth[:, :3, 3], axis=1),
        color="tab:blue",
        label="particle SLAM",
    )
    if log:
        ax.set_yscale("log")
    ax.set_xlabel("distance travelled (m)")
    ax.set_ylabel("position error (m)")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(loc="best", fontsize=10)
    ax.set_title(title or "Position error against ground truth")
    return fig


def plot_maps_side_by_side(
    maps: dict,
    ground_truth=None,
    figsize=(MAX_FIGURE_WIDTH_IN, 3.3),
    max_points: int = 80_000,
    zlim=None,
    window=None,
):
    """Top-down maps of several runs on the same frames, one panel each, one shared height colour scale.

    ``maps``: ``{title: (map points (M, 3), SLAM poses (F, 4, 4))}``; ``ground_truth`` (F, 4, 4) is drawn in
    black in every panel; ``window`` ``(xmin, xmax, ymin, ymax)`` metres (default: the trajectories + 40 m).
    """
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(
        1,
        len(maps),
        figsize=figsize,
        sharex=True,
        sharey=True,
        squeeze=False,
        layout="constrained",
    )
    axes = axes[0]
    allz = np.concatenate([np.asarray(p)[:, 2] for p, _ in maps.values()])
    lo, hi = zlim if zlim is not None else np.percentile(allz, [2, 98])
    sc = None
    for ax, (name, (pts, poses)) in zip(axes, maps.items()):
        m = _subsample(np.asarray(pts), max_points)
        order = np.argsort(m[:, 2])
        sc = ax.scatter(
            m[order, 0],
            m[order, 1],
            c=m[order, 2],
            s=0.3,
            lw=0,
            cmap="viridis",
            vmin=lo,
            vmax=hi,
            rasterized=True,
        )
        if ground_truth is not None:
            ax.plot(
                ground_truth[:, 0, 3],
                ground_truth[:, 1, 3],
                "k-",
                lw=1.5,
                label="ground truth",
            )
        ax.plot(
            poses[:, 0, 3], poses[:, 1, 3], "-", color="tab:red", lw=1.2, label="SLAM"
        )
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x (m)")
        ax.set_aspect("equal", adjustable="box")
    xy = np.vstack([p[:, :2, 3] for _, p in maps.values()])
    if window is None:
        window = (
            xy[:, 0].min() - 40,
            xy[:, 0].max() + 40,
            xy[:, 1].min() - 40,
            xy[:, 1].max() + 40,
        )
    axes[0].set_xlim(window[0], window[1])
    axes[0].set_ylim(window[2], window[3])
    axes[0].set_ylabel("y (m)")
    axes[0].legend(loc="lower left", fontsize=10)
    fig.colorbar(sc, ax=list(axes), label="height z (m)", shrink=0.8)
    return fig


#: Colours (RGB in [0, 1]) of the trajectory and the scale bar in a rendered map
#: (:func:`slamlib.experiments.render.render_map_3d`) and in :func:`show_map_render`'s key: red and black, apart
#: from the height colour map.
TRAJECTORY_RGB, SCALE_BAR_RGB = (0.9, 0.05, 0.05), (0.0, 0.0, 0.0)


def show_map_render(
    image,
    zlim,
    title=None,
    figsize=(MAX_FIGURE_WIDTH_IN, 4.4),
    cmap: str = "viridis",
    scale_m: float | None = None,
    trajectory: str | None = "trajectory",
):
    """Show a rendered map image (:func:`slamlib.experiments.render.render_map_3d`) with its height colour bar (m)
    and a key under it: the red ``trajectory`` line (``None``: no trajectory was drawn) and, given ``scale_m``
    (:func:`~slamlib.experiments.render.scale_bar_length` of the rendered points), the black scale bar's length."""
    import matplotlib.pyplot as plt
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    fig, ax = plt.subplots(figsize=figsize, layout="constrained")
    ax.imshow(image)
    ax.set_axis_off()
    fig.colorbar(
        ScalarMappable(Normalize(*zlim), cmap), ax=ax, label="height z (m)", shrink=0.7
    )
    key = []
    if trajectory:
        key.append(Line2D([], [], color=TRAJECTORY_RGB, lw=3, label=trajectory))
    if scale_m is not None:
        key.append(
            Line2D([], [], color=SCALE_BAR_RGB, lw=3, label=f"scale bar: {scale_m:g} m")
        )
    if key:
        fig.legend(handles=key, loc="outside lower center", ncols=len(key), frameon=False)
    if title:
        ax.set_title(title, fontsize=11)
    return fig
