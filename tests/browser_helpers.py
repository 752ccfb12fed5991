"""Headless Chromium driven over the Chrome DevTools protocol (CDP) with ``websockets``.

No browser is downloaded: the system's ``chromium`` (Debian's package) is used, found on
``PATH`` or named by ``FLEETMAP_CHROMIUM``. ``Browser`` starts it with a fresh profile on
a free DevTools port, attaches to its page, and records every protocol event, so a test
can read console errors, requests and navigations after the fact.
"""

from __future__ import annotations

import json
import os
import queue
import re
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import httpx
from websockets.sync.client import connect

FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
    "--no-default-browser-check",
    "--window-size=1280,800",
    "--remote-debugging-address=127.0.0.1",
    "--remote-debugging-port=0",
]
LISTENING = re.compile(r"DevTools listening on (ws://\S+)")


def find_chromium() -> str | None:
    """The Chromium executable: ``FLEETMAP_CHROMIUM``, else ``chromium`` on PATH."""
    named = os.environ.get("FLEETMAP_CHROMIUM")
    if named:
        return named
    for name in ("chromium", "chromium-browser"):
        found = shutil.which(name)
        if found:
            return found
    return None


def chromium_or_skip() -> str:
    """The Chromium executable; the test is skipped without one (failed under CI, whose
    ``.ci/run`` installs it: its absence there is a broken CI)."""
    import pytest

    executable = find_chromium()
    if executable is None:
        message = "chromium not found: apt-get install chromium, or set FLEETMAP_CHROMIUM"
        if os.environ.get("CI"):
            pytest.fail(message)
        pytest.skip(message)
    return executable


class ProtocolError(RuntimeError):
    """A DevTools command failed, or a page script threw."""


class Browser:
    """One headless Chromium with one page; ``close()`` ends it (and its children).
    ``flags``: more command-line switches, after ``FLAGS``."""

    def __init__(
        self,
        executable: str,
        profile_dir: Path,
        timeout: float = 30.0,
        flags: Sequence[str] = (),
    ) -> None:
        self.timeout = timeout
        self.events: list[dict[str, Any]] = []
        self._replies: dict[int, dict[str, Any]] = {}
        self._cond = threading.Condition()
        self._next_id = 0
        self._stack = ExitStack()
        self.proc = subprocess.Popen(
            [executable, *FLAGS, *flags, f"--user-data-dir={profile_dir}", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,  # its own process group: close() ends every child
        )
        try:
            port = self._devtools_port()
            socket = connect(self._page_socket(port), max_size=None, open_timeout=timeout)
            self.ws = self._stack.enter_context(socket)
        except Exception:
            self.close()
            raise
        self._reader = threading.Thread(target=self._read, name="cdp-reader", daemon=True)
        self._reader.start()
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")

    # ---------------------------------------------------------------- start-up
    def _devtools_port(self) -> int:
        """The port Chromium prints on stderr once its DevTools endpoint listens."""
        lines: queue.Queue[str] = queue.Queue()

        def pump() -> None:
            for line in self.proc.stderr:
                lines.put(line)

        threading.Thread(target=pump, name="chromium-stderr", daemon=True).start()
        deadline = time.monotonic() + self.timeout
        seen = []
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=0.2)
            except queue.Empty:
                if self.proc.poll() is not None:
                    break
                continue
            seen.append(line)
            match = LISTENING.search(line)
            if match:
                return int(re.search(r":(\d+)/", match.group(1)).group(1))
        raise RuntimeError(f"chromium did not open its DevTools port: {''.join(seen)[-2000:]}")

    def _page_socket(self, port: int) -> str:
        """The DevTools WebSocket of the browser's first page."""
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            targets = httpx.get(f"http://127.0.0.1:{port}/json/list", timeout=5.0).json()
            pages = [t for t in targets if t.get("type") == "page"]
            if pages:
                return pages[0]["webSocketDebuggerUrl"]
            time.sleep(0.1)
        raise RuntimeError("chromium opened no page")

    # ---------------------------------------------------------------- protocol
    def _read(self) -> None:
        try:
            for raw in self.ws:
                message = json.loads(raw)
                with self._cond:
                    if "id" in message:
                        self._replies[message["id"]] = message
                    else:
                        self.events.append(message)
                    self._cond.notify_all()
        except Exception:  # the socket closed: wake any waiter
            with self._cond:
                self._cond.notify_all()

    def call(self, method: str, **params: Any) -> dict[str, Any]:
        """Send one command and wait for its result."""
        with self._cond:
            self._next_id += 1
            call_id = self._next_id
        self.ws.send(json.dumps({"id": call_id, "method": method, "params": params}))
        deadline = time.monotonic() + self.timeout
        with self._cond:
            while call_id not in self._replies:
                left = deadline - time.monotonic()
                if left <= 0 or not self._reader.is_alive():
                    raise ProtocolError(f"{method}: no reply within {self.timeout} s")
                self._cond.wait(left)
            reply = self._replies.pop(call_id)
        if "error" in reply:
            raise ProtocolError(f"{method}: {reply['error']}")
        return reply.get("result", {})

    def evaluate(self, expression: str) -> Any:
        """The value of a page expression (promises awaited), returned by value."""
        result = self.call(
            "Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True
        )
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise ProtocolError(f"{expression!r} threw: {text}")
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 10.0) -> Any:
        """Poll a page expression until it is truthy; returns its value."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise AssertionError(f"{expression!r} still {value!r} after {timeout} s")
            time.sleep(0.05)

    def wait_event(self, method: str, timeout: float = 10.0) -> dict[str, Any]:
        """The first recorded event named ``method`` (waiting for it)."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                found = [e for e in self.events if e["method"] == method]
                if found:
                    return found[0]
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"no {method} event within {timeout} s")
                self._cond.wait(left)

    def open(self, url: str) -> None:
        """Navigate to ``url`` and wait for its load event; forgets earlier events."""
        with self._cond:
            self.events.clear()
        self.call("Page.navigate", url=url)
        self.wait_event("Page.loadEventFired", timeout=self.timeout)

    def named(self, method: str) -> list[dict[str, Any]]:
        """Every recorded event named ``method``, in order."""
        with self._cond:
            return [e["params"] for e in self.events if e["method"] == method]

    def console_errors(self) -> list[str]:
        """Uncaught exceptions, console.error calls and browser log errors so far."""
        errors = [
            e["exceptionDetails"].get("exception", {}).get("description", "exception")
            for e in self.named("Runtime.exceptionThrown")
        ]
        errors += [
            " ".join(str(a.get("value", a.get("description", ""))) for a in e["args"])
            for e in self.named("Runtime.consoleAPICalled")
            if e["type"] in ("error", "assert")
        ]
        errors += [
            f"{e['entry']['text']} ({e['entry'].get('url', '')})"
            for e in self.named("Log.entryAdded")
            if e["entry"]["level"] == "error"
        ]
        return errors

    def requested(self, fragment: str) -> int:
        """How many requests so far had ``fragment`` in their URL."""
        return sum(fragment in e["request"]["url"] for e in self.named("Network.requestWillBeSent"))

    def close(self) -> None:
        """Close the socket and end the browser's process group (SIGTERM, then SIGKILL)."""
        self._stack.close()
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout=10)
