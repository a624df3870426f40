"""3D pictures of a SLAM map: the map's points coloured by height, with the trajectory, rendered to an image array.

:func:`render_map_3d` renders with open3d's headless ``OffscreenRenderer`` (Filament; on a machine without a GPU
it runs on Mesa's software Vulkan/EGL driver) and falls back to a matplotlib 3D scatter when offscreen rendering
is unavailable; :func:`offscreen_available` says which one will be used. Points ``(M, 3)`` and poses
``(F, 4, 4)`` ``T_world_body`` are in the world frame, metres.
"""

from __future__ import annotations

import contextlib
import functools
import os
import sys

import numpy as np

from slamlib.slam3d.plot import SCALE_BAR_RGB, TRAJECTORY_RGB, _subsample

__all__ = [
    "render_map_3d",
    "offscreen_available",
    "height_colours",
    "default_camera",
    "scale_bar_length",
]

#: Metres the trajectory is drawn above the poses: clear of the points around the road (cars, hedges, the
#: road itself under an oblique view), which would otherwise hide it.
TRAJECTORY_LIFT_M = 2.0
#: Width (pixels) of the trajectory's line and of the scale bar in the open3d render.
TRAJECTORY_WIDTH_PX, SCALE_BAR_WIDTH_PX = 6.0, 5.0
#: Round lengths (m) a scale bar may have; :func:`scale_bar_length` picks the longest up to a quarter of the map.
SCALE_BAR_LENGTHS_M = (1, 2, 5, 10, 20, 50, 100, 200, 500, 1000)


def scale_bar_length(points: np.ndarray) -> float:
    """The length (m) of the scale bar :func:`render_map_3d` draws: the longest of :data:`SCALE_BAR_LENGTHS_M`
    no longer than a quarter of the map's extent along x."""
    span = float(np.ptp(np.asarray(points)[:, 0])) if len(points) else 0.0
    fitting = [length for length in SCALE_BAR_LENGTHS_M if length <= span / 4]
    return float(fitting[-1] if fitting else SCALE_BAR_LENGTHS_M[0])


def _scale_bar(points: np.ndarray) -> np.ndarray:
    """The scale bar's polyline (4, 3): a segment of :func:`scale_bar_length` along world x on the ground, near the
    map's (min x, min y) corner, with an upright tick of a tenth of its length at each end."""
    lo, hi = points.min(axis=0), points.max(axis=0)
    length = scale_bar_length(points)
    x0, y0 = lo[:2] + 0.05 * (hi[:2] - lo[:2])
    z0 = float(np.percentile(points[:, 2], 2))
    tick = length / 10
    return np.array(
        [
            [x0, y0, z0 + tick],
            [x0, y0, z0],
            [x0 + length, y0, z0],
            [x0 + length, y0, z0 + tick],
        ]
    )


