"""Headless Chromium driven over the Chrome DevTools Protocol (CDP), for the web page tests.

Debian's ``chromium`` is installed when missing (``apt-get``, as root); tests skip with the
reason only when that is impossible. Chromium starts with the flags this environment needs
(no sandbox as root, no background networking: the network is closed) and a fresh profile.
"""

from __future__ import annotations

import base64
import contextlib
import itertools
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time

import pytest

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-extensions", "--disable-dev-shm-usage", "--window-size=1400,1000"]


def chromium_path() -> str:
    """Path of a Chromium binary, installing Debian's package if needed (or pytest.skip)."""
    for name in ("chromium", "chromium-browser", "google-chrome"):
        p = shutil.which(name)
        if p:
            return p
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        pytest.skip("chromium is not installed and cannot be installed here (needs root and apt-get)")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "chromium"]):
        r = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=900, stdin=subprocess.DEVNULL)
        if r.returncode != 0:
            pytest.skip(f"installing chromium failed ({' '.join(cmd)}): {r.stderr.strip()[-300:]}")
    p = shutil.which("chromium")
    if not p:
        pytest.skip("apt-get installed chromium but no chromium binary is on PATH")
    return p


def _group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


class Browser:
    """One headless Chromium with one page, driven through CDP over a websocket."""

    def __init__(self):
        from websockets.sync.client import connect

        binary = chromium_path()  # may skip the test: before anything is opened
        self.profile = tempfile.mkdtemp(prefix="illum-chromium-")
        self.log = open(os.path.join(self.profile, "chromium.log"), "wb")
        try:
            self.proc = subprocess.Popen([binary, *FLAGS, f"--user-data-dir={self.profile}",
                                          "--remote-debugging-address=127.0.0.1", "--remote-debugging-port=0",
                                          "about:blank"], stdout=self.log, stderr=subprocess.STDOUT,
                                         stdin=subprocess.DEVNULL, start_new_session=True)
        except BaseException:
            self.log.close()
            shutil.rmtree(self.profile, ignore_errors=True)
            raise
        # /usr/bin/chromium is a wrapper script that forks the browser: its own process group
        # lets close() end the browser and all its helpers, and only those.
        self._stack = contextlib.ExitStack()
        self._ids = itertools.count(1)
        self.events: list[dict] = []
        try:
            port = self._devtools_port()
            # entered as a context manager (websockets >= 17 deprecates bare connections)
            self.ws = self._stack.enter_context(connect(self._page_ws(port), max_size=64 * 1024 * 1024,
                                                        open_timeout=20))
            self.call("Page.enable")
            self.call("Runtime.enable")
            self.call("Log.enable")
        except BaseException:
            self.close()
            raise

    def _devtools_port(self) -> int:
        path = os.path.join(self.profile, "DevToolsActivePort")
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"chromium exited with {self.proc.returncode}")
            try:
                with open(path) as fh:
                    first = fh.readline().strip()
                if first:
                    return int(first)
            except FileNotFoundError:
                pass
            time.sleep(0.05)
        raise RuntimeError("chromium did not open its DevTools port")

    def _page_ws(self, port: int) -> str:
        import httpx

        deadline = time.monotonic() + 20
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=5) as c:
            while time.monotonic() < deadline:
                pages = [t for t in c.get("/json/list").json() if t.get("type") == "page"]
                if pages:
                    return pages[0]["webSocketDebuggerUrl"]
                time.sleep(0.05)
        raise RuntimeError("chromium has no page target")

    # ------------------------------------------------------------------ protocol
    def call(self, method: str, timeout: float = 30.0, **params) -> dict:
        msg_id = next(self._ids)
        self.ws.send(json.dumps({"id": msg_id, "method": method, "params": params}))
        deadline = time.monotonic() + timeout
        while True:
            raw = self.ws.recv(timeout=max(0.01, deadline - time.monotonic()))
            msg = json.loads(raw)
            if msg.get("id") == msg_id:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error']}")
                return msg.get("result", {})
            if "method" in msg:
                self.events.append(msg)

    def eval(self, expression: str):
        """Evaluate JS in the page (promises awaited) and return its JSON value."""
        r = self.call("Runtime.evaluate", expression=expression, returnByValue=True, awaitPromise=True)
        if "exceptionDetails" in r:
            raise RuntimeError(f"JS error: {r['exceptionDetails']}")
        return r["result"].get("value")

    def goto(self, url: str) -> None:
        self.call("Page.navigate", url=url)
        self.wait("document.readyState === 'complete'", what="the page to load")

    def wait(self, expression: str, timeout: float = 30.0, what: str = ""):
        deadline = time.monotonic() + timeout
        while True:
            value = self.eval(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                pytest.fail(f"timed out after {timeout} s waiting for {what or expression}")
            time.sleep(0.1)

    def screenshot(self, path: str) -> None:
        data = self.call("Page.captureScreenshot", format="png")["data"]
        with open(path, "wb") as fh:
            fh.write(base64.b64decode(data))

    def js_errors(self) -> list:
        """Uncaught exceptions, and errors the browser logged (CSP violations, failed loads)."""
        self.eval("true")  # drain events that arrived since the last call
        return [e for e in self.events if e.get("method") == "Runtime.exceptionThrown"
                or (e.get("method") == "Log.entryAdded" and e["params"]["entry"].get("level") == "error")]

    def close(self) -> None:
        if self.log.closed:
            return  # closed already
        try:
            self._end()
        finally:
            self.log.close()
            shutil.rmtree(self.profile, ignore_errors=True)

    def _end(self) -> None:
        """Close the page's websocket and end the browser's process group."""
        try:
            if getattr(self, "ws", None) is not None:
                self.call("Browser.close", timeout=5)
        except Exception:  # already gone, or not answering: the signals below finish the job
            pass
        self._stack.close()
        for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 5.0)):
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            deadline = time.monotonic() + wait
            while time.monotonic() < deadline:
                self.proc.poll()  # reap the wrapper, or its zombie keeps the group "alive"
                if not _group_alive(self.proc.pid):
                    break
                time.sleep(0.05)
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
