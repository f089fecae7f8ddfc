"""Shared pieces of the MQTT integration tests: a real mosquitto on a free loopback port and a
recording test subscriber (used by test_mqtt.py and test_daemon_e2e.py).

mosquitto is required: without it the tests using these FAIL (the README's test command
installs it).
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from helpers_commands import ENV as COMMAND_KEY_ENV
from paho.mqtt.enums import CallbackAPIVersion

from edgedsm.publish import Topics
from tests.ports import free_port

REPO = Path(__file__).resolve().parents[2]
START_TIMEOUT_S = 10.0
WAIT_S = 15.0  # upper bound for anything that should happen "soon"


# -- tools -----------------------------------------------------------------------------------

def tool(name: str, package: str) -> str:
    path = shutil.which(name) or shutil.which(name, path="/usr/sbin:/usr/bin:/sbin")
    if path is None:
        pytest.fail(f"{name} is not installed, so the MQTT integration tests cannot run: install it with "
                    f"'apt-get install -y {package}' (the README's test command does)")
    return path


def wait_until(predicate: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


def child_env() -> dict[str, str]:
    path = os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))
    # the tests' command key (helpers_commands): a daemon started here accepts signed test commands
    return {**os.environ, "PYTHONPATH": path, **COMMAND_KEY_ENV}


# -- the broker ------------------------------------------------------------------------------

@dataclass
class TlsFiles:
    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path


class Broker:
    """A mosquitto on 127.0.0.1:<free port> (tests/ports.py); the port stays the same across restarts.

    ``settings``: mosquitto configuration lines (e.g. the shipped config/mosquitto/edgedsm.conf,
    its paths and listener templated) used instead of the listener, TLS and password lines."""

    def __init__(self, directory: Path, *, persistence: bool = False, tls: TlsFiles | None = None,
                 password_file: Path | None = None, settings: Callable[[int], str] | None = None) -> None:
        self.binary = tool("mosquitto", "mosquitto")
        self.directory = directory
        self.directory.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.persistence = persistence
        self.tls = tls
        self.password_file = password_file
        self.settings = settings
        self.log = directory / "mosquitto.log"
        self.process: subprocess.Popen[bytes] | None = None

    def _config(self) -> Path:
        lines = [f"listener {self.port} 127.0.0.1"]
        if self.settings is not None:
            lines = self.settings(self.port).splitlines()
        elif self.tls is not None:
            lines += [f"cafile {self.tls.ca}", f"certfile {self.tls.server_cert}",
                      f"keyfile {self.tls.server_key}", "require_certificate true"]
        if self.settings is not None:
            pass
        elif self.password_file is not None:
            lines += ["allow_anonymous false", f"password_file {self.password_file}"]
        else:
            lines.append("allow_anonymous true")
        if self.persistence:
            lines += ["persistence true", f"persistence_location {self.directory}/",
                      "autosave_interval 1"]
        else:
            lines.append("persistence false")
        lines += [f"log_dest file {self.log}", "log_type error", "log_type warning", "log_type notice"]
        if os.geteuid() == 0:
            lines.append("user root")  # mosquitto would otherwise drop to 'mosquitto' and lose tmp_path
        path = self.directory / "mosquitto.conf"
        path.write_text("\n".join(lines) + "\n")
        return path

    def _accepts(self) -> bool:
        with socket.socket() as sock:
            sock.settimeout(0.2)
            return sock.connect_ex(("127.0.0.1", self.port)) == 0

    def start(self, attempts: int = 5) -> Broker:
        config = self._config()
        self.process = subprocess.Popen([self.binary, "-c", str(config)], stdout=subprocess.DEVNULL,
                                        stderr=subprocess.PIPE)
        deadline = time.monotonic() + START_TIMEOUT_S
        while not self._accepts():
            if self.process.poll() is not None:
                err = self.process.stderr.read().decode(errors="replace") if self.process.stderr else ""
                log = self.log.read_text() if self.log.exists() else ""
                self._close_pipes()
                if "Address already in use" in log and attempts > 1:
                    # a restart on the same port: a client reconnecting meanwhile can be handed that
                    # very port as its ephemeral one (Linux connects it to itself) until it gives up
                    time.sleep(0.5)
                    return self.start(attempts - 1)
                pytest.fail(f"mosquitto exited with {self.process.returncode}:\n{err}\n{log}")
            if time.monotonic() > deadline:
                self.stop()
                pytest.fail(f"mosquitto did not accept connections on port {self.port} within "
                            f"{START_TIMEOUT_S} s")
            time.sleep(0.02)
        return self

    def stop(self) -> None:
        if self.process is None:
            return
        if self.process.poll() is None:
            self.process.terminate()  # SIGTERM: mosquitto saves its persistence file on the way out
            try:
                self.process.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(timeout=5)
        self._close_pipes()
        self.process = None

    def restart(self, pause: float = 0.3) -> None:
        self.stop()
        time.sleep(pause)
        self.start()

    def _close_pipes(self) -> None:
        if self.process is not None and self.process.stderr is not None:
            self.process.stderr.close()



def _openssl(*args: str, cwd: Path) -> None:
    result = subprocess.run([tool("openssl", "openssl"), *args], cwd=cwd, capture_output=True, text=True,
                            timeout=30)
    if result.returncode != 0:
        pytest.fail(f"openssl {' '.join(args)} failed:\n{result.stderr}")


def make_certificates(directory: Path) -> TlsFiles:
    """A CA, a server certificate for 127.0.0.1/localhost and a client certificate (EC P-256: fast)."""
    directory.mkdir(parents=True, exist_ok=True)
    key = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    _openssl("req", "-x509", *key, "-keyout", "ca.key", "-out", "ca.crt", "-days", "2", "-subj", "/CN=edgedsm test CA",
             "-addext", "basicConstraints=critical,CA:TRUE", "-addext", "keyUsage=critical,keyCertSign,cRLSign",
             cwd=directory)
    (directory / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n"
                                          "extendedKeyUsage=serverAuth\n")
    (directory / "client.ext").write_text("extendedKeyUsage=clientAuth\n")
    for name in ("server", "client"):
        _openssl("req", *key, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN=edgedsm-{name}",
                 cwd=directory)
        _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.crt", "-CAkey", "ca.key", "-CAcreateserial",
                 "-out", f"{name}.crt", "-days", "2", "-extfile", f"{name}.ext", cwd=directory)
    return TlsFiles(directory / "ca.crt", directory / "server.crt", directory / "server.key",
                    directory / "client.crt", directory / "client.key")


# -- a test subscriber -----------------------------------------------------------------------

@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    properties: Any = None

    def json(self) -> Any:
        return json.loads(self.payload)


@dataclass
class Subscriber:
    """A paho client that records everything on its topics (resubscribing after reconnects)."""

    port: int
    topics: list[str]
    client_id: str = ""
    protocol: int = mqtt.MQTTv311
    tls: TlsFiles | None = None
    username: str | None = None
    password: str | None = None
    messages: list[Received] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._lock = threading.Lock()
        self.subscribed = threading.Event()
        kwargs: dict[str, Any] = {}
        if self.protocol != mqtt.MQTTv5:
            kwargs["clean_session"] = not self.client_id
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=self.client_id, protocol=self.protocol,
                                  **kwargs)
        self.client.reconnect_delay_set(0.05, 0.3)
        if self.tls is not None:
            self.client.tls_set(ca_certs=str(self.tls.ca), certfile=str(self.tls.client_cert),
                                keyfile=str(self.tls.client_key))
        if self.username is not None:
            self.client.username_pw_set(self.username, self.password)
        self.client.on_connect = self._on_connect
        self.client.on_subscribe = lambda *args: self.subscribed.set()
        self.client.on_message = self._on_message

    def _on_connect(self, client: mqtt.Client, userdata: Any, flags: Any, reason: Any, props: Any) -> None:
        if not reason.is_failure:
            client.subscribe([(topic, 1) for topic in self.topics])

    def _on_message(self, client: mqtt.Client, userdata: Any, message: mqtt.MQTTMessage) -> None:
        with self._lock:
            self.messages.append(Received(message.topic, bytes(message.payload), bool(message.retain),
                                          getattr(message, "properties", None)))

    def start(self) -> Subscriber:
        self.client.connect_async("127.0.0.1", self.port, keepalive=10)
        self.client.loop_start()
        if not self.subscribed.wait(WAIT_S):
            self.stop()
            pytest.fail(f"test subscriber could not subscribe on port {self.port}")
        return self

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()

    def on(self, topic: str) -> list[Received]:
        with self._lock:
            return [m for m in self.messages if m.topic == topic]

    def wait_for(self, topic: str, predicate: Callable[[Received], bool], what: str,
                 timeout: float = WAIT_S) -> Received:
        found: list[Received] = []

        def check() -> bool:
            found[:] = [m for m in self.on(topic) if predicate(m)]
            return bool(found)

        wait_until(check, timeout, what)
        return found[-1]

    def alerts(self, topics: Topics) -> list[dict[str, Any]]:
        return [m.json() for m in self.on(topics.alerts)]
