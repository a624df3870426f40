"""Edits of a tiny KITTI raw drive (``conftest.drive_dir``, ``conftest.cli_drive``) that the reader's and the
commands' tests share."""


def set_oxts_field(drive_dir, index, name, value):
    """Set field ``name`` of frame ``index``'s OXTS packet file to the text ``value``."""
    from slamlib.kitti.oxts import OXTS_FIELDS

    path = drive_dir / "oxts" / "data" / f"{index:010d}.txt"
    parts = path.read_text().split()
    parts[OXTS_FIELDS.index(name)] = value
    path.write_text(" ".join(parts) + "\n")


def cut_frames(src_ddir, dst_ddir, keep):
    """Copy the KITTI raw drive folder ``src_ddir`` to ``dst_ddir`` with only the frames ``keep`` (ascending),
    renumbered 0, 1, ... with their own timestamps: a drive with a dropout where ``keep`` jumps."""
    import shutil
    from pathlib import Path

    src, dst = Path(src_ddir), Path(dst_ddir)
    for sub, ext in (("oxts", ".txt"), ("velodyne_points", ".bin")):
        (dst / sub / "data").mkdir(parents=True)
        for new, old in enumerate(keep):
            shutil.copyfile(
                src / sub / "data" / f"{old:010d}{ext}",
                dst / sub / "data" / f"{new:010d}{ext}",
            )
    shutil.copyfile(src / "oxts" / "dataformat.txt", dst / "oxts" / "dataformat.txt")
    stamps = [
        "oxts/timestamps.txt",
        "velodyne_points/timestamps.txt",
        "velodyne_points/timestamps_start.txt",
        "velodyne_points/timestamps_end.txt",
    ]
    for name in stamps:
        if (src / name).is_file():
            lines = (src / name).read_text().splitlines()
            (dst / name).write_text("\n".join(lines[k] for k in keep) + "\n")
    for calib in src.parent.glob("calib_*.txt"):
        shutil.copyfile(calib, dst.parent / calib.name)
