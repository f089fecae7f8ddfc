"""The dashboard as a process and Debian's chromium driven by Selenium, for the browser tests."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest
from helpers_mqtt import child_env

from tests.ports import free_port

CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1400,1300", "--force-device-scale-factor=1"]


class DashboardProcess:
    """`python -m edgedsm dashboard ...`; the URL is read from its first line."""

    def __init__(self, args: list[str], env: dict[str, str] | None = None) -> None:
        self.process = subprocess.Popen([sys.executable, "-m", "edgedsm", "-v", "dashboard", *args],
                                        stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                        text=True, env={**child_env(), **(env or {})})
        self.errors: list[str] = []
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        match = re.search(r"(https?://\S+/)", line)
        if match is None:
            self.process.kill()
            pytest.fail(f"the dashboard did not print its URL: {line!r} {self.process.stderr.read()!r}")
        self.url = match.group(1)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stderr is not None
        in_traceback = False
        for line in self.process.stderr:
            if in_traceback:
                # the whole traceback in one entry, up to its exception line: the failure says why
                self.errors[-1] += "\n" + line.rstrip()
                in_traceback = line.startswith((" ", "\t"))
            elif " ERROR " in line or "Traceback" in line or " CRITICAL " in line:
                self.errors.append(line.rstrip())
                in_traceback = "Traceback" in line

    def stop(self) -> int:
        self.process.terminate()
        try:
            code = self.process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.process.kill()
            code = self.process.wait(timeout=10)
        self._reader.join(2)
        for pipe in (self.process.stdout, self.process.stderr):
            if pipe is not None:
                pipe.close()
        return code

    def get(self, path: str) -> bytes:
        with urllib.request.urlopen(self.url.rstrip("/") + path, timeout=5) as answer:
            return answer.read()

    def post(self, path: str, body: dict) -> bytes:
        request = urllib.request.Request(self.url.rstrip("/") + path, data=json.dumps(body).encode(),
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request, timeout=5) as answer:
            return answer.read()


def make_browser(profile: Path):  # -> selenium WebDriver (import kept local: selenium is a test extra)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    binary, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if binary is None or driver is None:
        pytest.fail("chromium and chromium-driver are required (Debian: apt-get install chromium chromium-driver; "
                    "./scripts/test.sh installs them)")
    options = webdriver.ChromeOptions()
    options.binary_location = binary
    for flag in [*CHROMIUM_FLAGS, f"--user-data-dir={profile}"]:
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    # chromedriver's port from this worker's range (Selenium's own pick is bind(0), then released)
    service = Service(executable_path=driver, port=free_port())
    browser = webdriver.Chrome(options=options, service=service)
    browser.set_page_load_timeout(20)
    browser.set_script_timeout(20)
    return browser


def severe_console_messages(browser) -> list[str]:
    return [entry["message"] for entry in browser.get_log("browser") if entry.get("level") == "SEVERE"]


def wait_for(predicate, timeout: float, what: str, poll: float = 0.05):
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)
