"""The CUDA tests' outcome on a real GPU as committed JSON (``benchmarks/results/cuda-tests.json``).

``python -m benchmarks.gpu_tests_summary JUNIT_XML NVIDIA_SMI_CSV OUT_JSON``, run by ``benchmarks/gpu_check.sh``
after ``SLAMLIB_REAL_CUDA=1 pytest ... --junitxml``: each test's outcome (passed, skipped with the reason,
failed with the message's first line), the counts, the card and driver from ``nvidia-smi`` and the machine
(:func:`slamlib.machine.describe`), so the book can say which card ran the kernels' tests.
"""

from __future__ import annotations

import csv
import json
import sys
import xml.etree.ElementTree as ET


def outcome(case: ET.Element) -> tuple[str, str]:
    """``(outcome, detail)`` of one JUnit ``testcase``: passed, skipped, failed or error."""
    for tag in ("failure", "error", "skipped"):
        node = case.find(tag)
        if node is not None:
            detail = (node.get("message") or "").splitlines()[:1]
            return {"failure": "failed"}.get(tag, tag), detail[0] if detail else ""
    return "passed", ""


def summarise(junit_xml: str, nvidia_smi_csv: str, machine: dict) -> dict:
    """The JSON of this module's docstring from the two files and a machine description."""
    tests = [
        {
            "test": f"{c.get('classname')}::{c.get('name')}",
            "seconds": float(c.get("time", 0)),
            **dict(zip(("outcome", "detail"), outcome(c))),
        }
        for c in ET.parse(junit_xml).getroot().iter("testcase")
    ]
    with open(nvidia_smi_csv) as f:
        card = {
            k.strip(): v.strip()
            for k, v in next(csv.DictReader(f, skipinitialspace=True)).items()
        }
    counts = {
        o: sum(t["outcome"] == o for t in tests)
        for o in ("passed", "skipped", "failed", "error")
    }
    return {
        "benchmark": "cuda-tests",
        "machine": machine,
        "nvidia_smi": card,
        "counts": counts,
        "tests": tests,
    }


if __name__ == "__main__":
    from slamlib.machine import describe

    junit, smi, out = sys.argv[1:4]
    with open(out, "w") as f:
        json.dump(summarise(junit, smi, describe()), f, indent=1)
