"""Kill ``slamlib synth``, ``slamlib run`` and ``slamlib sweep`` at random points of their work and check what they
leave: never a mixed output, and no temporary once the process (or, after ``SIGKILL``, the next writer) is done.

Each kill point: the command writes over an earlier complete output of another setting (seed); a signal (SIGKILL,
SIGTERM or SIGINT, drawn) arrives after a random delay within the command's measured duration, from the end of the
interpreter's own start-up on (a signal before any slamlib code runs ends Python the way Python does). Then the
output must be exactly the earlier one, or exactly the new one (synth: every file; run: the poses and the set of files
of the new run; sweep: no table, or the whole table), the user's file in it untouched; after SIGTERM / SIGINT nothing
but the output may be left beside it, and after SIGKILL the same command run again must finish and clean up.

    python tests/faults/kill_points.py --count 200            # the local run of issue 34 (~20 min on 2 cores)
    python tests/faults/kill_points.py --count 6 --seed 1     # a few, as tests/test_atomic.py runs it

Prints one line per kill point and a summary; exits 1 on the first violation, naming it.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SIGNALS = (signal.SIGKILL, signal.SIGTERM, signal.SIGINT)
DRIVE = Path("2011_09_26") / "2011_09_26_drive_0001_sync"
SYNTH = ["--route", "loop", "--frames", "12", "--columns", "300", "--no-progress"]
SWEEP = [
    "--routes",
    "loop",
    "--frames",
    "0:12",
    "--methods",
    "slamlib",
    "--particles",
    "30",
]


def slamlib(*args, env=None) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "slamlib.cli", *map(str, args)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, **(env or {})},
    )


def tree(folder: Path) -> dict:
    """``{relative path: sha1}`` of every file under ``folder`` (empty when it does not exist)."""
    if not folder.exists():
        return {}
    return {
        str(p.relative_to(folder)): hashlib.sha1(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def leftovers(parent: Path, keep: set) -> list:
    """Entries beside the outputs that are not the outputs: temporaries, locks."""
    return sorted(p.name for p in parent.iterdir() if p.name not in keep)


def visible(folder: Path) -> set:
    """The names in ``folder`` that are not hidden: temporaries and locks are, outputs are not."""
    return {p.name for p in folder.iterdir() if not p.name.startswith(".")}


def finish(*args) -> None:
    proc = slamlib(*args)
    _, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"slamlib {' '.join(map(str, args))} failed: {err.strip()}")


def timed(*args) -> float:
    t0 = time.perf_counter()
    finish(*args)
    return time.perf_counter() - t0


class Case:
    """One command's setting: ``prepare()`` writes the earlier output and the references, ``start()`` the
    command to kill, ``check(sig)`` the output after the kill, ``rerun()`` the command run again to its end."""

    def __init__(self, root: Path):
        self.root = root


class Synth(Case):
    name = "synth"

    def prepare(self):
        self.out, ref = self.root / "synth", self.root / "synth-ref"
        finish("synth", "--out", ref, *SYNTH, "--seed", 1)
        self.new = tree(ref / DRIVE)
        self.duration = timed("synth", "--out", self.root / "timing", *SYNTH, "--seed", 1)

    def reset(self):
        import shutil

        shutil.rmtree(self.out, ignore_errors=True)
        finish("synth", "--out", self.out, *SYNTH, "--seed", 0)
        (self.out / DRIVE / "notes.txt").write_text("mine")
        self.old = tree(self.out / DRIVE)

    def start(self):
        return slamlib("synth", "--out", self.out, *SYNTH, "--seed", 1)

    def check(self):
        now = tree(self.out / DRIVE)
        new = dict(self.new, **{"notes.txt": self.old["notes.txt"]})
        if now not in (self.old, new):
            return "mixed drive"
        if now.get("notes.txt") != self.old["notes.txt"]:
            return "the user's file lost"
        return None

    def beside(self):
        return self.out / DRIVE.parent, {DRIVE.name} | {
            "calib_imu_to_velo.txt",
            "calib_velo_to_cam.txt",
            "calib_cam_to_cam.txt",
        }

    def rerun(self):
        finish("synth", "--out", self.out, *SYNTH, "--seed", 1)


class Run(Case):
    name = "run"

    def prepare(self):
        self.data = self.root / "drive"
        finish("synth", "--out", self.data, *SYNTH, "--seed", 3)
        self.args = ["--basedir", self.data, "--date", "2011_09_26", "--drive", 1]
        self.args += ["--particles", 50, "--no-progress"]
        ref = self.root / "run-ref"
        self.duration = timed("run", *self.args, "--seed", 1, "--out", ref)
        self.new_poses = (ref / "slam_poses.txt").read_bytes()
        self.new_files = set(tree(ref))

    def reset(self):
        import shutil

        self.out = self.root / "run"
        shutil.rmtree(self.out, ignore_errors=True)
        finish("run", *self.args, "--seed", 0, "--no-plots", "--out", self.out)
        (self.out / "notes.txt").write_text("mine")
        self.old = tree(self.out)

    def start(self):
        return slamlib("run", *self.args, "--seed", 1, "--out", self.out)

    def check(self):
        now = tree(self.out)
        if now == self.old:
            return None
        if (self.out / "slam_poses.txt").read_bytes() != self.new_poses:
            return "mixed results (poses of neither run)"
        if set(now) != self.new_files | {"notes.txt"}:
            return f"mixed results (files {sorted(set(now) ^ (self.new_files | {'notes.txt'}))})"
        if now["metrics.json"] == self.old["metrics.json"]:
            return "mixed results (the old metrics beside the new poses)"
        return None

    def beside(self):
        return self.root, visible(self.root)

    def rerun(self):
        finish("run", *self.args, "--seed", 1, "--out", self.out)


class Sweep(Case):
    name = "sweep"

    def prepare(self):
        self.data = self.root / "sweep-data"
        self.duration = timed(
            "sweep",
            "--out",
            self.root / "sweep-timing",
            "--data",
            self.data,
            *SWEEP,
            "--seeds",
            "0",
            "--no-progress",
        )

    def reset(self):
        import shutil

        self.out = self.root / "sweep"
        shutil.rmtree(self.out, ignore_errors=True)

    def start(self):
        return slamlib(
            "sweep",
            "--out",
            self.out,
            "--data",
            self.data,
            *SWEEP,
            "--seeds",
            "0,1",
            "--no-progress",
        )

    def check(self):
        from slamlib.commands.sweep import JOURNAL
        from slamlib.experiments.sweep import read_table

        if not self.out.exists():
            return None
        names = {p.name for p in self.out.iterdir()}
        if names - {"sweep.csv", "sweep.json", "sweep.png", JOURNAL}:
            return f"unexpected files {sorted(names)}"
        table = {"sweep.csv", "sweep.json", "sweep.png"}
        if names & table and not table <= names:
            return f"a partial table {sorted(names)}"
        if "sweep.csv" in names and len(read_table(self.out / "sweep.csv")) != 2:
            return "a table without all its rows"
        return None

    def beside(self):
        # the output folder itself is check()'s (a resume journal may stay)
        return self.root, visible(self.root)

    def rerun(self):
        finish(
            "sweep",
            "--out",
            self.out,
            "--data",
            self.data,
            *SWEEP,
            "--seeds",
            "0,1",
            "--no-progress",
            "--overwrite",
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--commands",
        default="synth,run,sweep",
        help="which to kill, in turn (default all three)",
    )
    args = parser.parse_args()
    rng = random.Random(args.seed)
    counts = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        chosen = args.commands.split(",")
        cases = [c(root) for c in (Synth, Run, Sweep) if c.name in chosen]
        for case in cases:
            case.prepare()
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import slamlib.cli"], check=True)
        startup = time.perf_counter() - t0
        for n in range(args.count):
            case = cases[n % len(cases)]
            sig = rng.choice(SIGNALS)
            case.reset()
            delay = rng.uniform(startup, 1.1 * case.duration)
            proc = case.start()
            time.sleep(delay)
            proc.send_signal(sig)
            _, err = proc.communicate()
            problem = case.check()
            parent, keep = case.beside()
            left = leftovers(parent, keep)
            if sig != signal.SIGKILL and left:
                problem = problem or f"left behind {left}"
            # -sig: the signal came before slamlib's handlers were in place (the interpreter's start-up) or after
            # they were restored (its shutdown): the output is checked the same
            early = sig != signal.SIGKILL and proc.returncode == -sig
            if (
                sig != signal.SIGKILL
                and proc.returncode not in (0, 130, 143)
                and not early
            ):
                problem = problem or f"exit {proc.returncode}: {err.strip()[-300:]}"
            if "Traceback" in err:
                problem = problem or f"a traceback: {err.strip()[-300:]}"
            # a dead writer's temporaries go with the next writer
            case.rerun()
            parent, keep = case.beside()
            left = leftovers(parent, keep)
            if left:
                problem = problem or f"left behind after the next run {left}"
            what = f"{case.name:5s} {signal.Signals(sig).name:7s} after {delay:5.2f} s exit {proc.returncode}"
            print(f"{n + 1:4d} {what}: {problem or 'ok'}", flush=True)
            if problem:
                print(f"FAILED: {what}: {problem}")
                return 1
            key = (
                case.name,
                signal.Signals(sig).name + (" (outside the command)" if early else ""),
            )
            counts[key] = counts.get(key, 0) + 1
    print(f"{args.count} kill points, no mixed output and nothing left behind:")
    for (name, sig), k in sorted(counts.items()):
        print(f"  {name} {sig}: {k}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
