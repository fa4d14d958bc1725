"""tests/conftest.py: the skips for missing real data are one summary line, other skips are listed as usual."""

from __future__ import annotations

from pathlib import Path

pytest_plugins = ["pytester"]

CONFTEST = Path(__file__).with_name("conftest.py")


def test_skips_for_missing_data_are_one_line_and_other_skips_are_listed(pytester, monkeypatch):
    monkeypatch.setenv("AVIO_DATA", str(pytester.path / "nowhere"))
    pytester.makeconftest(CONFTEST.read_text())
    pytester.makepyfile(test_data="""
        import pytest

        @pytest.mark.parametrize("i", range(3))
        def test_reads_data(shared_data, i):
            pass

        def test_reads_a_file(shared_data, skip_no_data):
            skip_no_data("the file")

        def test_other():
            pytest.skip("needs git")

        def test_ok():
            pass
    """)
    result = pytester.runpytest_subprocess("-ra", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, skipped=5)  # the final counts are unchanged
    nowhere = pytester.path / "nowhere"
    result.stdout.fnmatch_lines([
        "SKIPPED [[]1[]] test_data.py:*: needs git",
        f"SKIPPED 4 tests: real data absent: no folder {nowhere} (set AVIO_DATA to use another folder)",
    ])
    assert sum(line.startswith("SKIPPED") for line in result.outlines) == 2


def test_without_skip_reports_nothing_is_added(pytester, monkeypatch):
    monkeypatch.setenv("AVIO_DATA", str(pytester.path / "nowhere"))
    pytester.makeconftest(CONFTEST.read_text())
    pytester.makepyfile(test_data="def test_reads_data(shared_data):\n    pass\n")
    result = pytester.runpytest_subprocess("-rf", "-p", "no:cacheprovider")
    result.assert_outcomes(skipped=1)
    assert not any(line.startswith("SKIPPED") for line in result.outlines)
