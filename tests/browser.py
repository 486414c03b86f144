"""Open a report in Debian's headless Chromium (chromedriver at /usr/bin/chromedriver, installed
by `make setup`) and return what a reader would see. Not a test module: imported by tests.

The check fails, rather than skips, when Chromium or its driver is missing, unless
SGDR_SKIP_BROWSER=1 is set (then the calling test skips).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from pathlib import Path

import pytest

CHROMEDRIVER = "/usr/bin/chromedriver"
CHROMIUM = "/usr/bin/chromium"
ARGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-dev-shm-usage",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
)

# what the page shows once loaded: every image decoded, every video's metadata read (or failed)
_STATE = """
const imgs = Array.from(document.images);
const vids = Array.from(document.querySelectorAll('video'));
const v = document.getElementById('verdict');
return {
  ready: document.readyState,
  images: imgs.map(i => ({complete: i.complete, width: i.naturalWidth, alt: i.alt})),
  videos: vids.map(x => ({ready: x.readyState, error: x.error ? x.error.code : null, duration: x.duration,
                          width: x.videoWidth})),
  verdict_visible: !!v && v.offsetWidth > 0 && v.offsetHeight > 0 && getComputedStyle(v).visibility !== 'hidden',
  verdict_text: v ? v.innerText : '',
  first_section: document.querySelector('section') ? document.querySelector('section').id : null,
};
"""


def open_report(path: Path, timeout: float = 60.0) -> dict:
    """Load `path` in headless Chromium; wait until every image and video has loaded or failed.

    Returns the page state (`_STATE`) plus "log": the browser console entries.
    """
    if os.environ.get("SGDR_SKIP_BROWSER") == "1":
        pytest.skip("SGDR_SKIP_BROWSER=1")
    missing = [p for p in (CHROMIUM, CHROMEDRIVER) if not Path(p).exists()]
    if missing:
        pytest.fail(f"{missing} not found: run `make setup` (installs Debian's chromium, chromium-driver)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="sgdr-chromium-")
    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for arg in ARGS:
        opts.add_argument(arg)
    opts.add_argument(f"--user-data-dir={profile}")
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    try:
        driver.get(Path(path).resolve().as_uri())
        end = time.monotonic() + timeout
        while True:
            state = driver.execute_script(_STATE)
            settled = state["ready"] == "complete" and all(i["complete"] for i in state["images"])
            settled &= all(v["ready"] >= 1 or v["error"] is not None for v in state["videos"])
            if settled or time.monotonic() > end:
                break
            time.sleep(0.2)
        state["log"] = driver.get_log("browser")
        return state
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def assert_report_reads_well(path: Path) -> dict:
    """The report loads without console errors, opens with a visible verdict that names the
    fit quality, and every image and video decodes. Returns the page state."""
    state = open_report(path)
    severe = [e for e in state["log"] if e.get("level") == "SEVERE"]
    assert not severe, severe
    assert state["first_section"] == "verdict"
    assert state["verdict_visible"]
    text = state["verdict_text"]
    assert any(f"Fit {q}" in text for q in ("good", "fair", "poor", "unknown")), text
    assert state["images"] and all(i["width"] > 0 for i in state["images"]), state["images"]
    for v in state["videos"]:
        assert v["error"] is None and v["ready"] >= 1 and v["width"] > 0 and v["duration"] > 0, v
    return state