def height_colours(
    z: np.ndarray, zlim=None, cmap: str = "viridis"
) -> tuple[np.ndarray, tuple[float, float]]:
    """RGB colours ``(M, 3)`` in [0, 1] of heights ``z`` (m) through ``cmap``, clipped to ``zlim`` (default: the
    2nd and 98th percentiles). Returns ``(colours, (lo, hi))``."""
    import matplotlib

    z = np.asarray(z, dtype=np.float64)
    lo, hi = (
        zlim
        if zlim is not None
        else (np.percentile(z, [2, 98]) if len(z) else (0.0, 1.0))
    )
    u = np.clip((z - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return matplotlib.colormaps[cmap](u)[:, :3], (float(lo), float(hi))


def default_camera(
    points: np.ndarray,
    elevation_deg: float = 35.0,
    azimuth_deg: float = -60.0,
    distance: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """An oblique view of the whole map: ``(eye (3,), centre (3,))`` in world metres.

    The camera looks at the centre of the points' bounding box from ``azimuth_deg`` (from the world x axis,
    counter-clockwise seen from above) and ``elevation_deg`` above the horizon, at ``distance`` times the box's
    diagonal.
    """
    p = np.asarray(points, dtype=np.float64)
    lo, hi = p.min(axis=0), p.max(axis=0)
    centre = (lo + hi) / 2
    diag = float(np.linalg.norm(hi - lo)) or 1.0
    el, az = np.radians(elevation_deg), np.radians(azimuth_deg)
    direction = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return centre + distance * diag * direction, centre


@contextlib.contextmanager
def _quiet():
    """Silence what open3d and Filament print (Python prints and C++ writes to file descriptors 1 and 2) while
    rendering, so notebooks and progress bars stay clean. Does nothing where the descriptors cannot be swapped."""
    try:
        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
    except (OSError, ValueError, AttributeError):
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        with (
            open(os.devnull, "w") as sink,
            contextlib.redirect_stdout(sink),
            contextlib.redirect_stderr(sink),
        ):
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved + [devnull]:
            os.close(fd)


def _open3d():
    with _quiet():
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    return o3d


@functools.lru_cache(maxsize=1)
def offscreen_available() -> bool:
    """Whether open3d's ``OffscreenRenderer`` works in this process (tried once on a 16 x 16 image)."""
    try:
        o3d = _open3d()
        with _quiet():
            r = o3d.visualization.rendering.OffscreenRenderer(16, 16)
            img = np.asarray(r.render_to_image())
            del r
        return img.shape[:2] == (16, 16)
    # no open3d, no EGL/Vulkan driver, no rendering module in this build
    except Exception:
        return False


def render_map_3d(
    points,
    poses=None,
    size=(640, 400),
    engine: str = "auto",
    zlim=None,
    max_points: int = 400_000,
    point_size: float = 2.0,
    elevation_deg: float = 35.0,
    azimuth_deg: float = -60.0,
    distance: float = 0.7,
    fov_deg: float = 40.0,
    background=(1.0, 1.0, 1.0),
) -> np.ndarray:
    """Render the map ``points`` (M, 3) coloured by height, the trajectory ``poses`` (F, 4, 4) (a red line
    :data:`TRAJECTORY_LIFT_M` above the poses) and a black scale bar of :func:`scale_bar_length` metres along the
    world x axis (upright ticks at its ends) to an RGB image ``(H, W, 3)`` uint8, ``size = (W, H)`` pixels.

    ``engine``: ``"open3d"`` (offscreen, perspective camera with ``fov_deg`` vertical field of view placed by
    :func:`default_camera`), ``"matplotlib"`` (3D scatter, same viewing angles) or ``"auto"`` (open3d when
    :func:`offscreen_available`, else matplotlib). ``zlim`` clips the colour scale (see :func:`height_colours`).
    """
    w, h = (int(size[0]), int(size[1]))
    if w < 16 or h < 16:
        raise ValueError(f"size must be at least 16 x 16 pixels, got {size}")
    if engine not in ("auto", "open3d", "matplotlib"):
        raise ValueError(
            f"engine must be 'auto', 'open3d' or 'matplotlib', got {engine!r}"
        )
    points = np.asarray(points, dtype=np.float64)
    pts = _subsample(points, max_points)
    if len(pts) == 0:
        raise ValueError("no map points to render")
    if engine == "auto":
        engine = "open3d" if offscreen_available() else "matplotlib"
    colours, _ = height_colours(pts[:, 2], zlim)
    traj = (
        None
        if poses is None
        else np.asarray(poses)[:, :3, 3] + [0.0, 0.0, TRAJECTORY_LIFT_M]
    )
    bar = _scale_bar(points)  # all the points: scale_bar_length(points) names its length
    eye, centre = default_camera(pts, elevation_deg, azimuth_deg, distance)
    if engine == "open3d":
        return _render_open3d(
            pts, colours, traj, bar, w, h, eye, centre, point_size, fov_deg, background
        )
    return _render_matplotlib(
        pts, colours, traj, bar, w, h, point_size, elevation_deg, azimuth_deg, background
    )


def _polyline(o3d, vertices: np.ndarray, rgb):
    lines = o3d.geometry.LineSet(
        o3d.utility.Vector3dVector(vertices),
        o3d.utility.Vector2iVector(
            np.c_[np.arange(len(vertices) - 1), np.arange(1, len(vertices))]
        ),
    )
    lines.paint_uniform_color(list(rgb))
    return lines


def _render_open3d(
    pts, colours, traj, bar, w, h, eye, centre, point_size, fov_deg, background
):
    o3d = _open3d()
    rendering = o3d.visualization.rendering
    with _quiet():
        r = rendering.OffscreenRenderer(w, h)
    try:
        r.scene.set_background(list(background) + [1.0])
        # no tone mapping: the colours come out as given
        r.scene.view.set_post_processing(False)
        pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        pcd.colors = o3d.utility.Vector3dVector(colours)
        mat = rendering.MaterialRecord()
        mat.shader = "defaultUnlit"
        mat.point_size = float(point_size)
        r.scene.add_geometry("map", pcd, mat)
        drawn = [("scale bar", bar, SCALE_BAR_RGB, SCALE_BAR_WIDTH_PX)]
        if traj is not None and len(traj) > 1:
            drawn.append(("trajectory", traj, TRAJECTORY_RGB, TRAJECTORY_WIDTH_PX))
        for name, vertices, rgb, width in drawn:
            lmat = rendering.MaterialRecord()
            lmat.shader = "unlitLine"
            lmat.line_width = float(width)
            r.scene.add_geometry(name, _polyline(o3d, vertices, rgb), lmat)
        r.setup_camera(
            float(fov_deg),
            centre.astype(np.float32),
            eye.astype(np.float32),
            np.array([0.0, 0.0, 1.0], dtype=np.float32),
        )
        with _quiet():
            img = np.asarray(r.render_to_image())
    finally:
        with _quiet():
            del r
    return np.ascontiguousarray(img[:, :, :3], dtype=np.uint8)


def _render_matplotlib(
    pts, colours, traj, bar, w, h, point_size, elevation_deg, azimuth_deg, background
):
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    dpi = 100
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi, facecolor=background)
    FigureCanvasAgg(fig)
    ax = fig.add_axes([0, 0, 1, 1], projection="3d", facecolor=background)
    sub = _subsample(pts, 60_000)
    c = (
        colours
        if len(sub) == len(pts)
        else height_colours(sub[:, 2], (pts[:, 2].min(), pts[:, 2].max()))[0]
    )
    ax.scatter(
        sub[:, 0], sub[:, 1], sub[:, 2], c=c, s=point_size * 0.3, lw=0, depthshade=False
    )
    if traj is not None:
        ax.plot(*traj.T, color=TRAJECTORY_RGB, lw=TRAJECTORY_WIDTH_PX / 2)
    ax.plot(*bar.T, color=SCALE_BAR_RGB, lw=SCALE_BAR_WIDTH_PX / 2)
    span = np.ptp(pts, axis=0)
    ax.set_box_aspect((span[0], span[1], max(span[2], 0.05 * span[:2].max())))
    ax.view_init(elev=elevation_deg, azim=azimuth_deg)
    ax.set_axis_off()
    fig.canvas.draw()
    img = np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    plt.close(fig)
    return img
