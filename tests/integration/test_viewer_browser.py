"""The viewer page in a real browser: headless Chromium (software WebGL) opens it from
``file://``, through the Chrome DevTools protocol (``websockets``, the ``dev`` extra).

Skips when no Chromium is installed (Debian: ``apt-get install -y chromium``).
"""

from __future__ import annotations

import base64
import contextlib
import io
import json
import shutil
import subprocess
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from grip_bench.data.grab_io import read_grab
from grip_bench.report.viewer import Track, write_viewer
from tests.eval_fixtures import grasp_dataset

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "chrome")
BACKGROUND = np.array([0xF4, 0xF4, 0xF4])
WIDTH, HEIGHT = 1200, 700


def _browser() -> str:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    pytest.skip("no Chromium found (Debian: apt-get install -y chromium)")


class Chrome:
    """A headless browser and one page, driven over the DevTools protocol."""

    def __init__(self, exe: str, profile: Path):
        ws = pytest.importorskip("websockets.sync.client")
        self.proc = subprocess.Popen(
            [exe, "--headless=new", "--no-sandbox", "--no-first-run", "--disable-extensions",
             "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist",
             "--remote-debugging-port=0", f"--user-data-dir={profile}",
             f"--window-size={WIDTH},{HEIGHT}", "about:blank"],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        port_file = profile / "DevToolsActivePort"
        deadline = time.monotonic() + 60
        while not port_file.is_file() or not port_file.read_text().strip():
            if time.monotonic() > deadline or self.proc.poll() is not None:
                self.close()
                pytest.skip("Chromium did not start a DevTools endpoint")
            time.sleep(0.1)
        port = int(port_file.read_text().split()[0])
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=10) as r:
            pages = [t for t in json.load(r) if t["type"] == "page"]
        self.stack = contextlib.ExitStack()
        self.ws = self.stack.enter_context(ws.connect(pages[0]["webSocketDebuggerUrl"],
                                                      max_size=None))
        self.next_id = 0
        self.events: list[dict] = []
        for method in ("Runtime.enable", "Log.enable", "Page.enable"):
            self.call(method)

    def call(self, method: str, **params) -> dict:
        self.next_id += 1
        self.ws.send(json.dumps({"id": self.next_id, "method": method, "params": params}))
        while True:
            msg = json.loads(self.ws.recv(timeout=120))
            if msg.get("id") == self.next_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            self.events.append(msg)

    def eval(self, expr: str):
        r = self.call("Runtime.evaluate", expression=expr, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise AssertionError(f"{expr}: {r['exceptionDetails']}")
        return r["result"].get("value")

    def screenshot(self) -> np.ndarray:
        from PIL import Image

        png = base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"])
        return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(int)

    def errors(self) -> list[str]:
        out = []
        for e in self.events:
            p = e.get("params", {})
            if e.get("method") == "Runtime.exceptionThrown":
                out.append(json.dumps(p["exceptionDetails"])[:500])
            elif e.get("method") == "Runtime.consoleAPICalled" and p.get("type") == "error":
                out.append(json.dumps(p["args"])[:500])
            elif e.get("method") == "Log.entryAdded" and p["entry"]["level"] == "error":
                out.append(p["entry"]["text"][:500])
        return out

    def close(self) -> None:
        if getattr(self, "stack", None) is not None:
            self.stack.close()
        self.proc.terminate()
        try:
            self.proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            self.proc.kill()


@pytest.fixture(scope="module")
def page(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("viewer_browser")
    (path,) = grasp_dataset(root / "data", specs=(("s1", "mug", "lift", False),), T=24)
    gt = read_grab(path)
    pred = read_grab(path)
    pred.rhand["transl"] = np.asarray(pred.rhand["transl"]) + np.array([0.0, 0.004, 0.0])
    return write_viewer(root / "page.html", [Track("ground truth", gt), Track("shifted", pred)])


@pytest.fixture(scope="module")
def chrome(tmp_path_factory):
    browser = Chrome(_browser(), tmp_path_factory.mktemp("chrome_profile"))
    yield browser
    browser.close()


def _wait_ready(chrome: Chrome) -> None:
    deadline = time.monotonic() + 90
    while time.monotonic() < deadline:
        state = chrome.eval("[document.body && document.body.dataset.ready, "
                            "document.getElementById('status') && "
                            "document.getElementById('status').textContent]")
        if state and state[0] == "1":
            return
        assert not (state and state[1]), f"viewer failed: {state[1]}"
        time.sleep(0.2)
    raise AssertionError(f"viewer never became ready; errors: {chrome.errors()}")


def _viewport(img: np.ndarray, rect: dict, i: int, n: int) -> np.ndarray:
    x0 = int(rect["x"] + i * rect["w"] / n)
    x1 = int(rect["x"] + (i + 1) * rect["w"] / n)
    return img[int(rect["y"]) + 30:int(rect["y"] + rect["h"]), x0:x1]  # below the label


def _content(region: np.ndarray) -> dict[str, int]:
    """Pixel counts: not background, coloured (hands), grey (the object's material)."""
    diff = np.abs(region - BACKGROUND).sum(-1) > 24
    spread = region.max(-1) - region.min(-1)
    return {"drawn": int(diff.sum()), "coloured": int((diff & (spread > 40)).sum()),
            "grey": int((diff & (spread < 12)).sum())}


def test_page_loads_draws_and_scrubs_from_file_url(page, chrome):
    chrome.call("Page.navigate", url=page.resolve().as_uri())
    _wait_ready(chrome)
    time.sleep(0.5)
    assert chrome.errors() == []
    rect = chrome.eval("(() => {const r = document.getElementById('canvas')"
                       ".getBoundingClientRect(); return {x: r.x, y: r.y, w: r.width, "
                       "h: r.height};})()")
    assert rect["w"] > 300 and rect["h"] > 300
    first = chrome.screenshot()
    for i in range(2):  # side by side: ground truth left, the method right
        c = _content(_viewport(first, rect, i, 2))
        assert c["coloured"] > 500, (i, c)  # the hands (track colour / contact colours)
        assert c["grey"] > 200, (i, c)  # the object
    n = chrome.eval("window.gripViewer.frames")
    assert n == 24
    chrome.eval("(() => {const r = document.getElementById('frame'); r.value = '"
                + str(n - 1) + "'; r.dispatchEvent(new Event('input'));})()")
    time.sleep(0.3)
    assert chrome.eval("window.gripViewer.state.frame") == n - 1
    last = chrome.screenshot()
    canvas = _viewport(last, rect, 0, 1)
    changed = (np.abs(canvas - _viewport(first, rect, 0, 1)).sum(-1) > 24).sum()
    assert changed > 1000  # the hand closed on the object and lifted it
    assert "frame 23" in chrome.eval("document.getElementById('frameLabel').textContent")
    chrome.eval("(() => {const o = document.getElementById('overlay'); o.checked = true; "
                "o.dispatchEvent(new Event('change'));})()")
    time.sleep(0.3)
    overlay = chrome.screenshot()
    c = _content(_viewport(overlay, rect, 0, 1))
    assert c["coloured"] > 500 and c["grey"] > 200, c
    assert chrome.errors() == []


def test_no_network_requests(page, chrome):
    """Everything is inline: loading the page requests nothing but the file itself."""
    chrome.call("Network.enable")
    chrome.events.clear()
    chrome.call("Page.navigate", url=page.resolve().as_uri())
    _wait_ready(chrome)
    urls = [e["params"]["request"]["url"] for e in chrome.events
            if e.get("method") == "Network.requestWillBeSent"]
    assert all(u.startswith(("file:", "data:", "blob:")) for u in urls), urls
    assert sum(u.startswith("file:") for u in urls) == 1, urls
