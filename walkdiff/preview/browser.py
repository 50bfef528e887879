"""Headless Chromium driven over its DevTools protocol: open a page, wait for what it renders, read its
address and text, take screenshots.

Debian's `chromium` package is the browser (browser downloads, such as Playwright's, fail on closed
networks). The protocol is JSON over one websocket; `websockets` (already installed with viser) speaks it,
so no browser-automation package is needed. The `--dump-dom`/`--screenshot` command-line modes cannot
wait for a condition or say where a single-page app's router ended up; this can.
"""

from __future__ import annotations

import base64
import json
import queue
import re
import shutil
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from walkdiff.common.errors import WalkdiffError

# Without these, Chromium on a machine with no network waits on connections it will never make.
QUIET_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)


def find_chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


def chromium_version() -> str | None:
    chromium = find_chromium()
    if chromium is None:
        return None
    said = subprocess.run([chromium, "--version"], capture_output=True, text=True, timeout=60).stdout
    return said.strip() or None


class Browser:
    """One headless Chromium with one page: `with Browser(url) as page: page.wait_for("...")`.

    `launched` is the monotonic time the browser process was started (for load-time measurements).
    """

    def __init__(self, url: str = "about:blank", width: int = 1280, height: int = 800, timeout: float = 60):
        from websockets.sync.client import connect

        chromium = find_chromium()
        if chromium is None:
            raise WalkdiffError("no chromium found on PATH (Debian: `apt-get install chromium`)")
        self._profile = tempfile.TemporaryDirectory(prefix="walkdiff-chromium-")
        self.launched = time.monotonic()
        self._process = subprocess.Popen(
            [
                chromium, *QUIET_FLAGS, f"--user-data-dir={self._profile.name}", "--remote-debugging-port=0",
                f"--window-size={width},{height}", url,
            ],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            endpoint = self._devtools_endpoint(timeout)
            self._socket = connect(self._page_socket(endpoint, timeout), max_size=None, open_timeout=timeout)
        except BaseException:
            self.close()
            raise
        self._next_id = 0
        self.timeout = timeout

    def _devtools_endpoint(self, timeout: float) -> str:
        """The `http://127.0.0.1:PORT` Chromium prints once it listens (stderr: `DevTools listening on`).
        A thread keeps reading stderr, so the browser never blocks on a full pipe."""
        lines: queue.Queue[str | None] = queue.Queue()

        def read() -> None:
            for line in self._process.stderr:
                lines.put(line)
            lines.put(None)

        self._reader = threading.Thread(target=read, daemon=True)
        self._reader.start()
        seen = []
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = lines.get(timeout=left)
            except queue.Empty:
                break
            if line is None:
                break
            seen.append(line)
            found = re.search(r"DevTools listening on ws://([\d.:]+)/", line)
            if found:
                return f"http://{found[1]}"
        raise WalkdiffError(f"chromium did not start its DevTools endpoint: {''.join(seen)[-1000:]!r}")

    @staticmethod
    def _page_socket(endpoint: str, timeout: float) -> str:
        from urllib.request import urlopen

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            with urlopen(f"{endpoint}/json/list", timeout=timeout) as answer:
                pages = [t for t in json.load(answer) if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
            time.sleep(0.05)
        raise WalkdiffError(f"chromium at {endpoint} opened no page")

    def send(self, method: str, **params) -> dict:
        """Call one protocol method and return its result (events arriving meanwhile are dropped)."""
        self._next_id += 1
        self._socket.send(json.dumps({"id": self._next_id, "method": method, "params": params}))
        while True:
            message = json.loads(self._socket.recv(timeout=self.timeout))
            if message.get("id") == self._next_id:
                if "error" in message:
                    raise WalkdiffError(f"chromium: {method} failed: {message['error'].get('message')}")
                return message.get("result", {})

    def goto(self, url: str) -> None:
        self.send("Page.navigate", url=url)

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (JSON-like values only)."""
        result = self.send("Runtime.evaluate", expression=expression, returnByValue=True)
        if "exceptionDetails" in result:
            raise WalkdiffError(f"chromium: {expression!r} raised {result['exceptionDetails'].get('text')}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float | None = None, every: float = 0.1):
        """Poll a JavaScript expression until it is truthy; return its value, or fail naming it."""
        return self.wait_until(lambda: self.evaluate(expression), expression, timeout, every)

    def wait_until(self, check: Callable, what: str, timeout: float | None = None, every: float = 0.1):
        deadline = time.monotonic() + (self.timeout if timeout is None else timeout)
        while True:
            value = check()
            if value:
                return value
            if time.monotonic() > deadline:
                raise WalkdiffError(f"chromium: gave up waiting for {what} after {timeout or self.timeout} s")
            time.sleep(every)

    @property
    def url(self) -> str:
        return self.evaluate("location.href")

    def text(self) -> str:
        return self.evaluate("document.body ? document.body.innerText : ''")

    def screenshot(self, path: str | Path | None = None) -> bytes:
        """The page as PNG bytes (also written to `path` when given)."""
        png = base64.b64decode(self.send("Page.captureScreenshot", format="png")["data"])
        if path is not None:
            Path(path).write_bytes(png)
        return png

    def close(self) -> None:
        socket = getattr(self, "_socket", None)
        if socket is not None:
            socket.close()
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        reader = getattr(self, "_reader", None)
        if reader is not None:
            reader.join(timeout=10)
        self._process.stderr.close()
        self._profile.cleanup()

    def __enter__(self) -> Browser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
