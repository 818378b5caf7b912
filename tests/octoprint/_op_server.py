"""A real OctoPrint server for the tests: the one ``scripts/build-octoprint`` installs into
``build/octoprint-venv`` (with the plugin), started on 127.0.0.1 with a temporary base folder,
and a small client for its REST API (urllib: the test venv has no requests).

The base folder holds what OctoPrint's own end-to-end fixtures hold
(``.github/fixtures/with_acl`` in OctoPrint's repository): a ``config.yaml`` with the first run
done and the online checks off, and a ``users.yaml`` with an admin whose API key the client
sends (``X-Api-Key``; the global ``api.key`` is deprecated and stops working in 1.13). Clients
on 127.0.0.1 are logged in as that admin (``autologinLocal``), which the headless browser uses.
Plugins that would reach the network or add start-up work (software update, announcements,
tracking, the plugin repository, the first-run wizard...) are disabled.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import os
import secrets
import signal
import socket
import subprocess
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

__all__ = ["OCTOPRINT", "ROOT", "VENV", "OctoPrintServer", "needs_octoprint",
           "octoprint_available", "octoprint_server"]

ROOT = Path(__file__).resolve().parents[2]
VENV = ROOT / "build" / "octoprint-venv"
OCTOPRINT = VENV / "bin" / "octoprint"

DISABLED_PLUGINS = ["achievements", "announcements", "backup", "corewizard", "discovery",
                    "errortracking", "file_check", "firmware_check", "health_check",
                    "pi_support", "pluginmanager", "softwareupdate", "tracking"]


def octoprint_available() -> bool:
    """True when ``scripts/build-octoprint`` has built the server and installed the plugin."""
    return OCTOPRINT.is_file() and (VENV / ".stamp-plugin").is_file()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _yaml(data: Any, indent: int = 0) -> str:
    """YAML of nested dicts, lists and scalars (JSON scalars are YAML), without PyYAML."""
    pad = "  " * indent
    out = []
    for key, value in data.items():
        if isinstance(value, dict) and value:
            out.append(f"{pad}{key}:\n{_yaml(value, indent + 1)}")
        else:
            out.append(f"{pad}{key}: {json.dumps(value)}\n")
    return "".join(out)


class OctoPrintServer:
    """One OctoPrint server process on 127.0.0.1 with its own base folder.

    Parameters
    ----------
    basedir
        An empty folder for OctoPrint's settings, uploads and logs.
    plugin_settings
        ``plugins.printability`` of config.yaml (what the settings page would have saved).
    serial
        More of config.yaml's ``serial`` section.
    """

    def __init__(self, basedir: Path, *, plugin_settings: dict[str, Any] | None = None,
                 serial: dict[str, Any] | None = None) -> None:
        self.basedir = Path(basedir)
        self.port = _free_port()
        self.url = f"http://127.0.0.1:{self.port}/"
        self.api_key = secrets.token_urlsafe(32)
        self.plugin_settings = dict(plugin_settings or {})
        self.serial = {"autoconnect": False, "additionalPorts": ["/dev/pts/*"], **(serial or {})}
        self.proc: subprocess.Popen | None = None
        self.startup_seconds: float | None = None

    # -------------------------------------------------------------- files
    @property
    def uploads(self) -> Path:
        return self.basedir / "uploads"

    @property
    def log(self) -> Path:
        return self.basedir / "logs" / "octoprint.log"

    def log_text(self) -> str:
        try:
            return self.log.read_text(encoding="utf-8", errors="replace")
        except OSError:
            return ""

    def _password_hash(self) -> str:
        # the hash OctoPrint itself writes (argon2), computed by its own code
        code = ("import sys; from octoprint.access.users import FilebasedUserManager as M; "
                "print(M.create_password_hash(sys.argv[1]))")
        r = subprocess.run([str(VENV / "bin" / "python"), "-c", code, secrets.token_hex(8)],
                           capture_output=True, text=True, timeout=60)
        if r.returncode != 0:
            raise RuntimeError(f"cannot hash a password with OctoPrint's code: {r.stderr}")
        return r.stdout.strip()

    def _write_config(self) -> None:
        self.basedir.mkdir(parents=True, exist_ok=True)
        config = {
            "accessControl": {"autologinLocal": True, "autologinAs": "admin",
                              "autologinHeadsupAcknowledged": True},
            "devel": {"enableRateLimiter": False},
            "plugins": {"_disabled": DISABLED_PLUGINS, "printability": self.plugin_settings},
            "serial": self.serial,
            "server": {"firstRun": False, "onlineCheck": {"enabled": False},
                       "pluginBlacklist": {"enabled": False},
                       "secretKey": secrets.token_hex(16),
                       "seenWizards": {"corewizard": 4}},
        }
        (self.basedir / "config.yaml").write_text(_yaml(config), encoding="utf-8")
        users = {"_version": 2,
                 "admin": {"active": True, "apikey": self.api_key, "groups": ["admins", "users"],
                           "password": self._password_hash(), "permissions": [],
                           "roles": ["user", "admin"], "settings": {}}}
        (self.basedir / "users.yaml").write_text(_yaml(users), encoding="utf-8")

    # -------------------------------------------------------------- process
    def start(self, timeout: float = 120.0) -> None:
        """Start the server and wait until its REST API answers."""
        self._write_config()
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PRINTABILITY_SERVER": "off"}
        env.pop("PYTHONPATH", None)
        t0 = time.monotonic()
        self._out = open(self.basedir / "serve.out", "wb")
        self.proc = subprocess.Popen(
            [str(OCTOPRINT), "serve", "--basedir", str(self.basedir), "--host", "127.0.0.1",
             "--port", str(self.port),
             # OctoPrint refuses to start as root (CI containers run as root) without it
             *(["--iknowwhatimdoing"] if os.geteuid() == 0 else [])],
            stdout=self._out, stderr=subprocess.STDOUT, env=env, cwd=self.basedir,
            start_new_session=True)
        while True:
            if self.proc.poll() is not None:
                raise RuntimeError(f"OctoPrint exited ({self.proc.returncode}) while starting:\n"
                                   + self.tail())
            try:
                self.get("api/version", timeout=2)
                break
            except (OSError, http.client.HTTPException, RuntimeError):
                pass
            if time.monotonic() - t0 > timeout:
                raise RuntimeError(f"OctoPrint did not answer within {timeout:.0f} s:\n"
                                   + self.tail())
            time.sleep(0.25)
        self.startup_seconds = time.monotonic() - t0

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self) -> None:
        if self.proc is None:
            return
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGTERM)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(10)
        self._out.close()

    def tail(self, n: int = 60) -> str:
        parts = []
        for p in (self.basedir / "serve.out", self.log):
            try:
                lines = p.read_text(encoding="utf-8", errors="replace").splitlines()
            except OSError:
                continue
            parts.append(f"--- {p.name}\n" + "\n".join(lines[-n:]))
        return "\n".join(parts)

    # -------------------------------------------------------------- REST
    def request(self, method: str, path: str, *, data: bytes | None = None,
                headers: dict[str, str] | None = None, timeout: float = 60
                ) -> tuple[int, bytes, dict[str, str]]:
        """One request with the API key: (status, body, headers); an HTTP error status is
        returned, not raised."""
        req = urllib.request.Request(urllib.parse.urljoin(self.url, path), data=data,
                                     method=method,
                                     headers={"X-Api-Key": self.api_key, **(headers or {})})
        try:
            with urllib.request.urlopen(req, timeout=timeout) as r:
                return r.status, r.read(), dict(r.headers)
        except urllib.error.HTTPError as e:
            return e.code, e.read(), dict(e.headers)

    def get(self, path: str, *, timeout: float = 60) -> Any:
        status, body, _ = self.request("GET", path, timeout=timeout)
        if status != 200:
            raise RuntimeError(f"GET {path}: {status} {body[:500]!r}")
        return json.loads(body)

    def post_json(self, path: str, payload: dict[str, Any], *, timeout: float = 60
                  ) -> tuple[int, Any]:
        status, body, _ = self.request("POST", path, data=json.dumps(payload).encode(),
                                       headers={"Content-Type": "application/json"},
                                       timeout=timeout)
        try:
            return status, json.loads(body) if body else None
        except ValueError:
            return status, body.decode("utf-8", "replace")

    def upload(self, name: str, content: bytes, *, timeout: float = 120) -> tuple[int, Any]:
        """``POST /api/files/local`` (multipart, as OctoPrint's upload button sends it)."""
        boundary = uuid.uuid4().hex
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"file\"; "
                f"filename=\"{name}\"\r\nContent-Type: application/octet-stream\r\n\r\n"
                ).encode() + content + f"\r\n--{boundary}--\r\n".encode()
        status, data, _ = self.request(
            "POST", "api/files/local", data=body,
            headers={"Content-Type": f"multipart/form-data; boundary={boundary}"},
            timeout=timeout)
        try:
            return status, json.loads(data)
        except ValueError:
            return status, data.decode("utf-8", "replace")

    def plugin_state(self) -> dict[str, Any]:
        """``GET /api/plugin/printability``: settings, jobs, notifications, the axis check."""
        return self.get("api/plugin/printability")

    def wait_job(self, name: str, *, timeout: float = 180) -> dict[str, Any]:
        """The plugin's job for the file ``name`` once it is done, failed or skipped."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if not self.alive():
                raise RuntimeError("OctoPrint died:\n" + self.tail())
            for job in self.plugin_state()["jobs"]:
                if job["name"] == name and job["state"] in ("done", "failed", "skipped"):
                    return job
            time.sleep(0.3)
        raise TimeoutError(f"no finished printability job for {name} in {timeout:.0f} s:\n"
                           + json.dumps(self.plugin_state(), indent=1)[-3000:] + self.tail())


@contextlib.contextmanager
def octoprint_server(basedir: Path, **kwargs: Any) -> Iterator[OctoPrintServer]:
    """A started :class:`OctoPrintServer`, stopped on exit."""
    server = OctoPrintServer(basedir, **kwargs)
    try:
        server.start()
        yield server
    finally:
        server.stop()


def needs_octoprint():
    """A pytest mark: skip (saying why) when the server is not built."""
    import pytest

    return pytest.mark.skipif(
        not octoprint_available(),
        reason="OctoPrint is not built (run scripts/build-octoprint; scripts/test does)")
