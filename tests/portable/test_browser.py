"""The JavaScript port in headless Chromium: the conformance vectors, and a page that
generates a 5-s walk with no mogo process running, only a static file server this test starts
(onnxruntime-web fetches its .wasm and the graphs, which Chromium refuses from file://)."""
import functools
import http.server
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import mogo

WEB = Path(mogo.__file__).parent / "web"
CHROMIUM, DRIVER = "/usr/bin/chromium", shutil.which("chromedriver") or "/usr/bin/chromedriver"
pytestmark = pytest.mark.skipif(
    not (os.path.exists(CHROMIUM) and os.path.exists(DRIVER)),
    reason="needs Chromium (apt-get update && apt-get install -y chromium chromium-driver)")
webdriver = pytest.importorskip("selenium.webdriver")
SCREENSHOT = os.environ.get("MOGO_WEB_SCREENSHOT")  # where to keep the picture, if anywhere


@pytest.fixture(scope="module")
def site(portable_bundle, tmp_path_factory):
    """http://127.0.0.1:PORT/web/ (the package's web folder) and /bundle/ (the portable
    bundle), served by a thread of this process: files only, nothing of mogo runs there."""
    root = tmp_path_factory.mktemp("site")
    (root / "web").symlink_to(WEB)
    (root / "bundle").symlink_to(portable_bundle)
    handler = functools.partial(_QuietFiles, directory=str(root))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_address[1]}"
    server.shutdown()
    server.server_close()


class _QuietFiles(http.server.SimpleHTTPRequestHandler):
    extensions_map = {**http.server.SimpleHTTPRequestHandler.extensions_map,
                      ".mjs": "text/javascript", ".wasm": "application/wasm"}

    def log_message(self, *args):
        pass


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update",
                 "--disable-sync", "--window-size=960,720",
                 f"--user-data-dir={tempfile.mkdtemp(dir=tmp_path_factory.mktemp('chromium'))}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(options=options,
                              service=webdriver.ChromeService(executable_path=DRIVER))
    driver.set_page_load_timeout(60)
    yield driver
    driver.quit()


def _wait_for(browser, name: str, seconds: float = 300):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        error = browser.execute_script("return window.mogoError || null")
        assert error is None, error
        value = browser.execute_script(f"return window.{name} || null")
        if value is not None:
            return value
        time.sleep(0.5)
    raise AssertionError(f"no window.{name} within {seconds} s")


def test_the_port_passes_the_conformance_vectors_in_chromium(site, browser):
    browser.get(f"{site}/web/index.html?bundle=../bundle/&check=1")
    report = _wait_for(browser, "mogoConformance")
    assert report["problems"] == []
    assert all(case["agreed"] == case["steps"] for case in report["cases"]), report["cases"]


def test_a_page_generates_a_5s_walk_that_matches_our_runtime(site, browser, portable_generator):
    browser.get(f"{site}/web/index.html?bundle=../bundle/&prompt=a%20person%20walks%20forward"
                "&seconds=5&seed=0")
    result = _wait_for(browser, "mogoResult")
    ours = portable_generator.generate("a person walks forward", seconds=5, seed=0,
                                       plant_feet=False)
    page = np.array(result["joints"]).reshape(result["frames"], -1, 3)
    assert page.shape == ours.joints.shape == (100, 22, 3)
    embedding = portable_generator.embed(["a person walks forward"])[0]
    assert np.abs(np.array(result["embedding"]) - embedding).max() < 1e-3
    assert np.abs(page - ours.joints).max() < 1e-3  # the tolerance of the conformance vectors
    time.sleep(1.5)  # a few frames of the clip drawn
    if SCREENSHOT:
        Path(SCREENSHOT).write_bytes(browser.get_screenshot_as_png())
    print(f"browser: {result['frames']} frames in {result['totalSeconds']:.2f} s, "
          f"{result['framesPerSecond']:.1f} frames/s; bundle loaded in "
          f"{result['loadSeconds']:.2f} s")
