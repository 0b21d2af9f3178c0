"""The viewer page in a real browser: headless Chromium loads it from a running server, starts
two characters, and frames arrive and are drawn on the canvas, a third with the low-latency
box ticked starts too, with no error in the browser's console (a missing /favicon.ico was
one). Skipped without Chromium."""

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

CHROMIUM, DRIVER = "/usr/bin/chromium", shutil.which("chromedriver") or "/usr/bin/chromedriver"
pytestmark = pytest.mark.skipif(
    not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)),
    reason="needs /usr/bin/chromium and chromedriver: apt-get install chromium chromium-driver",
)
webdriver = pytest.importorskip("selenium.webdriver")
SCREENSHOT = os.environ.get("MOGO_VIEWER_SCREENSHOT")  # where to keep the picture, if anywhere


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_the_viewer_streams_and_draws_characters(tmp_path):
    port = free_port()
    server = subprocess.Popen(
        [sys.executable, "-m", "mogo", "serve", "--port", str(port), "--threads", "1"],
        stderr=subprocess.PIPE,
        text=True,
    )
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--window-size=1100,640",
        f"--user-data-dir={tempfile.mkdtemp(dir=tmp_path)}",
    ):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})  # the console, read below
    browser = None
    try:
        assert "mogo serve:" in server.stderr.readline()  # listening
        browser = webdriver.Chrome(
            options=options, service=webdriver.ChromeService(executable_path=DRIVER)
        )
        browser.set_page_load_timeout(30)
        browser.get(f"http://127.0.0.1:{port}/?n=2&prompt=a%20person%20walks%20forward")
        stats = {}
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            stats = browser.execute_script("return window.mogoStats")
            if stats["frames"] >= 60 and stats["drawn"] >= 40:
                break
            time.sleep(0.2)
        assert stats["frames"] >= 60 and stats["drawn"] >= 40 and not stats["errors"], stats
        browser.find_element("css selector", "#cast input").clear()
        browser.find_element("css selector", "#cast input").send_keys("a person jumps\n")
        time.sleep(2)
        lit = browser.execute_script(
            "const c = document.getElementById('stage'), d = c.getContext('2d')"
            ".getImageData(0, 0, c.width, c.height).data; let n = 0;"
            "for (let i = 0; i < d.length; i += 4) if (d[i] > 200 && d[i + 1] > 120) n++;"
            "return n"
        )
        assert lit > 500  # the characters' orange strokes, not only the dark floor
        browser.find_element("css selector", "#low").click()  # a third, low-latency character
        browser.find_element("css selector", "#add").click()
        before = browser.execute_script("return window.mogoStats")["frames"]
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            stats = browser.execute_script("return window.mogoStats")
            if stats["lowLatency"] == 1 and stats["frames"] >= before + 60:
                break
            time.sleep(0.2)
        assert stats["lowLatency"] == 1 and not stats["errors"], stats  # started: accepted
        console = [
            entry["message"] for entry in browser.get_log("browser") if entry["level"] == "SEVERE"
        ]
        assert not console, console  # e.g. "favicon.ico - Failed to load resource: ... 404"
        if SCREENSHOT:
            Path(SCREENSHOT).write_bytes(browser.get_screenshot_as_png())
    finally:
        if browser is not None:
            browser.quit()
        server.terminate()
        server.wait(timeout=30)
