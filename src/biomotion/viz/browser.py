"""Headless Chromium driven over the Chrome DevTools Protocol, to check and screenshot the HTML viewer.

Chromium is started with ``--remote-debugging-pipe``: it reads protocol commands from file descriptor 3 and writes
replies and events to descriptor 4, each message one JSON object ending in a NUL byte (Chrome DevTools Protocol,
chromedevtools.github.io/devtools-protocol; the transport Puppeteer and Playwright use). No network port is opened
and no package beyond the standard library is needed. Software WebGL (SwiftShader) draws the 3D view, which needs
``--enable-unsafe-swiftshader`` since Chromium 1xx refuses the silent fallback otherwise; the pages are local files.
"""

from __future__ import annotations

import base64
import fcntl
import json
import os
import select
import shutil
import subprocess
import tempfile
import time
from pathlib import Path
from typing import Any

CHROMIUM_CANDIDATES = ("/usr/bin/chromium", "chromium", "chromium-browser", "google-chrome")

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--use-angle=swiftshader",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-extensions",
    "--disable-default-apps",
    "--mute-audio",
    "--hide-scrollbars",
)


def find_chromium() -> str | None:
    """Path of a Chromium executable (``$BIOMOTION_CHROMIUM`` first), or None."""
    for candidate in (os.environ.get("BIOMOTION_CHROMIUM"),) + CHROMIUM_CANDIDATES:
        if candidate and (found := shutil.which(candidate)):
            return found
    return None


def _pipe_to_fds_3_and_4(read_end: int, write_end: int) -> None:
    """In the child, before exec: put the pipe ends on descriptors 3 and 4 (moved above 4 first, so neither
    overwrites the other); the originals are close-on-exec."""
    read_end, write_end = (
        fcntl.fcntl(read_end, fcntl.F_DUPFD_CLOEXEC, 5),
        fcntl.fcntl(write_end, fcntl.F_DUPFD_CLOEXEC, 5),
    )
    os.dup2(read_end, 3)
    os.dup2(write_end, 4)


class BrowserError(RuntimeError):
    """Chromium could not be started, or a protocol command failed or timed out."""


class Page:
    """One headless Chromium with one page: navigate, evaluate JavaScript, screenshot, and the page's errors.

    ``errors`` collects console errors, uncaught exceptions and failed loads; ``requests`` every URL the page
    asked for. Use as a context manager so the browser and its profile directory are removed.
    """

    def __init__(
        self, width: int = 1200, height: int = 800, chromium: str | None = None, timeout: float = 60.0
    ) -> None:
        executable = chromium or find_chromium()
        if executable is None:
            raise BrowserError("no Chromium executable found (install Debian's `chromium`)")
        self.timeout = timeout
        self.errors: list[str] = []
        self.requests: list[str] = []
        self._profile = tempfile.mkdtemp(prefix="biomotion-chromium-")
        to_browser_read, self._to_browser = os.pipe()
        self._from_browser, from_browser_write = os.pipe()
        self._process = subprocess.Popen(
            [
                executable,
                *FLAGS,
                f"--user-data-dir={self._profile}",
                f"--window-size={width},{height}",
                "--remote-debugging-pipe",
                "about:blank",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            close_fds=False,
            preexec_fn=lambda: _pipe_to_fds_3_and_4(to_browser_read, from_browser_write),
        )
        os.close(to_browser_read)
        os.close(from_browser_write)
        self._buffer = b""
        self._next_id = 0
        self._events: list[dict] = []
        try:
            target = self._command("Target.createTarget", {"url": "about:blank"})["targetId"]
            self._session = self._command("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
            for domain in ("Page", "Runtime", "Log", "Network"):
                self.send(f"{domain}.enable")
            self.send(
                "Emulation.setDeviceMetricsOverride",
                {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
            )
        except BaseException:
            self.close()
            raise

    def __enter__(self) -> Page:
        return self

    def __exit__(self, *_: Any) -> None:
        self.close()

    def close(self) -> None:
        """Stop Chromium and remove its profile."""
        if self._process.poll() is None:
            self._process.terminate()
            try:
                self._process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait()
        for fd in (self._to_browser, self._from_browser):
            try:
                os.close(fd)
            except OSError:
                pass
        shutil.rmtree(self._profile, ignore_errors=True)

    # ---- protocol ----------------------------------------------------------------------------------------------
    def send(self, method: str, params: dict | None = None) -> dict:
        """Run a command in the page's session and return its result."""
        return self._command(method, params, session=self._session)

    def _command(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session:
            message["sessionId"] = session
        os.write(self._to_browser, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            reply = self._receive(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error'].get('message')}")
                return reply.get("result", {})
            self._record(reply)

    def _receive(self, deadline: float) -> dict:
        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError(f"no reply from Chromium within {self.timeout:.0f} s")
            ready, _, _ = select.select([self._from_browser], [], [], left)
            if ready:
                chunk = os.read(self._from_browser, 1 << 20)
                if not chunk:
                    raise BrowserError("Chromium closed the protocol pipe (it crashed or could not start)")
                self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def _record(self, event: dict) -> None:
        method, params = event.get("method"), event.get("params", {})
        if method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "assert"):
            self.errors.append(
                "console: " + " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
            )
        elif method == "Runtime.exceptionThrown":
            details = params.get("exceptionDetails", {})
            self.errors.append("exception: " + details.get("exception", {}).get("description", details.get("text", "")))
        elif method == "Log.entryAdded" and params.get("entry", {}).get("level") == "error":
            self.errors.append("log: " + params["entry"].get("text", ""))
        elif method == "Network.requestWillBeSent":
            self.requests.append(params.get("request", {}).get("url", ""))
        elif method == "Network.loadingFailed" and not params.get("canceled"):
            self.errors.append("load failed: " + params.get("errorText", ""))
        self._events.append(event)

    # ---- page --------------------------------------------------------------------------------------------------
    def open(self, path: str | Path) -> float:
        """Load a local file and wait for its load event; returns the seconds it took."""
        start = time.monotonic()
        self._events.clear()
        self.send("Page.navigate", {"url": Path(path).resolve().as_uri()})
        deadline = start + self.timeout
        while not any(e.get("method") == "Page.loadEventFired" for e in self._events):
            self._record(self._receive(deadline))
        return time.monotonic() - start

    def evaluate(self, expression: str) -> Any:
        """Value of a JavaScript expression (promises are awaited); a thrown error raises `BrowserError`."""
        result = self.send("Runtime.evaluate", {"expression": expression, "awaitPromise": True, "returnByValue": True})
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise BrowserError(
                f"{expression[:60]}: {details.get('exception', {}).get('description', details.get('text'))}"
            )
        return result.get("result", {}).get("value")

    def screenshot(self) -> bytes:
        """PNG of the viewport."""
        return base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])
