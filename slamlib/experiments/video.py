"""A video of the map being built as the vehicle drives, from a run's snapshots.

:func:`write_map_video` draws one frame per snapshot ``(frame position k, map points so far, pose)`` of a
:class:`~slamlib.slam3d.run.SLAMRun` (``run_drive(..., snapshot_every=n)``): the map so far seen from above and
coloured by height, the SLAM trajectory so far (red), the ground truth so far (black) and the current pose (a
triangle pointing along the body x axis), with fixed axes in metres. ``.mp4`` is written with imageio-ffmpeg
(H.264, yuv420p: plays in every browser), ``.gif`` with Pillow.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = [
    "VIDEO_FORMATS",
    "check_video_path",
    "map_video_frames",
    "write_map_video",
    "snapshot_every_for",
]

#: File extensions :func:`write_map_video` can write, and the package each needs.
VIDEO_FORMATS = {".mp4": "imageio-ffmpeg", ".gif": "pillow"}

#: Pixels at the bottom of a frame that a browser's video controls (play bar, time, volume) draw over.
PLAYER_CONTROLS_PX = 44
#: Pixels under the map's axes for the x tick labels and the x label (10 pt at 100 dpi).
X_LABEL_PX = 46
#: Frame fractions: the map axes' width, and the margin above them for the title.
AXES_WIDTH, TOP_MARGIN = 0.72, 0.08


def check_video_path(path, overwrite: bool = True) -> str:
    """The format (``".mp4"`` or ``".gif"``) of ``path``, checked before any work is done.

    Raises ``ValueError`` for another extension, for a folder at ``path``, or (``overwrite=False``) for a file
    already at ``path``, and ``ImportError`` naming the package to install when the writer's package is missing.
    """
    ext = Path(path).suffix.lower()
    if ext not in VIDEO_FORMATS:
        raise ValueError(
            f"cannot write a video to {str(path)!r}: the name must end in "
            f"{' or '.join(VIDEO_FORMATS)}, not {ext or '(no extension)'!r}"
        )
    if Path(path).is_dir():
        raise ValueError(f"cannot write a video to {str(path)!r}: it is a folder")
    if not overwrite and Path(path).exists():
        raise ValueError(
            f"{str(path)!r} exists; give --overwrite to replace it, or another name"
        )
    parent = Path(path).parent
    # the folders the writer will make: the nearest existing one must be a folder
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise ValueError(
            f"cannot write a video to {str(path)!r}: {str(parent)!r} is a file, not a folder"
        )
    try:
        if ext == ".mp4":
            import imageio_ffmpeg

            imageio_ffmpeg.get_ffmpeg_exe()
        else:
            import PIL  # noqa: F401
    except ImportError:
        pkg = VIDEO_FORMATS[ext]
        raise ImportError(
            f"writing {ext} videos needs the package {pkg!r}: pip install {pkg}"
        ) from None
    except RuntimeError as exc:  # imageio-ffmpeg installed without its ffmpeg binary
        raise ImportError(
            f"writing {ext} videos needs an ffmpeg binary ({exc}); pip install --force-reinstall "
            f"imageio-ffmpeg"
        ) from None
    return ext


def snapshot_every_for(n_frames: int, max_video_frames: int = 150) -> int:
    """The ``snapshot_every`` of :func:`~slamlib.slam3d.run.run_drive` that gives at most ``max_video_frames``
    snapshots (video frames) of an ``n_frames`` run."""
    return max(1, -(-int(n_frames) // int(max_video_frames)))


#: The current-pose marker: a dart pointing along +x (matplotlib marker vertices).
_CAR = np.array([[1.0, 0.0], [-0.7, 0.55], [-0.35, 0.0], [-0.7, -0.55], [1.0, 0.0]])


def _even(x: int, m: int = 16) -> int:
    return max(m, int(round(x / m)) * m)


def map_video_frames(
    snapshots,
    poses,
    ground_truth=None,
    size=(640, 480),
    max_points: int = 12_000,
    zlim=None,
    pad: float = 15.0,
):
    """Yield one RGB frame ``(H, W, 3)`` uint8 per snapshot, ``size = (W, H)`` pixels (matplotlib, Agg).

    The axes (x, y in metres, world frame) and the height colour scale stay fixed over the video: they come from
    the whole trajectory(ies) and the last snapshot's map.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from slamlib.slam3d.plot import draw_snapshot

    if not snapshots:
        raise ValueError(
            "the run has no snapshots: run_drive(..., snapshot_every=n) keeps them"
        )
    poses = np.asarray(poses)
    w, h = int(size[0]), int(size[1])
    dpi = 100
    fig = Figure(figsize=(w / dpi, h / dpi), dpi=dpi)
    FigureCanvasAgg(fig)
    # the axes sit above the band that a browser's video controls cover, with room for the x label
    bottom = (PLAYER_CONTROLS_PX + X_LABEL_PX) / h
    ax_w, ax_h = AXES_WIDTH, 1.0 - bottom - TOP_MARGIN
    ax = fig.add_axes([0.1, bottom, ax_w, ax_h])
    cax = fig.add_axes([0.85, bottom + 0.05, 0.025, ax_h - 0.1])
    last = np.asarray(snapshots[-1][1])
    lo, hi = (
        zlim
        if zlim is not None
        else (np.percentile(last[:, 2], [2, 98]) if len(last) else (0.0, 1.0))
    )
    xy = (
        poses[:, :2, 3]
        if ground_truth is None
        else np.vstack([poses[:, :2, 3], ground_truth[:, :2, 3]])
    )
    ext = max(np.ptp(xy[:, 0]), np.ptp(xy[:, 1]) * w / h * ax_w / ax_h) / 2 + pad
    cx, cy = (xy.min(axis=0) + xy.max(axis=0)) / 2
    sc = ax.scatter(
        np.zeros(0),
        np.zeros(0),
        c=np.zeros(0),
        s=1.5,
        lw=0,
        cmap="viridis",
        vmin=lo,
        vmax=hi,
    )
    fig.colorbar(sc, cax=cax).set_label("height z (m)", fontsize=10)
    cax.tick_params(labelsize=10)
    (gt_line,) = ax.plot([], [], "k-", lw=1.0, label="ground truth")
    (line,) = ax.plot([], [], "-", color="tab:red", lw=1.6, label="SLAM")
    (car,) = ax.plot(
        [], [], marker=_CAR, color="tab:red", ms=14, ls="none", mec="k", mew=0.6
    )
    ax.set_xlim(cx - ext, cx + ext)
    ax.set_ylim(cy - ext * h / w * ax_h / ax_w, cy + ext * h / w * ax_h / ax_w)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)", fontsize=10)
    ax.set_ylabel("y (m)", fontsize=10)
    ax.tick_params(labelsize=10)
    ax.legend(loc="upper left", fontsize=10)
    title = ax.set_title("", fontsize=10)
    try:
        for j, (_, _, pose) in enumerate(snapshots):
            k = draw_snapshot(
                snapshots, j, poses, ground_truth, sc, line, gt_line, max_points
            )
            yaw = np.arctan2(pose[1, 0], pose[0, 0])
            c, s_ = np.cos(yaw), np.sin(yaw)
            car.set_data([pose[0, 3]], [pose[1, 3]])
            # a dart pointing along the body x axis
            car.set_marker(_CAR @ np.array([[c, s_], [-s_, c]]))
            title.set_text(f"frame {k}: map of {len(snapshots[j][1]):,} elements")
            fig.canvas.draw()
            yield np.asarray(fig.canvas.buffer_rgba())[:, :, :3].copy()
    finally:
        fig.clear()


