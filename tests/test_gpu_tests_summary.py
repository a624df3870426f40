"""benchmarks.gpu_tests_summary: the CUDA tests' JUnit report on a GPU, summarised as committed JSON."""

from benchmarks.gpu_tests_summary import summarise

JUNIT = """<?xml version="1.0" encoding="utf-8"?>
<testsuites><testsuite name="pytest" errors="0" failures="1" skipped="1" tests="4">
<testcase classname="tests.test_a" name="test_ok" time="0.5" />
<testcase classname="tests.test_a" name="test_skip" time="0.0">
  <skipped type="pytest.skip" message="checks what happens without a GPU">reason</skipped></testcase>
<testcase classname="tests.test_b" name="test_bad[x]" time="1.25">
  <failure message="AssertionError: 3 != 4&#10;second line">trace</failure></testcase>
<testcase classname="tests.test_b" name="test_broken" time="0.1">
  <error message="fixture failed">trace</error></testcase>
</testsuite></testsuites>
"""
SMI = "name, driver_version, memory.total [MiB]\nNVIDIA H100 80GB HBM3, 580.159.04, 81559 MiB\n"


def test_each_outcome_with_its_first_line_and_the_card(tmp_path):
    (tmp_path / "t.xml").write_text(JUNIT)
    (tmp_path / "smi.csv").write_text(SMI)
    d = summarise(str(tmp_path / "t.xml"), str(tmp_path / "smi.csv"), {"gpu": "card"})
    assert d["counts"] == {"passed": 1, "skipped": 1, "failed": 1, "error": 1}
    by = {t["test"]: t for t in d["tests"]}
    assert by["tests.test_a::test_ok"] == {
        "test": "tests.test_a::test_ok",
        "seconds": 0.5,
        "outcome": "passed",
        "detail": "",
    }
    assert by["tests.test_a::test_skip"]["detail"] == "checks what happens without a GPU"
    assert by["tests.test_b::test_bad[x]"]["detail"] == "AssertionError: 3 != 4"
    assert by["tests.test_b::test_broken"]["outcome"] == "error"
    assert d["nvidia_smi"]["driver_version"] == "580.159.04"
    assert d["machine"] == {"gpu": "card"}
