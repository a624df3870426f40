"""The console script and the package's public basics."""

import subprocess
import sys

import pytest

import slamlib
from slamlib.cli import build_parser, main
from slamlib.commands import COMMANDS
from slamlib.paths import kitti_sample_dir


def test_version_is_a_release_string():
    parts = slamlib.__version__.split(".")
    assert len(parts) == 3 and all(p.isdigit() for p in parts)


def test_help_lists_every_command(capsys):
    parser = build_parser()
    text = parser.format_help()
    for name in COMMANDS:
        assert name in text


def test_console_script_runs_as_module():
    out = subprocess.run(
        [sys.executable, "-m", "slamlib.cli", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    assert "bench" in out


def test_no_command_prints_help(capsys):
    assert main([]) == 0
    assert "usage: slamlib" in capsys.readouterr().out


def test_shipped_kitti_samples_keep_their_attribution():
    readme = (kitti_sample_dir() / "README.md").read_text()
    assert "CC BY-NC-SA 3.0" in readme and "Geiger" in readme
    assert (kitti_sample_dir() / "raw/2011_09_26/calib_imu_to_velo.txt").is_file()


# ------------------------------------------------------------------ an option's value that looks like an option
@pytest.mark.parametrize(
    "command,option", [("synth", "--drive"), ("sim2d", "--particles")]
)
def test_option_equals_double_dash_is_a_one_line_error(tmp_path, capsys, command, option):
    from slamlib.cli import main

    argv = [command, f"{option}=--"] + (
        ["--out", str(tmp_path / "s")] if command == "synth" else []
    )
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and option in capsys.readouterr().err


def test_a_full_disk_anywhere_is_one_line_with_the_file_and_the_free_space(
    monkeypatch, capsys
):
    """An ``ENOSPC`` from any command (here a plotting write of ``sim1d``) ends it with one line naming the file
    and the free space, exit 1, no traceback."""
    import errno

    import slamlib.commands.sim1d as sim1d

    def full(args):
        raise OSError(errno.ENOSPC, "No space left on device", "/tmp/x/plot.png")

    monkeypatch.setattr(sim1d, "main", full)
    from slamlib.cli import main

    assert main(["sim1d"]) == 1
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("slamlib sim1d: /tmp/x/plot.png: no space left on the disk (")
    assert line.endswith(" free there)")


def test_a_signal_swallowed_in_a_destructor_still_ends_the_command_as_it_asks(
    monkeypatch, capsys
):
    """SIGTERM arriving while a destructor runs: Python cannot raise there and would print "Exception ignored";
    the command finishes, prints no such report, and ends with the one line and exit 143."""
    import os
    import signal

    import slamlib.commands.sim1d as sim1d

    class Dying:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGTERM)
            for _ in range(1000):  # bytecodes for the handler to run in
                pass

    def command(args):
        Dying()  # collected at once, its destructor signalling
        return 0

    monkeypatch.setattr(sim1d, "main", command)
    assert main(["sim1d"]) == 143
    err = capsys.readouterr().err
    assert (
        err.strip() == "slamlib sim1d: terminated (SIGTERM); nothing half written is left"
    )


def test_a_swallowed_signal_is_sent_again_and_stops_a_long_command(monkeypatch, capsys):
    """The signal swallowed in a destructor is sent again a moment later and stops the command where it runs:
    Ctrl-C is not put off to the end of a long run."""
    import os
    import signal
    import time

    import slamlib.commands.sim1d as sim1d

    finished = []

    class Dying:
        def __del__(self):
            os.kill(os.getpid(), signal.SIGINT)
            for _ in range(1000):
                pass

    def command(args):
        Dying()
        t0 = time.monotonic()
        while time.monotonic() - t0 < 5.0:  # a long command
            pass
        finished.append(True)
        return 0

    monkeypatch.setattr(sim1d, "main", command)
    t0 = time.monotonic()
    assert main(["sim1d"]) == 130
    assert not finished and time.monotonic() - t0 < 2.0
    assert capsys.readouterr().err.strip() == (
        "slamlib sim1d: interrupted (Ctrl-C); nothing half written is left"
    )
