"""The demo's HTML report in a real headless browser: write it, screenshot it, time both.

Usage::

    PYTHONPATH=. python bench/report_shot.py [--out DIR] [--browser /usr/bin/chromium]

Records the demo session (``capture.run --demo``) into ``DIR/demo_session`` unless it is there,
writes ``DIR/report.html`` (``capture.report --html``) and opens it in headless Chromium
(Debian: ``apt-get install chromium``), which saves ``DIR/report.png`` (1280 px wide). Prints
the report's size, its number of inline images, the time to write it against the time to
print the table alone (the peer, same run), and where the screenshot is: look at it.
"""

from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import time
from pathlib import Path

from capture.pipeline.html_report import write_html
from capture.results import format_flight_table, session_results
from capture.run import main as run_main


def demo_session(out: Path) -> Path:
    """``out/demo_session``, recorded by ``capture.run --demo`` unless it is there (``out`` is created)."""
    out.mkdir(parents=True, exist_ok=True)
    session = out / "demo_session"
    if not (session / "zarr.json").exists():
        run_main(["--demo", "--out", str(session), "--viewer", "none", "--quiet"])
    return session


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="report_shot", help="working directory")
    ap.add_argument("--browser", default=shutil.which("chromium") or shutil.which("chromium-browser"),
                    help="headless browser (Chromium)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    session = demo_session(out)
    t0 = time.perf_counter()
    print(format_flight_table(session_results(session)[0]))
    t_table = time.perf_counter() - t0
    t0 = time.perf_counter()
    page = write_html(session, out / "report.html")
    t_html = time.perf_counter() - t0
    doc = page.read_text()
    n_img = len(re.findall(r"src='data:image/png;base64,", doc))
    print(f"report {page}: {len(doc) / 1024:.0f} KiB, {n_img} inline images, written in {t_html:.2f} s "
          f"({t_html / max(t_table, 1e-9):.0f}x the {t_table:.2f} s of the table alone)")
    if not args.browser:
        print("no Chromium found (apt-get install chromium): no screenshot")
        return 1
    shot = out / "report.png"
    t0 = time.perf_counter()
    subprocess.run([args.browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    "--window-size=1280,2000", f"--screenshot={shot.resolve()}", page.resolve().as_uri()],
                   check=True, capture_output=True, timeout=120)
    print(f"screenshot {shot} ({shot.stat().st_size / 1024:.0f} KiB) in {time.perf_counter() - t0:.1f} s: look at it")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