def write_map_video(
    run,
    path,
    fps: float = 10.0,
    size=(640, 480),
    max_points: int = 12_000,
    progress: bool = True,
    quality: int = 4,
) -> dict:
    """Write the video of ``run``'s map being built to ``path`` (``.mp4`` or ``.gif``); one frame per snapshot.

    Returns ``{"path", "frames", "seconds", "size", "bytes"}``. Raises ``ValueError`` for an unknown extension
    or a run without snapshots, ``ImportError`` naming the package when the writer is missing.

    Parameters
    ----------
    run : a :class:`~slamlib.slam3d.run.SLAMRun` with ``snapshots`` (``run_drive(..., snapshot_every=n)``).
    fps : video frames per second (a 300-frame drive with ``snapshot_every=3`` at 10 fps lasts 10 s).
    size : ``(W, H)`` pixels; rounded to multiples of 16 (H.264 macro blocks).
    max_points : map points drawn per frame (a random subset).
    progress : a tqdm bar over the frames.
    quality : mp4 quality 1-10 (imageio-ffmpeg: H.264 crf = 51 (1 - quality / 10); lower is smaller).
    """
    from tqdm.auto import tqdm

    path = Path(path)
    ext = check_video_path(path)
    snaps = run.snapshots
    if not snaps:
        raise ValueError(
            "the run has no snapshots: run_drive(..., snapshot_every=n) keeps them"
        )
    w, h = _even(size[0]), _even(size[1])
    path.parent.mkdir(parents=True, exist_ok=True)
    frames = map_video_frames(snaps, run.poses, run.ground_truth, (w, h), max_points)
    bar = tqdm(frames, total=len(snaps), desc="video", unit="frame", disable=not progress)
    n = 0
    if ext == ".mp4":
        import imageio_ffmpeg

        writer = imageio_ffmpeg.write_frames(
            str(path),
            (w, h),
            fps=float(fps),
            codec="libx264",
            quality=quality,
            macro_block_size=16,
            pix_fmt_out="yuv420p",
            output_params=["-movflags", "+faststart"],
            ffmpeg_log_level="error",
        )
        writer.send(None)
        try:
            for img in bar:
                writer.send(np.ascontiguousarray(img))
                n += 1
        finally:
            writer.close()
    else:
        from PIL import Image

        images = [
            Image.fromarray(img).quantize(colors=128, method=Image.Quantize.MEDIANCUT)
            for img in bar
        ]
        n = len(images)
        images[0].save(
            path,
            save_all=True,
            append_images=images[1:],
            duration=int(round(1000 / fps)),
            loop=0,
            optimize=False,
        )
    bar.close()
    return {
        "path": path,
        "frames": n,
        "seconds": n / float(fps),
        "size": (w, h),
        "bytes": path.stat().st_size,
    }
