"""tools.id_loss: the missing IDs of a run split by when they happen, per truth LED."""

from __future__ import annotations

from tools.id_loss import id_loss


def _frame(k, *leds):
    return {"frame": k, "leds": [{"cx": x, "cy": y, "id": i, "border": False} for x, y, i in leds]}


def test_missing_ids_split_into_before_never_and_after():
    """LED 7 is missing in frames 0-1, right in 2-3, missing in 4 and wrong in 5; LED 9 is
    never decoded; an observation far from every truth LED is not counted."""
    truth = {k: {"targets": [(100.0, 100.0, 7, 2.0), (500.0, 300.0, 9, 2.0)]} for k in range(6)}
    ids7 = [None, None, 7, 7, None, 8]
    run = [_frame(k, (101.0, 99.0, ids7[k]), (499.0, 301.0, None), (900.0, 700.0, 5)) for k in range(6)]
    r = id_loss(run, truth)
    assert (r["matched"], r["right"], r["wrong"]) == (12, 2, 1)
    assert (r["before"], r["never"], r["after"]) == (2, 6, 1)
    assert list(r["leds"]) == [7, 9]
    assert [s for _, s, _ in r["leds"][7]] == ["missing", "missing", "right", "right", "missing", "wrong"]
