"""Headless Chromium driven through the Chrome DevTools Protocol over a pipe
(``--remote-debugging-pipe``: JSON messages ending in NUL on the browser's fds 3 and 4), so
the tests need neither selenium, playwright, chromedriver nor a websocket client: only
Debian's ``chromium`` and the standard library.

Every console error, uncaught exception and error log entry of the page is collected in
:attr:`Browser.errors`.
"""

from __future__ import annotations

import base64
import contextlib
import fcntl
import json
import os
import select
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

__all__ = ["CHROMIUM", "Browser", "BrowserError"]

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


class BrowserError(RuntimeError):
    """The browser answered a command with an error, or did not answer in time."""


def _high(fd: int) -> int:
    """``fd`` moved to a number of 10 or more (the original closed)."""
    new = fcntl.fcntl(fd, fcntl.F_DUPFD, 10)
    os.close(fd)
    return new


class Browser:
    """One headless Chromium with one page.

    Parameters
    ----------
    profile
        An empty folder for the browser's profile.
    size
        The window's width and height, px.
    """

    def __init__(self, profile: Path, *, size: tuple[int, int] = (1280, 1400)) -> None:
        if CHROMIUM is None:
            raise BrowserError("chromium is not installed")
        # the browser reads commands on its fd 3 and writes answers on its fd 4
        cmd_r, self._cmd_w = os.pipe()
        self._ans_r, ans_w = os.pipe()
        # pass_fds keeps the numbers of the fds it passes: a small Python moves them to 3
        # and 4 (from numbers above 9, so that neither move overwrites the other) and
        # becomes the browser
        cmd_r, ans_w = (_high(fd) for fd in (cmd_r, ans_w))
        trampoline = ("import os, sys; os.dup2(int(sys.argv[1]), 3); "
                      "os.dup2(int(sys.argv[2]), 4); os.close(int(sys.argv[1])); "
                      "os.close(int(sys.argv[2])); os.execv(sys.argv[3], sys.argv[3:])")
        self.proc = subprocess.Popen(
            [sys.executable, "-S", "-c", trampoline, str(cmd_r), str(ans_w),
             CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             "--disable-extensions", "--remote-debugging-pipe",
             f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
             "about:blank"],
            pass_fds=(cmd_r, ans_w), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True)
        os.close(cmd_r)
        os.close(ans_w)
        self._buf = b""
        self._id = 0
        self._events: list[dict[str, Any]] = []
        self.errors: list[str] = []
        self.console: list[str] = []
        target = self.send("Target.createTarget", {"url": "about:blank"})["targetId"]
        self.session = self.send("Target.attachToTarget",
                                 {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.send(f"{domain}.enable", session=True)

    # -------------------------------------------------------------- protocol
    def _read(self, timeout: float) -> dict[str, Any] | None:
        end = time.monotonic() + timeout
        while b"\0" not in self._buf:
            left = end - time.monotonic()
            if left <= 0:
                return None
            ready, _, _ = select.select([self._ans_r], [], [], left)
            if not ready:
                return None
            chunk = os.read(self._ans_r, 1 << 20)
            if not chunk:
                raise BrowserError("chromium closed its DevTools pipe (it exited)")
            self._buf += chunk
        msg, self._buf = self._buf.split(b"\0", 1)
        data = json.loads(msg)
        if "method" in data:
            self._on_event(data)
        return data

    def _on_event(self, ev: dict[str, Any]) -> None:
        self._events.append(ev)
        method, p = ev["method"], ev.get("params", {})
        if method == "Runtime.consoleAPICalled":
            text = " ".join(str(a.get("value", a.get("description", ""))) for a in p["args"])
            self.console.append(f"{p['type']}: {text}")
            if p["type"] in ("error", "assert"):
                self.errors.append(f"console.{p['type']}: {text}")
        elif method == "Runtime.exceptionThrown":
            d = p["exceptionDetails"]
            desc = (d.get("exception") or {}).get("description") or d.get("text")
            self.errors.append(f"uncaught exception at {d.get('url', '?')}:"
                               f"{d.get('lineNumber', '?')}: {desc}")
        elif method == "Log.entryAdded" and p["entry"]["level"] == "error":
            e = p["entry"]
            self.errors.append(f"{e['source']} error: {e['text']} ({e.get('url', '')})")

    def send(self, method: str, params: dict[str, Any] | None = None, *,
             session: bool = False, timeout: float = 30.0) -> dict[str, Any]:
        """One command; its result (raises :class:`BrowserError` on an error answer)."""
        self._id += 1
        msg: dict[str, Any] = {"id": self._id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = self.session
        os.write(self._cmd_w, json.dumps(msg).encode() + b"\0")
        end = time.monotonic() + timeout
        while True:
            data = self._read(max(0.0, end - time.monotonic()))
            if data is None:
                raise BrowserError(f"no answer to {method} within {timeout:.0f} s")
            if data.get("id") == self._id:
                if "error" in data:
                    raise BrowserError(f"{method}: {data['error']}")
                return data.get("result", {})

    def pump(self, seconds: float) -> None:
        """Read the page's events for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self._read(max(0.0, end - time.monotonic()))

    # -------------------------------------------------------------- page
    def navigate(self, url: str) -> None:
        self.send("Page.navigate", {"url": url}, session=True)

    def evaluate(self, expression: str, *, timeout: float = 30.0) -> Any:
        """The value of a JavaScript expression in the page (promises awaited)."""
        r = self.send("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                           "awaitPromise": True}, session=True,
                      timeout=timeout)
        if "exceptionDetails" in r:
            d = r["exceptionDetails"]
            raise BrowserError(f"{expression[:80]}: "
                               f"{(d.get('exception') or {}).get('description') or d['text']}")
        return r["result"].get("value")

    def wait_for(self, expression: str, *, timeout: float = 60.0, what: str = "") -> Any:
        """Poll until the expression's value is truthy; returns it."""
        end = time.monotonic() + timeout
        last: Any = None
        while time.monotonic() < end:
            with contextlib.suppress(BrowserError):
                last = self.evaluate(expression)
                if last:
                    return last
            self.pump(0.2)
        raise BrowserError(f"waited {timeout:.0f} s for {what or expression} (last: {last!r})")

    def screenshot(self, png: Path) -> Path:
        data = self.send("Page.captureScreenshot", {"format": "png"}, session=True)["data"]
        png.write_bytes(base64.b64decode(data))
        return png

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.send("Browser.close", timeout=5)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, 9)
            self.proc.wait(10)
        for fd in (self._cmd_w, self._ans_r):
            with contextlib.suppress(OSError):
                os.close(fd)
