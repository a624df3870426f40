"""Plant issue 15's four bugs again, one at a time, and show which unit test catches each.

``python tests/mutation/planted.py`` (``make planted``; ``make mutate`` runs it last). Each bug is planted in a
fresh copy of ``slamlib`` and ``tests`` under a temporary folder (never in the checkout) and the named tests are run
there: each must fail, having passed on the unplanted copy first. Exit status 1 if any planted bug passes its tests
(or its code is no longer where the plant expects it: the text to replace must occur exactly once), else 0. Prints a
Markdown table for tests/mutation/REPORT.md.

The four bugs passed every test before issue 15 (its description): the end-to-end checks are robust to them.
"""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

#: (description, file, original text, planted text, tests that must fail)
PLANTS = [
    (
        "ESS = `1 / max(w)` instead of `1 / sum(w^2)`",
        "slamlib/resampling.py",
        "ess = 1.0 / float(np.sum(w * w))",
        "ess = 1.0 / float(np.max(w))",
        [
            "tests/test_resampling.py::test_effective_sample_size_on_uneven_weights_is_one_over_sum_of_squares"
        ],
    ),
    (
        'KITTI segment end: first frame with `d >= d_f + L` (`side="left"`)',
        "slamlib/metrics.py",
        'last = np.searchsorted(d, d[first] + length, side="right")',
        'last = np.searchsorted(d, d[first] + length, side="left")',
        [
            "tests/test_metrics.py::test_kitti_segment_ends_at_the_first_frame_strictly_beyond_the_length"
        ],
    ),
    (
        "1D filter drops the prior weights: `normalise(scores)`",
        "slamlib/contract.py",  # the 1D and 2D filters' shared loop, StepsFilter.step
        "log_w = normalise_log_weights(self.log_weights + scores)",
        "log_w = normalise_log_weights(scores)",
        [
            "tests/test_sim1d.py::test_filter_weights_are_prior_times_likelihood_between_resamplings"
        ],
    ),
    (
        "`VoxelHashMap` merge does not refresh the last voxel touched",
        "slamlib/maps/voxel_hash.py",
        "    # previous point's voxel, which the next points of a ring often share)\n    for j in range(n):",
        "    # previous point's voxel, which the next points of a ring often share)\n    for j in range(n - 1):",
        [
            "tests/test_maps.py::test_voxel_hash_statistics_after_merging_one_point",
            "tests/test_maps.py::test_voxel_hash_merge_in_pieces_equals_merge_at_once",
        ],
    ),
]


def _run(work: Path, *args: str) -> subprocess.CompletedProcess:
    """``python ARGS`` in the copy ``work``, importing the copy's slamlib, with a Numba cache of its own."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(work / "numba"), PYTHONPATH=str(work))
    return subprocess.run(
        [sys.executable, *args], cwd=work, env=env, capture_output=True, text=True
    )


def _pytest(work: Path, *tests: str) -> subprocess.CompletedProcess:
    return _run(
        work, "-m", "pytest", "-p", "no:dash", "-p", "no:cacheprovider", "-q", *tests
    )


def run_plant(
    work: Path, file: str, original: str, planted: str, tests: list[str]
) -> list[tuple[str, str]]:
    """Plant one bug in ``work`` (a copy), run each test there, restore; ``[(test, outcome)]``."""
    path = work / file
    source = path.read_text(encoding="utf-8")
    if source.count(original) != 1:
        return [
            (
                t,
                f"NOT PLANTED: {original!r} occurs {source.count(original)} times in {file}",
            )
            for t in tests
        ]
    out = []
    try:
        path.write_text(source.replace(original, planted), encoding="utf-8")
        for test in tests:
            r = _pytest(work, test)
            out.append(
                (
                    test,
                    "fails (caught)"
                    if r.returncode == 1
                    else f"NOT CAUGHT (pytest exit {r.returncode})",
                )
            )
    finally:
        path.write_text(source, encoding="utf-8")
    return out


def main() -> int:
    with tempfile.TemporaryDirectory(prefix="slamlib-planted-") as tmp:
        work = Path(tmp)
        for part in ("slamlib", "tests"):
            shutil.copytree(
                ROOT / part,
                work / part,
                ignore=shutil.ignore_patterns("__pycache__", "mutation"),
            )
        shutil.copy(ROOT / "pyproject.toml", work)
        found = _run(work, "-c", "import slamlib; print(slamlib.__file__)")
        if found.returncode != 0:
            sys.exit(
                f"planted.py: the copy cannot import slamlib:\n{found.stderr[-3000:]}"
            )
        where = found.stdout.strip()
        if not Path(where).is_relative_to(
            work
        ):  # an installed slamlib would shadow the planted copy
            sys.exit(
                f"planted.py: the copy's tests import slamlib from {where}, not from {work}"
            )
        every = [t for *_, tests in PLANTS for t in tests]
        clean = _pytest(work, *every)
        if clean.returncode != 0:  # a failure below must be the plant's doing
            sys.exit(
                f"planted.py: the tests fail on the unplanted copy:\n{clean.stdout[-3000:]}"
            )
        rows, ok = [], True
        for what, file, original, planted, tests in PLANTS:
            for test, outcome in run_plant(work, file, original, planted, tests):
                ok &= outcome.startswith("fails")
                rows.append(f"| {what} | `{test}` | {outcome} |")
    print("| planted bug | test | outcome |\n|---|---|---|")
    print("\n".join(rows))
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
