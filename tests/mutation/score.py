"""Mutation score per module from ``mutmut results --all true`` output (``make mutate`` runs it).

Usage: ``python tests/mutation/score.py results.txt [more.txt ...]`` (``make mutate`` passes its two groups'
files: a mutant is counted in the file where it was checked). A line
``    slamlib.metrics.x_f__mutmut_3: killed`` counts
for module ``slamlib.metrics``. Score = killed (+ timeout) / (all - skipped), as mutmut's own badge; mutants with
no covering test count as not killed. Prints a Markdown table and then every mutant not killed.
"""

import re
import sys
from collections import Counter, defaultdict

KILLED = {"killed", "timeout", "caught by type check"}


def module_of(name: str) -> str:
    """``slamlib.metrics.x_f__mutmut_3`` -> ``slamlib.metrics``; methods (``xǁClassǁm``) too."""
    return re.split(r"\.x[_\u01c1]", name, maxsplit=1)[0]


def main(paths: list[str]) -> None:
    counts: dict[str, Counter] = defaultdict(Counter)
    alive: list[str] = []
    lines = [line for path in paths for line in open(path, encoding="utf-8")]
    for line in lines:
        line = line.strip()
        if "__mutmut_" not in line or ": " not in line:
            continue
        name, status = line.rsplit(": ", 1)
        if status == "not checked":  # outside this run's MUTANTS globs
            continue
        counts[module_of(name)][status] += 1
        if status not in KILLED and status != "skipped":
            alive.append(f"{name}: {status}")
    print("| module | mutants | killed | survived | no tests | other | score |")
    print("|---|---|---|---|---|---|---|")
    for mod, c in sorted(counts.items()):
        tested = sum(c.values()) - c["skipped"]
        killed = sum(c[s] for s in KILLED)
        other = tested - killed - c["survived"] - c["no tests"]
        score = 100.0 * killed / tested if tested else float("nan")
        print(
            f"| {mod} | {tested} | {killed} | {c['survived']} | {c['no tests']} | {other} | {score:.1f} % |"
        )
    print()
    for a in alive:
        print(a)


if __name__ == "__main__":
    main(sys.argv[1:])
