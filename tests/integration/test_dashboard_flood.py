"""The dashboard and the daemon's /metrics server hold under a flood of idle and slow clients
(issue 34): a real mosquitto, a daemon on a simulated camera with ``[http]``, ``edgedsm dashboard``
as a process and Debian's chromium (headless, Selenium).

Checked, with numbers that can fail: 1000 idle TCP connections and 20 slowloris ones (a header
byte a second) against the dashboard; the page still loads in chromium and shows live data
within a bound; the dashboard's CPU during the idle flood stays low; its open files stay
bounded; its threads return to the baseline afterwards. The same flood against the daemon's
``[http]`` port leaves its frame rate unchanged (frames over equal intervals, from the daemon's
own statistics). Then: a foreign Host header is refused (421); HTTPS with a self-signed
certificate is served, plain HTTP on that port is refused, and a stalled handshake does not block
others; the viewer login is required when configured (303/401 without, the page with), in the
browser too, and wrong passwords are rate-limited.
"""

from __future__ import annotations

import base64
import http.client
import json
import os
import re
import resource
import shutil
import socket
import ssl
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from helpers_daemon import Daemon, base_config, write_config
from helpers_dashboard import DashboardProcess, make_browser, wait_for
from helpers_mqtt import Broker, Subscriber

from edgedsm.publish import Topics
from edgedsm.publish.http_guard import ConnectionLimits
from tests.ports import free_port

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.xdist_group("dashboard_flood")]

IDLE = 1000
SLOW = 20
DEVICE = "flooded"
LIVE_S = 15.0  # the page loads and shows a new frame count within this, under the flood
IDLE_CPU = 0.10  # cores: the dashboard's CPU during the idle flood, at most
PASSWORD = "viewer-password-7"
PER_CLIENT = ConnectionLimits().max_per_client  # every connection here comes from 127.0.0.1


