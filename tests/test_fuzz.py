"""Issue 13, item 2: a fuzz suite over the KITTI readers and the ``slamlib`` CLI options, classifying outcomes.

Each example corrupts one file of a tiny drive (or gives one or two CLI options odd values) and must end in exactly
one of:

- success: the reader returns frames whose numbers are all finite (or the command starts / finishes, with finite
  outputs);
- ``DataFormatError`` (readers) whose one-line message names the corrupted file, or ``SystemExit`` (CLI) whose
  one-line message names the file (data) or one of the fuzzed options; argparse's own usage error (exit status 2,
  the option named on stderr) counts as the latter;
- nothing else: any other exception is a "foreign exception" and fails the test.

CI runs a few examples per test, derandomised (the same examples every run). A longer local run is one command::

    SLAMLIB_FUZZ_EXAMPLES=2000 .venv/bin/python -m pytest -p no:dash tests/test_fuzz.py -q

(with ``SLAMLIB_FUZZ_EXAMPLES`` set, the examples are random: each run explores new ones).
"""

from __future__ import annotations

import json
import math
import os
import shutil
import struct
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from slamlib.errors import DataFormatError
from slamlib.kitti.sample import SAMPLE_DATE, SAMPLE_DRIVE, make_tiny_drive

_LOCAL = os.environ.get("SLAMLIB_FUZZ_EXAMPLES")


def _settings(ci_examples: int):
    """``ci_examples`` derandomised examples in CI; ``SLAMLIB_FUZZ_EXAMPLES`` random ones locally."""
    n = int(_LOCAL) if _LOCAL else ci_examples
    return settings(
        max_examples=n,
        deadline=None,
        derandomize=not _LOCAL,
        database=None,
        suppress_health_check=list(HealthCheck),
    )


N_FRAMES = 3


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    """A 3-frame drive, written once; each example works on a fresh copy."""
    base = tmp_path_factory.mktemp("pristine")
    make_tiny_drive(base, n_frames=N_FRAMES, point_stride=500)
    return base


class _Copy:
    def __init__(self, pristine: Path):
        self.tmp = Path(tempfile.mkdtemp(prefix="fuzz-"))
        self.base = self.tmp / "kitti"
        shutil.copytree(pristine, self.base)
        from slamlib.kitti.raw import drive_folder_name

        self.drive = (
            self.base / SAMPLE_DATE / drive_folder_name(SAMPLE_DATE, SAMPLE_DRIVE)
        )

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        shutil.rmtree(self.tmp, ignore_errors=True)


# ------------------------------------------------------------------------------------------ value strategies
ODD_NUMBERS = [
    "0",
    "-0",
    "-1",
    "nan",
    "NaN",
    "-nan",
    "inf",
    "-inf",
    "1e308",
    "-1e308",
    "1e400",
    "1e-320",
    "99999999999999999999",
    "-99999999999999999999",
    "4294967296",
    "2147483648",
    "9223372036854775808",
]
ODD_TEXT = [
    "",
    " ",
    "abc",
    "1,5",
    "0x10",
    "1e",
    "-",
    "1.5.2",
    "\u00e9",
    "1_000",
    "+",
    "None",
]

odd_number_text = st.one_of(
    st.sampled_from(ODD_NUMBERS),
    st.integers(-(10**12), 10**12).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.floats(-1e6, 1e6).map(lambda x: f"{x:.6g}"),
)
odd_text = st.one_of(
    odd_number_text,
    st.sampled_from(ODD_TEXT),
    st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=8),
)
#: ``--option=--`` is left out here: Python 3.11's argparse hands the command ``[]``, which slamlib.cli now
#: refuses with a usage error naming the option (tests/test_fuzz_findings.py checks it).
option_text = odd_text.filter(lambda v: v != "--")


# ------------------------------------------------------------------------------------------ data corruptions
def _lines(path: Path) -> list[str]:
    return path.read_text().splitlines()


def _write_lines(path: Path, lines: list[str]) -> None:
    path.write_text("\n".join(lines) + ("\n" if lines else ""))


