"""Take the README's screenshot of the HUD: a live dry-run of the A320 on the busy apron,
seen in Debian's headless Chromium after SECONDS of simulated time.

Usage: python docs/hud_screenshot.py [--seconds 70] [--out docs/img/hud.png]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from executive.core.resources import missions_dir
from executive.hud.live import LiveDryRun
from sim2d.scenario import load_scenario


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=70.0)
    parser.add_argument("--scenario", default="busy-apron")
    parser.add_argument("--out", type=Path, default=Path("docs/img/hud.png"))
    args = parser.parse_args()
    scenario = load_scenario(missions_dir() / "a320" / "scenarios" / f"{args.scenario}.xml")
    with (
        tempfile.TemporaryDirectory() as tmp,
        LiveDryRun(scenario, Path(tmp), pace=4.0) as live,
        sync_playwright() as p,
    ):
        browser = p.chromium.launch(
            executable_path="/usr/bin/chromium",
            args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
        )
        page = browser.new_page(viewport={"width": 1280, "height": 760})
        page.goto(live.server.url)
        while live.sim.time < args.seconds:
            time.sleep(0.2)
        page.wait_for_timeout(500)
        page.screenshot(path=str(args.out))
        browser.close()
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
