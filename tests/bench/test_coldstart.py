"""bench/coldstart.py: the parts of a cold start, a column per variant."""

from __future__ import annotations

from bench.coldstart import PARTS, parse_variants, table


def test_variants_are_name_equals_checkout() -> None:
    assert parse_variants("base=/work/wt/base, new=.") == {"base": "/work/wt/base", "new": "."}
    assert parse_variants("this") == {"this": "."}


def test_the_table_gives_each_part_median_and_range_in_ms() -> None:
    runs = [{part: s for part in PARTS} for s in (0.1, 0.3, 0.2)]
    lines = table({"base": runs, "new": runs[:1]}).splitlines()
    assert lines[0] == "| part (ms, median (min-max)) | base | new |"
    assert lines[2] == "| interpreter | 200 (100-300) | 100 (100-100) |"
    assert [line.split(" | ")[0].lstrip("| ") for line in lines[2:]] == list(PARTS)
