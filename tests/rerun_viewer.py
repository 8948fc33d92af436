"""Drive the bundled Rerun viewer headless and read what it shows: which recordings it holds, which views
the blueprint of each one lays out on screen, and screenshots.

rerun-sdk 0.41 ships ``rerun --headless`` (an offscreen viewer whose gRPC control service keeps running) and
``rerun viewer-mcp`` (a Model Context Protocol server on stdio that drives a running viewer: ``rerun_get_state``
names the open recordings and every view of the blueprint on screen, ``rerun_set_location`` shows a recording,
``rerun_save_screenshot`` writes a PNG). :class:`HeadlessViewer` speaks that protocol (JSON-RPC 2.0, one message
per line) to one viewer started on the recordings, bound to 127.0.0.1, with its own home folder (no state shared
with a user's viewer), in its own process group (ended as a whole on close).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

RERUN = Path(sys.executable).with_name("rerun")


def rerun_binary() -> str:
    """The bundled ``rerun`` binary (the venv's, else the one on PATH)."""
    return str(RERUN if RERUN.exists() else shutil.which("rerun"))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Shown:
    """What the viewer shows for one recording: its application id, active timeline and the views on screen."""

    store_id: str
    application_id: str
    timeline: str | None
    views: list[dict[str, Any]] = field(default_factory=list)

    def origins(self) -> set[str]:
        return {str(v.get("origin", "")).strip("/") for v in self.views}

    def names(self) -> set[str]:
        return {str(v.get("name", "")) for v in self.views}


class ViewerError(RuntimeError):
    """The viewer or its control server failed (message with the viewer's log tail)."""


class HeadlessViewer:
    """One headless Rerun viewer opened on ``rrds`` (in that order), driven through ``rerun viewer-mcp``.

    Parameters
    ----------
    rrds : sequence of Path
        Recordings to open, in order.
    workdir : Path
        Scratch folder (the viewer's home, its log).
    size : (int, int)
        Window size [logical points].
    timeout_s : float
        Longest wait for the viewer to load and answer.
    """

    def __init__(self, rrds: list[Path], workdir: Path, *, size: tuple[int, int] = (1600, 1000),
                 timeout_s: float = 90.0) -> None:
        self.timeout_s = timeout_s
        self.workdir = Path(workdir)
        home = self.workdir / "home"
        home.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        env = {**os.environ, "HOME": str(home), "XDG_DATA_HOME": str(home / "data"),
               "XDG_CONFIG_HOME": str(home / "config"), "WGPU_BACKEND": os.environ.get("WGPU_BACKEND", "vulkan")}
        # usage analytics off (what `rerun analytics disable` writes): a test sends nothing anywhere
        config = home / "config" / "rerun"
        config.mkdir(parents=True, exist_ok=True)
        (config / "analytics.json").write_text(json.dumps({
            "analytics_enabled": False, "analytics_id": "0" * 32, "metadata": {},
            "config_file_path": str(config / "analytics.json"), "data_dir_path": str(home / "data" / "rerun")}))
        self.env = env
        self.log_path = self.workdir / "viewer.log"
        self._log = self.log_path.open("w")
        cmd = [rerun_binary(), *(str(Path(p).resolve()) for p in rrds), "--headless",
               "--window-size", f"{size[0]}x{size[1]}", "--bind", "127.0.0.1", "--port", str(self.port)]
        self.viewer = subprocess.Popen(cmd, stdout=self._log, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                       env=env, start_new_session=True, cwd=self.workdir)
        self.mcp: subprocess.Popen[str] | None = None
        self._id = 0
        try:
            self._connect()
        except BaseException:
            self.close()
            raise

    # -- protocol ------------------------------------------------------------------------------------------------

    def _connect(self) -> None:
        deadline = time.monotonic() + self.timeout_s
        while True:  # the viewer's gRPC server listens once it started
            if self.viewer.poll() is not None:
                raise ViewerError(f"the viewer exited with {self.viewer.returncode}:\n{self.log_tail()}")
            with socket.socket() as s:
                if s.connect_ex(("127.0.0.1", self.port)) == 0:
                    break
            if time.monotonic() > deadline:
                raise ViewerError(f"the viewer did not listen within {self.timeout_s:.0f} s:\n{self.log_tail()}")
            time.sleep(0.2)
        self.mcp = subprocess.Popen([rerun_binary(), "viewer-mcp", "--endpoint", f"http://127.0.0.1:{self.port}"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                    text=True, env=self.env, start_new_session=True)
        self._request("initialize", {"protocolVersion": "2024-11-05", "capabilities": {},
                                     "clientInfo": {"name": "oacli-tests", "version": "0"}})
        self._send({"jsonrpc": "2.0", "method": "notifications/initialized"})

    def _send(self, message: dict[str, Any]) -> None:
        assert self.mcp is not None and self.mcp.stdin is not None
        self.mcp.stdin.write(json.dumps(message) + "\n")
        self.mcp.stdin.flush()

    def _request(self, method: str, params: dict[str, Any]) -> dict[str, Any]:
        assert self.mcp is not None and self.mcp.stdout is not None
        self._id += 1
        self._send({"jsonrpc": "2.0", "id": self._id, "method": method, "params": params})
        while True:
            line = self.mcp.stdout.readline()
            if not line:
                raise ViewerError(f"viewer-mcp closed its output during {method}:\n{self.log_tail()}")
            reply = json.loads(line)
            if reply.get("id") == self._id:
                break
        if "error" in reply:
            raise ViewerError(f"{method}: {reply['error']}")
        return dict(reply["result"])

    def call(self, tool: str, **arguments: Any) -> Any:
        """Call one viewer-mcp tool; its JSON answer (the first text item), parsed when it is JSON."""
        result = self._request("tools/call", {"name": tool, "arguments": arguments})
        texts = [c["text"] for c in result.get("content", []) if c.get("type") == "text"]
        if result.get("isError"):
            raise ViewerError(f"{tool}({arguments}): {' '.join(texts)[:2000]}")
        if not texts:
            return None
        try:
            return json.loads(texts[0])
        except json.JSONDecodeError:
            return texts[0]

    def log_tail(self, chars: int = 3000) -> str:
        self._log.flush()
        return self.log_path.read_text(errors="replace")[-chars:]

    # -- what is shown -------------------------------------------------------------------------------------------

    def state(self) -> dict[str, Any]:
        return dict(self.call("rerun_get_state"))

    def wait_loaded(self, count: int) -> dict[str, Any]:
        """Wait until ``count`` recordings are open and none is loading; the viewer state then."""
        deadline = time.monotonic() + self.timeout_s
        while True:
            state = self.state()
            if len(state.get("recordings", [])) >= count and not state.get("loading"):
                return state
            if "Failed to load" in self.log_tail(100_000):
                raise ViewerError(f"the viewer could not load a recording:\n{self.log_tail()}")
            if time.monotonic() > deadline:
                raise ViewerError(f"{len(state.get('recordings', []))} of {count} recordings loaded after "
                                  f"{self.timeout_s:.0f} s:\n{self.log_tail()}")
            time.sleep(0.3)

    def application_ids(self, state: dict[str, Any]) -> dict[str, str]:
        """Dataset id (as in a store id) to application id (the catalog entry's name)."""
        out = {}
        for server in state.get("servers", []):
            for entry in server.get("entries", []):
                out[str(entry["url"]).rsplit("/", 1)[-1]] = str(entry["name"])
        return out

    def show(self, recording: dict[str, Any], state: dict[str, Any]) -> Shown:
        """Make ``recording`` (an item of ``state["recordings"]``) the one on screen; what its blueprint shows."""
        self.call("rerun_set_location", location=recording["location"])
        self.call("wait_for", min_steps=10, timeout_secs=30)
        now = self.state()
        store_id = str(recording["store_id"])
        if now.get("active_store_id") != store_id:
            raise ViewerError(f"{store_id} is not on screen after set_location (active: {now.get('active_store_id')})")
        dataset = store_id.split(":", 2)[1]
        active = next(r for r in now["recordings"] if r["store_id"] == store_id)
        timeline = (active.get("current_time") or {}).get("timeline", {}).get("name")
        return Shown(store_id, self.application_ids(now).get(dataset, dataset), timeline,
                     [v for v in now.get("views", []) if v.get("visible", True)])

    def screenshot(self, png: Path, *, view_id: str | None = None, max_size: int = 0) -> Path:
        """Save the window (or one view) as a PNG at full resolution; returns the path."""
        args: dict[str, Any] = {"file_path": str(Path(png).resolve()), "max_size": max_size}
        if view_id is not None:
            args["view_id"] = view_id
        self.call("rerun_save_screenshot", **args)
        deadline = time.monotonic() + self.timeout_s
        while not Path(png).exists():
            if time.monotonic() > deadline:
                raise ViewerError(f"no screenshot at {png}")
            time.sleep(0.1)
        return Path(png)

    def close(self) -> None:
        if self.mcp is not None:
            self.mcp.kill()
            self.mcp.wait()
        if self.viewer.poll() is None:
            os.killpg(self.viewer.pid, signal.SIGKILL)
        self.viewer.wait()
        self._log.close()

    def __enter__(self) -> HeadlessViewer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