def _set_nofile(soft: int) -> None:
    """This process's soft open-file limit (children inherit it at start)."""
    hard = resource.getrlimit(resource.RLIMIT_NOFILE)[1]
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft if hard == resource.RLIM_INFINITY else min(soft, hard), hard))


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _threads(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("Threads:"):
            return int(line.split()[1])
    raise AssertionError("no Threads line")


def _soft_nofile(pid: int) -> int:
    line = next(line for line in Path(f"/proc/{pid}/limits").read_text().splitlines()
                if line.startswith("Max open files"))
    return int(line.split()[3])


def _fds(pid: int) -> int:
    return len(os.listdir(f"/proc/{pid}/fd"))


def _cpu_over(pid: int, seconds: float) -> float:
    """Cores used by ``pid`` over the next ``seconds``."""
    cpu, start = _cpu_s(pid), time.monotonic()
    time.sleep(seconds)
    return (_cpu_s(pid) - cpu) / (time.monotonic() - start)


class Flood:
    """``idle`` connections opened and left silent (those the server closes stay closed), and
    ``slow`` slowloris connections, each sending one header byte a second and reopened when the
    server closes it."""

    def __init__(self, port: int, idle: int = IDLE, slow: int = SLOW) -> None:
        self.port = port
        self.idle = [socket.create_connection(("127.0.0.1", port), timeout=5) for _ in range(idle)]
        self.slow_closed = 0
        self.slow_lifetimes: list[float] = []
        self._stop = threading.Event()
        self._slow: dict[socket.socket, float] = {}
        for _ in range(slow):
            self._open_slow()
        self._thread = threading.Thread(target=self._trickle, name="slowloris", daemon=True)
        self._thread.start()

    def _open_slow(self) -> None:
        sock = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        sock.sendall(b"GET / HTTP/1.1\r\n")
        self._slow[sock] = time.monotonic()

    def _trickle(self) -> None:
        for _ in range(600):  # bounded: ten minutes at most
            if self._stop.wait(1.0):
                return
            for sock, opened in list(self._slow.items()):
                try:
                    sock.sendall(b"X")
                    sock.setblocking(False)
                    closed = sock.recv(1) == b""
                except BlockingIOError:
                    closed = False
                except OSError:
                    closed = True
                finally:
                    sock.setblocking(True)
                if closed:
                    self.slow_closed += 1
                    self.slow_lifetimes.append(time.monotonic() - opened)
                    sock.close()
                    del self._slow[sock]
                    if not self._stop.is_set():
                        self._open_slow()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        for sock in [*self.idle, *self._slow]:
            sock.close()


@dataclass
class Plant:
    broker: Broker
    daemon: Daemon
    http_port: int
    dashboard: DashboardProcess
    stats: Subscriber
    browser: Any
    tmp: Path


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    user_soft = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    _set_nofile(1024)  # the dashboard and the daemon start with a user's default limit
    tmp = tmp_path_factory.mktemp("flood")
    broker = Broker(tmp / "broker").start()
    http_port = free_port()
    config = base_config(tmp / DEVICE, device=DEVICE, port=broker.port)
    config["http"] = {"listen": f"127.0.0.1:{http_port}"}
    config_path = write_config(tmp / f"{DEVICE}.toml", config)
    stats = Subscriber(broker.port, [Topics.of("edgedsm", DEVICE).stats]).start()
    dashboard = DashboardProcess(["--broker", f"127.0.0.1:{broker.port}", "--listen", "127.0.0.1:0",
                                  "--database", str(tmp / "history.sqlite3"), "-c", str(config_path)])
    daemon = Daemon(config_path)
    _set_nofile(max(4 * IDLE, user_soft))  # the flood's sockets are the test's
    browser = None
    try:
        browser = make_browser(tmp / "chromium-profile")
        yield Plant(broker, daemon, http_port, dashboard, stats, browser, tmp)
    finally:
        if browser is not None:
            browser.quit()
        daemon.kill()
        dashboard.stop()
        stats.stop()
        broker.stop()
        _set_nofile(user_soft)


def _frames_shown(browser: Any) -> int | None:
    text = browser.execute_script("const s = document.getElementById('device-stats'); return s ? s.textContent : '';")
    match = re.search(r"frames (\d+)", text or "")
    return int(match.group(1)) if match else None


def _load_until_live(plant: Plant) -> float:
    """Load the page; seconds until it shows a frame count, then a newer one (live data)."""
    started = time.monotonic()
    plant.browser.get(plant.dashboard.url)
    first = wait_for(lambda: _frames_shown(plant.browser), LIVE_S, "the device's frame count on the page")
    wait_for(lambda: (_frames_shown(plant.browser) or 0) > first, LIVE_S, "a newer frame count (live)")
    return time.monotonic() - started


@pytest.mark.alone
@pytest.mark.timeout(300)
def test_a_flood_of_idle_and_slow_clients_leaves_the_page_live_and_the_dashboard_idle(plant: Plant) -> None:
    pid = plant.dashboard.process.pid
    assert _soft_nofile(pid) == 1024  # a user's default: the caps keep the dashboard well within it
    _wait_for_statistics(plant)
    before = _load_until_live(plant)
    time.sleep(1.0)
    baseline_threads, baseline_fds = _threads(pid), _fds(pid)
    baseline_cpu = _cpu_over(pid, 5.0)

    burst_cpu = _cpu_s(pid)
    flood = Flood(int(plant.dashboard.url.rsplit(":", 1)[1].strip("/")))
    burst_cpu = _cpu_s(pid) - burst_cpu  # accepting the 1000 and closing those beyond the caps
    try:
        time.sleep(0.5)
        flood_cpu = _cpu_over(pid, 5.0)
        flood_fds = _fds(pid)
        under = _load_until_live(plant)
        started = time.monotonic()
        assert b"edgedsm plant dashboard" in plant.dashboard.get("/")
        plain_get = time.monotonic() - started
        time.sleep(11.0)  # past the header timeout (10 s): every slowloris connection was closed once
        slow_closed, lifetimes = flood.slow_closed, sorted(flood.slow_lifetimes)
    finally:
        flood.close()
    print(f"\nflood: page live in {before:.2f} s before, {under:.2f} s under {IDLE} idle + {SLOW} slow "
          f"connections; GET / {plain_get * 1000:.0f} ms; CPU {baseline_cpu:.3f} cores before, {flood_cpu:.3f} "
          f"during ({burst_cpu:.2f} CPU-s to accept the burst);\n"
          f"fds {baseline_fds} -> {flood_fds}; threads {baseline_threads}; slowloris closed {slow_closed}, "
          f"lifetimes {lifetimes[:1]}..{lifetimes[-1:]} s")
    assert under < LIVE_S and plain_get < 1.0
    assert flood_cpu <= IDLE_CPU and flood_cpu <= baseline_cpu + 0.05, (baseline_cpu, flood_cpu)
    assert burst_cpu < 2.0  # about a millisecond per connection accepted
    assert flood_fds <= baseline_fds + PER_CLIENT + 8  # one address's cap (and a few closing), not 1000
    assert slow_closed >= SLOW and all(life < 10.0 + 2.5 for life in lifetimes)  # header deadline, bytes or not
    wait_for(lambda: _threads(pid) <= baseline_threads + 3, 15.0, "the dashboard's threads back to the baseline")
    assert plant.dashboard.errors == []


def _wait_for_statistics(plant: Plant) -> None:
    """The daemon's first statistics (its start compiles kernels: slow on a busy host)."""
    topic = plant.stats.topics[0]
    plant.daemon.wait_until(lambda: len(plant.stats.on(topic)) >= 4, 120, "the daemon's statistics")


def _rate(stats: Subscriber, seconds: float) -> float:
    """Frames per second over the next ``seconds``, from the daemon's own statistics (t, frames)."""
    topic = stats.topics[0]
    first = stats.on(topic)[-1].json()
    time.sleep(seconds)
    last = stats.on(topic)[-1].json()
    return (last["frames"] - first["frames"]) / (last["t"] - first["t"])


def _healthz(port: int) -> int:
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    try:
        connection.request("GET", "/healthz")
        return connection.getresponse().status
    finally:
        connection.close()


@pytest.mark.alone
@pytest.mark.timeout(300)
def test_the_same_flood_on_the_daemons_metrics_port_leaves_its_frame_rate_unchanged(plant: Plant) -> None:
    _wait_for_statistics(plant)
    pid = plant.daemon.process.pid
    cpu_start, started = _cpu_s(pid), time.monotonic()
    calm = [_rate(plant.stats, 8.0)]
    daemon_cpu_calm = (_cpu_s(pid) - cpu_start) / (time.monotonic() - started)
    flood = Flood(plant.http_port)
    try:
        cpu_start, started = _cpu_s(pid), time.monotonic()
        flooded = _rate(plant.stats, 8.0)
        daemon_cpu_flood = (_cpu_s(pid) - cpu_start) / (time.monotonic() - started)
        health = _healthz(plant.http_port)
    finally:
        flood.close()
    calm.append(_rate(plant.stats, 8.0))
    mean = sum(calm) / 2
    print(f"\ndaemon frame rate: {calm[0]:.1f} fps before, {flooded:.1f} under the flood of [http], "
          f"{calm[1]:.1f} after; daemon CPU {daemon_cpu_calm:.2f} cores before, {daemon_cpu_flood:.2f} during")
    assert health == 200
    # 8 s at ~100 frames/s: the statistics' 0.5 s cadence is in t, so the rate is exact to a frame
    # or two; the shared host's own jitter (the calm intervals' spread) is the tolerance beside 5 %
    tolerance = max(0.05 * mean, abs(calm[0] - calm[1]))
    assert abs(flooded - mean) <= tolerance, (calm, flooded)


# -- Host, HTTPS, login: their own small dashboards (no broker needed) -----------------------

def _small_dashboard(*args: str, env: dict[str, str] | None = None, tmp: Path) -> DashboardProcess:
    return DashboardProcess(["--broker", f"127.0.0.1:{free_port()}", "--listen", "127.0.0.1:0",
                             "--database", str(tmp / "history.sqlite3"), *args], env=env)


def _request(url: str, path: str, *, method: str = "GET", headers: dict[str, str] | None = None,
             body: bytes | None = None, context: ssl.SSLContext | None = None) -> http.client.HTTPResponse:
    host, port = url.split("//", 1)[1].strip("/").rsplit(":", 1)
    connection = (http.client.HTTPSConnection(host, int(port), timeout=5, context=context) if context
                  else http.client.HTTPConnection(host, int(port), timeout=5))
    connection.request(method, path, body=body, headers=headers or {})
    answer = connection.getresponse()
    answer.read()
    connection.close()
    return answer


def test_a_foreign_host_header_is_refused(tmp_path: Path) -> None:
    dashboard = _small_dashboard("--allowed-host", "dash.plant.local", tmp=tmp_path)
    try:
        statuses = {host: _request(dashboard.url, "/api/info", headers={"Host": host}).status
                    for host in ("attacker.example:8080", "dash.plant.local", "localhost:1", "127.0.0.1",
                                 socket.gethostname())}
    finally:
        dashboard.stop()
    assert statuses == {"attacker.example:8080": 421, "dash.plant.local": 200, "localhost:1": 200,
                        "127.0.0.1": 200, socket.gethostname(): 200}


@pytest.fixture
def certificate(tmp_path: Path) -> tuple[Path, Path]:
    openssl = shutil.which("openssl")
    if openssl is None:
        pytest.fail("openssl is required (Debian: apt-get install openssl; ./scripts/test.sh installs it)")
    cert, key = tmp_path / "dash.crt", tmp_path / "dash.key"
    subprocess.run([openssl, "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert),
                    "-days", "1", "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1"],
                   check=True, capture_output=True, timeout=60)
    return cert, key


def test_https_is_served_plain_http_refused_and_a_stalled_handshake_blocks_nobody(
        tmp_path: Path, certificate: tuple[Path, Path]) -> None:
    cert, key = certificate
    dashboard = _small_dashboard("--tls-cert", str(cert), "--tls-key", str(key), "--header-timeout", "2", tmp=tmp_path)
    assert dashboard.url.startswith("https://127.0.0.1:")
    host, port = dashboard.url.split("//", 1)[1].strip("/").rsplit(":", 1)
    trusted = ssl.create_default_context(cafile=str(cert))
    stalled = [socket.create_connection((host, int(port))) for _ in range(3)]
    stalled[0].sendall(b"\x16\x03\x01")  # a ClientHello that never completes
    try:
        started = time.monotonic()
        answer = _request(dashboard.url, "/api/info", context=trusted)
        secure_s = time.monotonic() - started
        plain = socket.create_connection((host, int(port)), timeout=5)
        plain.sendall(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        refusal = plain.recv(4096)
        plain.close()
        with pytest.raises(ssl.SSLCertVerificationError):
            _request(dashboard.url, "/", context=ssl.create_default_context())  # not trusted without the cert
        started = time.monotonic()
        assert stalled[0].recv(1) == b""  # the stalled handshake is closed at the header deadline
        stalled_s = time.monotonic() - started
    finally:
        for sock in stalled:
            sock.close()
        dashboard.stop()
    assert answer.status == 200 and secure_s < 1.0
    assert refusal.startswith(b"HTTP/1.1 400 ") and b"this port speaks HTTPS" in refusal
    assert stalled_s < 2.5


def test_the_viewer_login_is_required_when_configured(tmp_path: Path) -> None:
    dashboard = _small_dashboard(env={"EDGEDSM_DASHBOARD_VIEWER_PASSWORD": PASSWORD}, tmp=tmp_path)
    form = {"Content-Type": "application/x-www-form-urlencoded"}
    try:
        page = _request(dashboard.url, "/")
        api = _request(dashboard.url, "/api/devices")
        login_page = _request(dashboard.url, "/login")
        wrong = _request(dashboard.url, "/login", method="POST", headers=form, body=b"password=guess")
        right = _request(dashboard.url, "/login", method="POST", headers=form, body=f"password={PASSWORD}".encode())
        cookie = right.getheader("Set-Cookie", "")
        session = cookie.split(";", 1)[0]
        with_cookie = _request(dashboard.url, "/", headers={"Cookie": session})
        basic = "Basic " + base64.b64encode(f"script:{PASSWORD}".encode()).decode()
        with_basic = _request(dashboard.url, "/api/devices", headers={"Authorization": basic})
        guesses = [_request(dashboard.url, "/login", method="POST", headers=form, body=b"password=guess").status
                   for _ in range(5)]
        still_in = _request(dashboard.url, "/api/info", headers={"Cookie": session})
    finally:
        dashboard.stop()
    assert (page.status, page.getheader("Location")) == (303, "/login")
    assert api.status == 401 and login_page.status == 200
    assert (wrong.status, wrong.getheader("Location")) == (303, "/login?failed")
    assert (right.status, right.getheader("Location")) == (303, "/")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie and "Secure" not in cookie
    assert with_cookie.status == 200 and with_basic.status == 200
    assert guesses == [303, 303, 303, 303, 429]  # 5 wrong per minute from one address, then 429
    assert still_in.status == 200  # a session already open is not locked out


@pytest.mark.alone  # with the flood tests: the module's plant (daemon, browser) is started once
@pytest.mark.timeout(120)
def test_the_browser_logs_in_and_sees_live_data(plant: Plant) -> None:
    dashboard = DashboardProcess(["--broker", f"127.0.0.1:{plant.broker.port}", "--listen", "127.0.0.1:0",
                                  "--database", str(plant.tmp / "login.sqlite3")],
                                 env={"EDGEDSM_DASHBOARD_VIEWER_PASSWORD": PASSWORD})
    try:
        plant.browser.get(dashboard.url)
        wait_for(lambda: plant.browser.current_url.endswith("/login"), 10, "the login page")
        plant.browser.find_element("id", "password").send_keys(PASSWORD)
        plant.browser.find_element("id", "login").click()
        wait_for(lambda: _frames_shown(plant.browser), LIVE_S, "the page with the device's frames after login")
        info = json.loads(plant.browser.execute_script(
            "return fetch('/api/info').then((r) => r.text());"))
    finally:
        dashboard.stop()
    assert plant.browser.current_url == dashboard.url and "read_only" in info
