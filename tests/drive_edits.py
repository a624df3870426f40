"""Edits of a tiny KITTI raw drive (``conftest.drive_dir``, ``conftest.cli_drive``) that the reader's and the
commands' tests share."""


def set_oxts_field(drive_dir, index, name, value):
    """Set field ``name`` of frame ``index``'s OXTS packet file to the text ``value``."""
    from slamlib.kitti.oxts import OXTS_FIELDS

    path = drive_dir / "oxts" / "data" / f"{index:010d}.txt"
    parts = path.read_text().split()
    parts[OXTS_FIELDS.index(name)] = value
    path.write_text(" ".join(parts) + "\n")
