"""A private mosquitto on a free loopback port, for the demo, the benchmarks and the dashboard's load
test when no broker is set (not part of the daemon: it never starts a broker).

``secure=True`` (the demo) runs it as a plant should: the shipped ``config/mosquitto/edgedsm.conf``
and ``acl`` (docs/security.md) with their paths and port changed, a fresh CA and server
certificate (openssl) and a password file (mosquitto_passwd) with a random password per user."""

from __future__ import annotations

import os
import secrets
import shutil
import socket
import subprocess
import tempfile
import time
from pathlib import Path
from types import TracebackType
from typing import Self

from edgedsm.errors import EdgedsmError
from edgedsm.resources import data_file

SHIPPED_PATHS = "/etc/mosquitto/edgedsm/"
SHIPPED_LISTENER = "listener 8883"
SHIPPED_PREFIX, SHIPPED_DEVICE = "edgedsm", "line3"  # what the shipped acl names


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _run(command: list[str], cwd: Path) -> None:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True, timeout=60)
    if done.returncode != 0:
        raise EdgedsmError(f"{Path(command[0]).name} failed: {done.stderr.strip()[-300:]}")


def _tool(name: str, package: str) -> str:
    binary = shutil.which(name) or (f"/usr/sbin/{name}" if Path(f"/usr/sbin/{name}").exists() else None)
    if binary is None:
        raise EdgedsmError(f"{name} is not installed (Debian: apt-get install {package})")
    return binary


def secure_settings(directory: Path, port: int, prefix: str, device: str) -> dict[str, str]:
    """Write the shipped broker config for ``<prefix>/<device>`` into ``directory`` (certificates,
    password file, acl, edgedsm.conf listening on 127.0.0.1:``port``); returns user -> password."""
    openssl = _tool("openssl", "openssl")
    key = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    _run([openssl, "req", "-x509", *key, "-keyout", "ca.key", "-out", "ca.crt", "-days", "30", "-subj",
          "/CN=edgedsm demo CA", "-addext", "basicConstraints=critical,CA:TRUE", "-addext",
          "keyUsage=critical,keyCertSign,cRLSign"], directory)
    (directory / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n")
    _run([openssl, "req", *key, "-keyout", "server.key", "-out", "server.csr", "-subj", "/CN=localhost"], directory)
    _run([openssl, "x509", "-req", "-in", "server.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
          "-out", "server.crt", "-days", "30", "-extfile", "server.ext"], directory)
    acl = data_file("config/mosquitto/acl").read_text(encoding="utf-8")
    acl = acl.replace(f"{SHIPPED_PREFIX}/{SHIPPED_DEVICE}/", "\0base\0") \
        .replace(f"{SHIPPED_PREFIX}/", f"{prefix}/").replace("\0base\0", f"{prefix}/{device}/") \
        .replace(f"user {SHIPPED_PREFIX}-{SHIPPED_DEVICE}", f"user edgedsm-{device}")
    (directory / "acl").write_text(acl, encoding="utf-8")
    users = [line.split()[1] for line in acl.splitlines() if line.startswith("user ")]
    passwords = {user: secrets.token_urlsafe(18) for user in users}
    passwd = _tool("mosquitto_passwd", "mosquitto")
    for i, (user, password) in enumerate(passwords.items()):
        _run([passwd, "-b", *(["-c"] if i == 0 else []), str(directory / "passwd"), user, password], directory)
    conf = data_file("config/mosquitto/edgedsm.conf").read_text(encoding="utf-8")
    lines = [line for line in conf.splitlines() if line.strip() and not line.startswith("#")]
    if SHIPPED_LISTENER not in lines:
        raise EdgedsmError(f"config/mosquitto/edgedsm.conf has no '{SHIPPED_LISTENER}' line")
    text = "\n".join(lines).replace(SHIPPED_LISTENER, f"listener {port} 127.0.0.1") \
        .replace(SHIPPED_PATHS, f"{directory}/")
    if os.geteuid() == 0:
        text += "\nuser root"  # else mosquitto drops to 'mosquitto', who cannot read this private directory
    (directory / "mosquitto.conf").write_text(text + "\npersistence false\n", encoding="utf-8")
    return passwords


class LocalBroker:
    """``with LocalBroker() as broker: ... broker.port`` — mosquitto, anonymous, loopback only; with
    ``secure=True``, TLS, passwords and the shipped acl for ``<prefix>/<device>`` (``ca_file``,
    ``passwords``: user -> password; users edgedsm-<device>, -dashboard, -operator, -viewer)."""

    def __init__(self, port: int | None = None, start_timeout_s: float = 5.0, *, secure: bool = False,
                 prefix: str = SHIPPED_PREFIX, device: str = SHIPPED_DEVICE) -> None:
        self.port = port or free_port()
        self.start_timeout_s = start_timeout_s
        self.secure, self.prefix, self.device = secure, prefix, device
        self.passwords: dict[str, str] = {}
        self.ca_file: Path | None = None
        self._dir: tempfile.TemporaryDirectory[str] | None = None
        self._process: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> Self:
        binary = _tool("mosquitto", "mosquitto")
        self._dir = tempfile.TemporaryDirectory(prefix="edgedsm-broker-")
        directory = Path(self._dir.name)
        conf = directory / "mosquitto.conf"
        if self.secure:
            try:
                self.passwords = secure_settings(directory, self.port, self.prefix, self.device)
            except BaseException:
                self.__exit__(None, None, None)
                raise
            self.ca_file = directory / "ca.crt"
        else:
            conf.write_text(f"listener {self.port} 127.0.0.1\nallow_anonymous true\npersistence false\n")
        self._process = subprocess.Popen([binary, "-c", str(conf)], stdout=subprocess.DEVNULL,
                                         stderr=subprocess.PIPE)
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                err = self._process.stderr.read().decode(errors="replace") if self._process.stderr else ""
                self.__exit__(None, None, None)
                raise EdgedsmError(f"mosquitto exited at start: {err.strip()}")
            try:
                with socket.create_connection(("127.0.0.1", self.port), timeout=0.2):
                    return self
            except OSError:
                time.sleep(0.05)
        self.__exit__(None, None, None)
        raise EdgedsmError(f"mosquitto did not listen on port {self.port} within {self.start_timeout_s} s")

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        if self._process is not None:
            self._process.terminate()
            try:
                self._process.wait(timeout=3)
            except subprocess.TimeoutExpired:
                self._process.kill()
                self._process.wait(timeout=3)
            if self._process.stderr is not None:
                self._process.stderr.close()
            self._process = None
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None
