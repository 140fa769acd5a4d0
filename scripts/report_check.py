"""The report as a person sees it (make report-check): a shipped problem fitted with --report, the
page opened in headless Chromium (Debian's `chromium`), its DOM and a screenshot checked.

Passes when the browser's DOM holds the page's figures (PNG data URIs) and tables and nothing
fetched from elsewhere, and the screenshot is not blank and shows the figures drawn: pixels of
matplotlib's first line colour, which the page's own style never uses. Writes the screenshot to
results/report-check/ (or the folder given) for a person to look at.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
from PIL import Image

from crashnlp.cli import main

PROBLEM = Path("problems/pickup-56kph.yaml")
WINDOW = (1280, 6000)  # the whole page of the pickup's fit in one screenshot
FIGURE_BLUE = np.array([31, 119, 180])  # matplotlib's C0, the model's curves
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--hide-scrollbars",
)


class Elements(HTMLParser):
    """What the browser's DOM holds: embedded images, tables, and references to anything outside."""

    def __init__(self) -> None:
        super().__init__()
        self.images, self.tables, self.outside = 0, 0, []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if tag == "img" and (values.get("src") or "").startswith("data:image/png;base64,"):
            self.images += 1
        if tag == "table":
            self.tables += 1
        self.outside += [v for k, v in attrs if k in ("src", "href") and v and not v.startswith("data:")]


def chromium(page: Path, *args: str) -> str:
    """Run headless Chromium on the page with a fresh profile; its standard output."""
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        sys.exit("report-check: no chromium (apt-get install chromium)")
    with tempfile.TemporaryDirectory(prefix="crashnlp-chromium-") as profile:
        command = [browser, *FLAGS, f"--user-data-dir={profile}", *args, page.resolve().as_uri()]
        done = subprocess.run(command, capture_output=True, text=True, timeout=180, check=True)
    return done.stdout


def check(out: Path) -> list[str]:
    """Fit, write the report, open it; what failed (empty: all passed)."""
    fit = out / "fit"
    if main(["identify", str(PROBLEM), "--out", str(fit), "--report"]) != 0:
        return [f"crashnlp identify {PROBLEM} --report failed"]
    page = fit / "report.html"
    dom = Elements()
    dom.feed(chromium(page, "--dump-dom"))
    shot = out / "report.png"
    chromium(page, f"--screenshot={shot}", f"--window-size={WINDOW[0]},{WINDOW[1]}")
    pixels = np.asarray(Image.open(shot).convert("RGB"), dtype=int)
    colours = len(np.unique(pixels.reshape(-1, 3), axis=0))
    blue = int(np.sum(np.all(np.abs(pixels - FIGURE_BLUE) <= 12, axis=-1)))
    print(f"report-check: {page}: {dom.images} figures, {dom.tables} tables in the DOM; screenshot {shot}: {colours} colours,")
    print(f"  {blue} pixels of the figures' curves")
    failed = []
    if dom.images < 3 or dom.tables < 3:
        failed.append(f"the DOM holds {dom.images} figures and {dom.tables} tables (at least 3 of each expected)")
    if dom.outside:
        failed.append(f"the page refers outside itself: {dom.outside[:3]}")
    if colours < 2:
        failed.append("the screenshot is blank")
    if blue < 1000:
        failed.append(f"the screenshot shows {blue} pixels of the figures' curves: the figures were not drawn")
    return failed


if __name__ == "__main__":
    folder = Path(sys.argv[1] if len(sys.argv) > 1 else "results/report-check")
    folder.mkdir(parents=True, exist_ok=True)
    problems = check(folder)
    for problem in problems:
        print(f"report-check: {problem}", file=sys.stderr)
    sys.exit(1 if problems else 0)
