"""What the browser tests share: whether headless Chromium can run here, Selenium's
names, a browser, and a render process stopped as an operator stops it.

A test module calls :func:`skip_if_missing` at its top. Where Chromium, its driver,
Selenium or aiohttp is missing its tests are skipped, except on CI (``CI`` set) unless
``EVO_DOOR_BROWSER_TESTS=0``: there :func:`headless_chromium` fails them instead, so the
browser tests cannot silently drop out.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import subprocess

import pytest


def _program(path: str, name: str) -> str | None:
    return path if os.access(path, os.X_OK) else shutil.which(name)


CHROMIUM = _program("/usr/bin/chromium", "chromium")
CHROMEDRIVER = _program("/usr/bin/chromedriver", "chromedriver")
MISSING = [
    what
    for what, there in (
        ("chromium (apt-get install chromium)", CHROMIUM),
        ("chromedriver (apt-get install chromium-driver)", CHROMEDRIVER),
        ("selenium (pip install selenium)", importlib.util.find_spec("selenium")),
        ("aiohttp (pip install aiohttp)", importlib.util.find_spec("aiohttp")),
    )
    if not there
]
#: on CI the browser tests must run: a missing browser fails them instead of a skip
REQUIRED = bool(os.environ.get("CI")) and os.environ.get("EVO_DOOR_BROWSER_TESTS", "1") != "0"
WHY = "the browser tests need " + ", ".join(MISSING)
if not MISSING:  # else (on CI) headless_chromium fails every test with WHY
    from selenium import webdriver
    from selenium.common.exceptions import NoAlertPresentException, TimeoutException
    from selenium.webdriver.chrome.options import Options
    from selenium.webdriver.chrome.service import Service
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait
else:  # the test modules import these names either way
    By = NoAlertPresentException = TimeoutException = WebDriverWait = None


def skip_if_missing() -> None:
    """Skip the calling test module where the browser is missing and CI does not
    require it."""
    if MISSING and not REQUIRED:
        pytest.skip(WHY, allow_module_level=True)


def headless_chromium():
    """A headless Chromium driven by Selenium (fails the test with what is missing)."""
    if MISSING:  # REQUIRED: CI must not lose the browser tests silently
        pytest.fail(f"{WHY}; CI requires them (EVO_DOOR_BROWSER_TESTS=0 skips)", pytrace=False)
    options = Options()
    for arg in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1366,900"):
        options.add_argument(arg)
    options.binary_location = CHROMIUM
    return webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)


def stop(proc) -> None:
    """Stop a render still running as an operator does (Ctrl-C), killed after 30 s."""
    if proc is not None and proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