@st.composite
def oxts_corruption(draw):
    frame = draw(st.integers(0, N_FRAMES - 1))
    kind = draw(st.sampled_from(["field", "drop", "extra", "empty", "garbage", "lines"]))
    if kind == "field":
        fields = draw(
            st.lists(st.tuples(st.integers(0, 29), odd_text), min_size=1, max_size=3)
        )
    else:
        fields = draw(st.just([]))
    extra = draw(st.integers(1, 5))

    def apply(drive: Path) -> Path:
        path = drive / "oxts" / "data" / f"{frame:010d}.txt"
        parts = path.read_text().split()
        if kind == "field":
            for i, value in fields:
                parts[i] = value
            path.write_text(" ".join(parts) + "\n")
        elif kind == "drop":
            path.write_text(" ".join(parts[:-extra]) + "\n")
        elif kind == "extra":
            path.write_text(" ".join(parts + ["1"] * extra) + "\n")
        elif kind == "empty":
            path.write_text("")
        elif kind == "garbage":
            path.write_bytes(bytes(range(256)) * extra)
        else:  # the packet on several lines
            path.write_text("\n".join(parts[:10]) + "\n" + " ".join(parts[10:]) + "\n")
        return path

    return f"oxts {frame} {kind} {fields or extra}", apply


TS_FILES = {
    "oxts": ("oxts", "timestamps.txt"),
    "velo": ("velodyne_points", "timestamps.txt"),
}
ODD_STAMPS = [
    "0001-01-01 00:00:00.000000000",
    "9999-12-31 23:59:59.999999999",
    "1969-12-31 23:59:59.000000000",
    "2011-13-01 00:00:00.000000000",
    "2011-09-26 25:00:00.000000000",
    "2011-09-26 13:02:25",
    "2011-09-26T13:02:25.964389445",
    "2011-09-26 13:02:25.9643894451234",
    "1e9",
    "",
    "2011-09-26 13:02:nan",
    "2262-04-12 00:00:00.000000000",
    "1677-09-21 00:00:00.000000000",
]


@st.composite
def timestamp_corruption(draw):
    which = draw(st.sampled_from(sorted(TS_FILES)))
    kind = draw(
        st.sampled_from(["replace", "swap", "delete", "duplicate", "append", "empty"])
    )
    line = draw(st.integers(0, N_FRAMES - 1))
    value = draw(st.one_of(st.sampled_from(ODD_STAMPS), odd_text))

    def apply(drive: Path) -> Path:
        path = drive.joinpath(*TS_FILES[which])
        lines = _lines(path)
        if kind == "replace":
            lines[line] = value
        elif kind == "swap":
            j = (line + 1) % len(lines)
            lines[line], lines[j] = lines[j], lines[line]
        elif kind == "delete":
            del lines[line]
        elif kind == "duplicate":
            lines.insert(line, lines[line])
        elif kind == "append":
            lines.append(value)
        else:
            lines = []
        _write_lines(path, lines)
        return path

    return f"timestamps {which} {kind} line {line} {value!r}", apply


