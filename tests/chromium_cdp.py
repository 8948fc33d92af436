"""Open a local HTML file in a real headless Chromium and inspect it over the DevTools protocol (test helper).

Chromium (Debian's ``chromium``) runs with a fresh profile, no sandbox, no GPU, no background networking, component
updates, sync or first-run tasks, and ``--remote-debugging-port=0``; the helper reads the port from the profile's
``DevToolsActivePort``, connects with tornado's websocket client (tornado comes with ``distributed``, a dependency),
opens one page target, enables the Network and Page domains, navigates to the file and waits for its load event.
Every ``Network.requestWillBeSent`` of the page is recorded; ``file://`` (the page itself) and ``data:`` (inline
images) are not network requests, anything else is. :func:`open_page` returns the requests, the value of a
JavaScript expression evaluated in the page, and a full-page screenshot (PNG bytes).
"""

from __future__ import annotations

import asyncio
import base64
import json
import os
import shutil
import signal
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

CHROMIUM_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run", "--disable-default-apps",
         "--disable-extensions", "--remote-debugging-port=0", "--remote-allow-origins=*")


def chromium_or_skip() -> str:
    """The Chromium executable, or skip the calling test with the reason."""
    for name in CHROMIUM_NAMES:
        path = shutil.which(name)
        if path:
            try:
                import tornado.websocket  # noqa: F401
            except ImportError:  # pragma: no cover - a dependency of distributed
                pytest.skip("needs tornado (with distributed) for the DevTools protocol")
            return path
    pytest.skip("needs a headless Chromium (Debian: apt-get install chromium; .ci/run installs it on CI)")


@dataclass
class PageResult:
    """What a page load showed: the requests, the evaluated expression's value, a screenshot."""

    requests: list[str]
    network_requests: list[str]
    value: Any
    screenshot_png: bytes


async def _session(ws_url: str, file_url: str, expression: str, timeout_s: float) -> PageResult:
    from tornado.websocket import websocket_connect

    conn = await websocket_connect(ws_url, max_message_size=256 * 2**20)
    counter = 0
    events: list[dict[str, Any]] = []

    async def call(method: str, params: dict[str, Any] | None = None, session: str | None = None) -> dict[str, Any]:
        nonlocal counter
        counter += 1
        msg: dict[str, Any] = {"id": counter, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        await conn.write_message(json.dumps(msg))
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            raw = await asyncio.wait_for(conn.read_message(), timeout_s)
            if raw is None:
                raise RuntimeError("DevTools connection closed")
            data = json.loads(raw)
            if data.get("id") == counter:
                if "error" in data:
                    raise RuntimeError(f"{method}: {data['error']}")
                return data.get("result", {})
            events.append(data)
        raise TimeoutError(method)

    async def until(method: str) -> None:
        deadline = time.monotonic() + timeout_s
        while not any(e.get("method") == method for e in events):
            if time.monotonic() > deadline:
                raise TimeoutError(method)
            raw = await asyncio.wait_for(conn.read_message(), timeout_s)
            if raw is None:
                raise RuntimeError("DevTools connection closed")
            events.append(json.loads(raw))

    target = (await call("Target.createTarget", {"url": "about:blank"}))["targetId"]
    session = (await call("Target.attachToTarget", {"targetId": target, "flatten": True}))["sessionId"]
    await call("Network.enable", {}, session)
    await call("Page.enable", {}, session)
    await call("Page.navigate", {"url": file_url}, session)
    await until("Page.loadEventFired")
    value = (await call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                             "awaitPromise": True}, session))["result"].get("value")
    shot = await call("Page.captureScreenshot", {"format": "png", "captureBeyondViewport": True}, session)
    await asyncio.sleep(0.2)  # late requests, if any, get their events in
    conn.close()
    urls = [e["params"]["request"]["url"][:120] for e in events
            if e.get("method") == "Network.requestWillBeSent" and e.get("sessionId") == session]
    network = [u for u in urls if not (u.startswith("file://") or u.startswith("data:"))]
    return PageResult(urls, network, value, base64.b64decode(shot["data"]))


def open_page(chromium: str, html: Path, expression: str, timeout_s: float = 60.0) -> PageResult:
    """Load ``html`` in a fresh headless Chromium; record its requests, evaluate ``expression``, screenshot it.

    Parameters
    ----------
    chromium : str
        The executable.
    html : Path
        A local HTML file.
    expression : str
        JavaScript evaluated after the load event (its value returned by value).
    timeout_s : float
        Limit of each wait [s].

    Returns
    -------
    PageResult
    """
    with tempfile.TemporaryDirectory(prefix="oacli-chromium-", ignore_cleanup_errors=True) as profile:
        proc = subprocess.Popen([chromium, *FLAGS, f"--user-data-dir={profile}", "--window-size=1280,900",
                                 "about:blank"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)  # its own process group: its helpers end with it
        try:
            port_file = Path(profile) / "DevToolsActivePort"
            deadline = time.monotonic() + timeout_s
            while not (port_file.is_file() and len(port_file.read_text().splitlines()) >= 2):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"chromium did not start (exit {proc.poll()})")
                time.sleep(0.05)
            port, path = port_file.read_text().splitlines()[:2]
            return asyncio.run(_session(f"ws://127.0.0.1:{port}{path}", Path(html).resolve().as_uri(), expression,
                                        timeout_s))
        finally:
            _stop(proc)


def _stop(proc: subprocess.Popen) -> None:
    """End the Chromium this helper started and its helper processes (its own process group)."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(10)
            time.sleep(0.2)  # the group's helpers leave with the browser
        except subprocess.TimeoutExpired:
            continue


PAGE_FACTS = """(() => {
  const imgs = Array.from(document.querySelectorAll('img'));
  const text = (sel) => { const e = document.querySelector(sel); return e ? e.innerText : null; };
  const rows = (sel) => document.querySelectorAll(sel + ' tr').length;
  return {
    title: document.title,
    status: text('#status-line'),
    images: imgs.map(i => ({alt: i.alt, complete: i.complete, w: i.naturalWidth, h: i.naturalHeight,
                            shown_w: i.getBoundingClientRect().width})),
    segment_rows: rows('#segment-table'), comparison_rows: rows('#comparison-table'),
    estimate_rows: rows('#estimate-table'), run_rows: rows('#run-table'), cell_rows: rows('#cell-table'),
    run_table: text('#run-table'), config: text('#config-text'),
    scripts: document.scripts.length,
  };
})()"""
"""What the report tests read of a page."""
