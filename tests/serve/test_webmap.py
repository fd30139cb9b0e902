"""The live web map at `occloc serve --http`'s `/`, in a real headless Chromium (the
distribution's /usr/bin/chromium driven by Playwright's Python package): a device run against
the server is drawn at its position on the LED map. With OCCLOC_DOCS_SCREENSHOT=1 the test saves
the screenshot the docs show (docs/img/webmap.png); otherwise it leaves the tree as it is."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.serve.test_server import WALK
from tests.serve.test_server_http import serve, stop

ROOT = Path(__file__).resolve().parents[2]
CHROMIUM = Path("/usr/bin/chromium")
SCREENSHOT = ROOT / "docs" / "img" / "webmap.png"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
        "--disable-component-update", "--disable-sync", "--no-first-run"]

sync_api = pytest.importorskip("playwright.sync_api")
if not CHROMIUM.exists():
    pytest.skip("no /usr/bin/chromium (tools/dev test installs it)", allow_module_level=True)


def _centre(box) -> tuple[float, float]:
    return box["x"] + box["width"] / 2, box["y"] + box["height"] / 2


def test_web_map_draws_the_device_at_its_position(tmp_path, capsys):
    shot = SCREENSHOT if os.environ.get("OCCLOC_DOCS_SCREENSHOT") == "1" else tmp_path / "webmap.png"
    from receiver.cli import main as cli

    out = tmp_path / "r.jsonl"
    with serve() as (proc, udp, http), sync_api.sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=ARGS)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 800})
            page.goto(http + "/", timeout=30_000)
            page.wait_for_function("window.occlocReady === true", timeout=30_000)
            leds = page.locator("rect.led")
            n_map = len(json.loads((WALK / "map.json").read_text())["leds"])
            assert leds.count() == n_map and page.locator("text.ledid").count() == n_map
            assert cli(["run", str(WALK), "--max-frames", "24", "--server", udp, "--server-timeout", "30",
                        "--out", str(out)]) == 0
            capsys.readouterr()
            last = [json.loads(line)["position"] for line in out.read_text().splitlines()][-1]
            marker = page.locator("circle.marker")
            marker.wait_for(timeout=30_000)
            page.wait_for_function(f"document.querySelector('circle.marker').dataset.x == '{last['x']}'",
                                   timeout=30_000)
            # Where the map puts (x, y), from two LEDs' drawn centres (not the page's own transform).
            a, b = leds.nth(0), leds.nth(n_map - 1)
            (ax, ay), (bx, by) = _centre(a.bounding_box()), _centre(b.bounding_box())
            (mx, my) = (float(a.get_attribute("data-x")), float(a.get_attribute("data-y")))
            (nx, ny) = (float(b.get_attribute("data-x")), float(b.get_attribute("data-y")))
            assert mx != nx and my != ny
            want = (ax + (last["x"] - mx) * (bx - ax) / (nx - mx), ay + (last["y"] - my) * (by - ay) / (ny - my))
            got = _centre(marker.bounding_box())
            assert abs(got[0] - want[0]) < 2.0 and abs(got[1] - want[1]) < 2.0, (got, want)
            assert page.locator("ellipse.ellipse").count() == 1 and page.locator("line.heading").count() == 1
            assert page.locator("line.trail").count() >= 10
            row = page.locator("#list tr")
            page.wait_for_function(f"document.querySelector('#list tr').innerText.includes('{last['x']:.2f}, "
                                   f"{last['y']:.2f}')", timeout=30_000)
            assert row.count() == 1
            page.screenshot(path=str(shot))
        finally:
            browser.close()
        stop(proc)
    assert shot.stat().st_size > 10_000