@st.composite
def velodyne_corruption(draw):
    frame = draw(st.integers(0, N_FRAMES - 1))
    kind = draw(st.sampled_from(["truncate", "extend", "empty", "values", "all"]))
    cut = draw(st.integers(0, 64))
    odd = [math.nan, math.inf, -math.inf, 3.4e38, -3.4e38, 1e30, 0.0, 1e-45]
    values = draw(
        st.lists(
            st.tuples(st.integers(0, 10**6), st.sampled_from(odd)), min_size=1, max_size=4
        )
    )
    fill = draw(st.sampled_from(odd))

    def apply(drive: Path) -> Path:
        path = drive / "velodyne_points" / "data" / f"{frame:010d}.bin"
        data = bytearray(path.read_bytes())
        if kind == "truncate":
            data = data[: max(0, len(data) - 1 - cut)]
        elif kind == "extend":
            data += bytes(1 + cut)
        elif kind == "empty":
            data = bytearray()
        elif kind == "values":
            n = len(data) // 4
            for i, v in values:
                struct.pack_into("<f", data, 4 * (i % n), v)
        else:
            data = bytearray(np.full(len(data) // 4, fill, np.float32).tobytes())
        path.write_bytes(bytes(data))
        return path

    return f"velodyne {frame} {kind} cut {cut} {values} fill {fill}", apply


CALIBS = ("calib_imu_to_velo.txt", "calib_velo_to_cam.txt", "calib_cam_to_cam.txt")


@st.composite
def calib_corruption(draw):
    name = draw(st.sampled_from(CALIBS))
    kind = draw(st.sampled_from(["drop_line", "number", "count", "empty", "no_colon"]))
    line = draw(st.integers(0, 40))
    value = draw(odd_text)

    def apply(drive: Path) -> Path:
        path = drive.parent / name
        lines = _lines(path)
        i = line % len(lines)
        key, _, rest = lines[i].partition(":")
        numbers = rest.split()
        if kind == "drop_line":
            del lines[i]
        elif kind == "number" and numbers:
            numbers[line % len(numbers)] = value
            lines[i] = f"{key}: {' '.join(numbers)}"
        elif kind == "count":
            lines[i] = f"{key}: {' '.join(numbers[:-1])}"
        elif kind == "empty":
            lines = []
        else:
            lines[i] = lines[i].replace(":", " ")
        _write_lines(path, lines)
        return path

    return f"calib {name} {kind} line {line} {value!r}", apply


corruption = st.one_of(
    oxts_corruption(), timestamp_corruption(), velodyne_corruption(), calib_corruption()
)


# ------------------------------------------------------------------------------------------ missing and unread files
#: Files and folders of the drive (relative to the drive folder) that a user can lose, and whether the drive still reads
#: without them. ``oxts/dataformat.txt`` (the field names) is read by neither slamlib nor pykitti, and
#: ``velodyne_points/timestamps.txt`` is optional (scan times are informational).
#: ``velodyne_points/timestamps_start.txt``
#: and ``timestamps_end.txt`` are not listed: slamlib (and pykitti) never read them, so they are not fuzzed.
REQUIRED_PATHS = (
    ["../" + name for name in CALIBS]
    + [
        "oxts/timestamps.txt",
        "oxts/data",
        "velodyne_points/data",
        "oxts",
        "velodyne_points",
        ".",
    ]
    + [f"oxts/data/{k:010d}.txt" for k in range(N_FRAMES)]
    + [f"velodyne_points/data/{k:010d}.bin" for k in range(N_FRAMES)]
)
OPTIONAL_PATHS = ["oxts/dataformat.txt", "velodyne_points/timestamps.txt"]


@st.composite
def missing_file(draw):
    rel = draw(st.sampled_from(REQUIRED_PATHS + OPTIONAL_PATHS))
    kind = draw(
        st.sampled_from(["delete", "folder"])
    )  # gone, or a folder where the file was

    def apply(drive: Path) -> Path:
        path = (drive / rel).resolve()
        if path.is_dir():
            shutil.rmtree(path)
        else:
            path.unlink()
        if kind == "folder":
            path.mkdir()
        return path

    return f"missing {rel} ({kind})", apply, rel in OPTIONAL_PATHS


@st.composite
def dataformat_corruption(draw):
    kind = draw(st.sampled_from(["empty", "garbage", "drop_line", "text"]))
    line = draw(st.integers(0, 40))
    value = draw(odd_text)

    def apply(drive: Path) -> Path:
        path = drive / "oxts" / "dataformat.txt"
        lines = _lines(path)
        if kind == "empty":
            lines = []
        elif kind == "drop_line":
            del lines[line % len(lines)]
        elif kind == "text":
            lines[line % len(lines)] = value
        if kind == "garbage":
            path.write_bytes(bytes(range(256)) * (1 + line % 3))
        else:
            _write_lines(path, lines)
        return path

    return f"dataformat {kind} line {line} {value!r}", apply, True


#: ``(what, apply, optional)``: ``optional`` True when the drive must still read (success is then the only outcome);
#: otherwise the file is needed, and only an error naming it is right.
unread_or_missing = st.one_of(missing_file(), dataformat_corruption())


def _read_everything(base: Path) -> None:
    """Everything the readers give for a drive; every number they return must be finite."""
    from slamlib.kitti import KittiRawDrive

    drive = KittiRawDrive(base, SAMPLE_DATE, SAMPLE_DRIVE)
    for frame in drive:
        for name in (
            "scan",
            "velocity",
            "angular_rate",
            "acceleration",
            "T_w_imu",
            "T_w_velo",
        ):
            assert np.all(np.isfinite(getattr(frame, name))), (
                f"non-finite {name} in frame {frame.index}"
            )
        assert math.isfinite(frame.dt) and frame.dt >= 0, (
            f"dt {frame.dt} in frame {frame.index}"
        )
    assert np.all(np.isfinite(drive.ground_truth_poses())), "non-finite ground truth"
    assert np.all(np.isfinite(drive.oxts_array())), "non-finite OXTS array"
    imu = drive.imu_arrays()
    for name, value in vars(imu).items():
        if isinstance(value, np.ndarray) and value.dtype.kind == "f":
            assert np.all(np.isfinite(value)), f"non-finite imu_arrays().{name}"
    # pykitti's camera calibration: slamlib checks what pykitti will read before pykitti reads it
    for name, value in drive.calib._asdict().items():
        assert np.all(np.isfinite(value)), f"non-finite calib.{name}"


def _check_data_error(exc: BaseException, path: Path, what: str) -> None:
    msg = str(exc)
    assert "\n" not in msg, f"{what}: message on several lines: {msg!r}"
    assert path.name in msg, f"{what}: message does not name {path.name}: {msg!r}"


def _read_case(pristine, what: str, apply, optional: bool | None = None) -> None:
    """Read a corrupted copy: finite frames or a one-line DataFormatError naming the file, nothing else.
    ``optional``: None, either outcome; True, the file is not needed (must read); False, it is (must fail)."""
    with _Copy(pristine) as c:
        path = apply(c.drive)
        try:
            _read_everything(c.base)
        except DataFormatError as exc:
            assert optional is not True, (
                f"{what}: the drive does not need this file, yet: {exc}"
            )
            _check_data_error(exc, path, what)
            event("DataFormatError naming the file")
        except Exception as exc:  # noqa: BLE001 - the point of the test
            pytest.fail(f"{what}: foreign exception {type(exc).__name__}: {exc}")
        else:
            assert optional is not False, f"{what}: read without a file the drive needs"
            event("success")


@_settings(80)
@given(corruption)
def test_fuzz_readers_give_finite_frames_or_a_data_format_error_naming_the_file(
    pristine, case
):
    _read_case(pristine, *case)


@_settings(12)
@given(unread_or_missing)
def test_fuzz_readers_missing_or_unread_files_read_or_name_the_file(pristine, case):
    _read_case(pristine, *case)


def _run_args(base: Path, out: Path) -> list[str]:
    return [
        "run",
        "--basedir",
        str(base),
        "--date",
        SAMPLE_DATE,
        "--drive",
        SAMPLE_DRIVE,
        "--no-progress",
        "--no-plots",
        "--particles",
        "8",
        "--points",
        "30",
        "--backend",
        "numpy",
        "--out",
        str(out),
    ]


def _check_outputs_finite(out: Path, what: str) -> None:
    from slamlib.kitti import read_kitti_poses

    json.loads(
        (out / "metrics.json").read_text(),
        parse_constant=lambda c: pytest.fail(f"{what}: {c} in metrics.json"),
    )
    for name in ("slam_poses.txt", "dead_reckoning_poses.txt"):
        if (out / name).is_file():
            assert np.all(np.isfinite(read_kitti_poses(out / name))), (
                f"{what}: non-finite {name}"
            )


def _run_case(pristine, what: str, apply, optional: bool | None = None) -> None:
    """``slamlib run`` on a corrupted copy: exit 0 with finite outputs, or a one-line SystemExit naming the file
    (a hint line may follow). ``optional`` as in :func:`_read_case`."""
    from slamlib.cli import main

    with _Copy(pristine) as c:
        path = apply(c.drive)
        out = c.tmp / "out"
        try:
            rc = main(_run_args(c.base, out))
        except SystemExit as exc:
            msg = str(exc.code)
            assert optional is not True, (
                f"{what}: the run does not need this file, yet: {msg!r}"
            )
            assert msg.startswith("slamlib run: "), f"{what}: {msg!r}"
            assert path.name in msg.splitlines()[0], (
                f"{what}: message does not name {path.name}: {msg!r}"
            )
            assert len(msg.splitlines()) == 1 or msg.splitlines()[1].startswith(
                "  hint: "
            ), f"{what}: {msg!r}"
            event("SystemExit naming the file")
        except Exception as exc:  # noqa: BLE001
            pytest.fail(f"{what}: foreign exception {type(exc).__name__}: {exc}")
        else:
            assert optional is not False, f"{what}: ran without a file the drive needs"
            assert rc == 0
            _check_outputs_finite(out, what)
            event("success, finite outputs")


@_settings(25)
@given(corruption)
def test_fuzz_slamlib_run_on_corrupted_data_finishes_finite_or_names_the_file(
    pristine, case
):
    _run_case(pristine, *case)


@_settings(6)
@given(unread_or_missing)
def test_fuzz_slamlib_run_with_missing_or_unread_files_finishes_finite_or_names_the_file(
    pristine, case
):
    _run_case(pristine, *case)


# ------------------------------------------------------------------------------------------ CLI options
class _Started(Exception):
    """Raised by the stand-in for the long work: the command accepted its options."""


def _stop(*args, **kwargs):
    raise _Started


OPTIONS = {
    "run": [
        "--particles",
        "--points",
        "--temperature",
        "--anneal-rounds",
        "--tilt-sigma",
        "--seed",
        "--noise",
        "--frames",
        "--transient-span",
    ],
    "sim1d": [
        "--particles",
        "--frames",
        "--seed",
        "--motion-noise",
        "--sensor-noise",
        "--bias",
    ],
    "sim2d": ["--particles", "--laps", "--seed", "--resolution", "--beams"],
    "synth": ["--frames", "--seed", "--drive", "--columns", "--imu-noise", "--date"],
}


@st.composite
def cli_case(draw):
    command = draw(st.sampled_from(sorted(OPTIONS)))
    names = draw(
        st.lists(st.sampled_from(OPTIONS[command]), min_size=1, max_size=2, unique=True)
    )
    values = [draw(option_text) for _ in names]
    return command, list(zip(names, values))


def _patch_long_work(monkeypatch, command: str) -> None:
    import slamlib.sim1d
    import slamlib.sim2d
    import slamlib.slam3d
    import slamlib.synth

    target = {
        "run": (slamlib.slam3d, "run_drive"),
        "sim1d": (slamlib.sim1d, "simulate"),
        "sim2d": (slamlib.sim2d, "simulate"),
        "synth": (slamlib.synth, "write_drive"),
    }[command]
    monkeypatch.setattr(*target, _stop)


@_settings(100)
@given(case=cli_case())
def test_fuzz_cli_options_start_or_exit_with_one_line_naming_the_option(
    pristine, case, capsys
):
    from slamlib.cli import main

    command, options = case
    what = f"slamlib {command} " + " ".join(f"{k}={v!r}" for k, v in options)
    with _Copy(pristine) as c:
        argv = _run_args(c.base, c.tmp / "out") if command == "run" else [command]
        if command == "synth":
            argv += [
                "--out",
                str(c.tmp / "synth"),
                "--no-progress",
                "--route",
                "straight",
            ]
        for name, value in options:
            argv.append(
                f"{name}={value}"
            )  # '=' so that a value starting with '-' is a value
        capsys.readouterr()
        with pytest.MonkeyPatch.context() as mp:
            _patch_long_work(mp, command)
            try:
                main(argv)
            except _Started:
                event(f"{command}: started")
                return
            except SystemExit as exc:
                err = capsys.readouterr().err
                if exc.code == 2 and isinstance(
                    exc.code, int
                ):  # argparse: usage + the option on stderr
                    assert any(name in err for name, _ in options), f"{what}: {err!r}"
                    event(f"{command}: argparse error naming the option")
                    return
                msg = str(exc.code)
                assert msg.startswith(f"slamlib {command}: ") and "\n" not in msg, (
                    f"{what}: {msg!r}"
                )
                assert any(name in msg for name, _ in options), (
                    f"{what}: option not named: {msg!r}"
                )
                event(f"{command}: SystemExit naming the option")
                return
            except Exception as exc:  # noqa: BLE001
                pytest.fail(f"{what}: foreign exception {type(exc).__name__}: {exc}")
        pytest.fail(f"{what}: returned without starting the work")
