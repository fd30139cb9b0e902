"""tools/perf_page: the per-megapixel table of the performance page and its --scales check."""

from __future__ import annotations

import pytest

from tools import perf_page


def _case(name, w, h, medians, p99s):
    return [{"case": name, "size": [w, h], "total": {"median_ms": m, "p99_ms": p},
             "stages": {"detect": {"median_ms": m / 2}}} for m, p in zip(medians, p99s)]


def test_scale_table_gives_ms_per_megapixel_and_ratio_to_the_first_size():
    runs = [{"cases": _case("indoor-walk@1280x720", 1280, 720, [2.0], [4.0])
             + _case("indoor-walk@1920x1080", 1920, 1080, [6.0], [9.0])},
            {"cases": _case("indoor-walk@1280x720", 1280, 720, [3.0], [5.0])
             + _case("indoor-walk@1920x1080", 1920, 1080, [5.0], [8.0])}]
    rows = perf_page.summarise(runs)
    lines = perf_page.scale_table(rows)
    body = [ln for ln in lines if ln.startswith("| 1")]
    assert len(body) == 2
    # 720p: median of 2 and 3 = 2.5 ms over 0.9216 MP; 1080p: 5.5 ms over 2.0736 MP
    ref = 2.5 / 0.9216
    assert body[0].split(" | ")[4] == f"{ref:.2f}" and body[0].split(" | ")[5] == "1.00"
    assert body[1].split(" | ")[4] == f"{5.5 / 2.0736:.2f}"
    assert body[1].split(" | ")[5] == f"{5.5 / 2.0736 / ref:.2f}"
    assert "8.00-9.00" in body[1]
    page = perf_page.page(rows, "python -m tools.perf_page", 2, "native", rows)
    assert "Cost per megapixel" in page and page.count("| 1920x1080 |") == 2


def test_no_scales_no_table():
    assert perf_page.scale_table([]) == []


@pytest.mark.parametrize("bad", ["1920", "1920x", "axb", "1920x1080,huge"])
def test_bad_scales_is_a_usage_error(bad, capsys):
    with pytest.raises(SystemExit) as e:
        perf_page.main(["--scales", bad, "--out", "/nonexistent/never-written.md"])
    assert e.value.code == 2
    assert "--scales" in capsys.readouterr().err
