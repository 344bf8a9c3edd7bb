"""The operator's console of a rendered mechanism in a real browser.

``evo-door render soft_close_drawer.yaml --set stop.k=2000 --user swing --console``
(at 1 kHz)
runs in its own process; headless Chromium opens the URL it prints. The page is the
drawer's: its handle on its stroke in m, no door, no latch zoom, no JND panel; the
drawer's parameters with their units and sliders over four times their values; a key
steps the mass and the renderer applies it; a stop too stiff for the loop is refused
with the renderer's reason and the set in force stays. Skipped as
``tests/test_console_browser.py`` is where Chromium, its driver or Selenium is missing
(on CI they are required).
"""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from evo_door.models.blocks import CACHE_ENV
from tests.browser import (
    By,
    TimeoutException,
    WebDriverWait,
    headless_chromium,
    skip_if_missing,
    stop,
)
from tests.helpers import LOADED_MACHINE_WATCHDOG

pytestmark = [pytest.mark.browser, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]
DRAWER = str(ROOT / "examples" / "blocks" / "soft_close_drawer.yaml")


skip_if_missing()

#: how long the renderer gets to print its console URL, the page to show a change (s)
START_TIMEOUT = 60.0
APPLY_TIMEOUT = 10.0


def _wait(driver, condition, what: str, timeout: float = APPLY_TIMEOUT):
    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(condition)
    except TimeoutException:
        message = driver.find_element(By.ID, "message").text
        raise AssertionError(f"timed out: {what} (#message: {message!r})") from None


def _in_force(driver, name: str) -> float | None:
    value = driver.find_element(By.ID, f"slider-{name}").get_attribute("data-in-force")
    return None if value in (None, "") else float(value)


def _render(folder: Path):
    """``render DRAWER ... --console`` in its own process: (process, URL)."""
    # at 1 kHz with a watchdog of 1 s: a loaded machine (CI) does not stall the loop,
    # which would end the render under the page
    command = [sys.executable, "-m", "evo_door", "render", DRAWER, "--set", "stop.k=2000"]
    command += ["--user", "swing", "--duration", "120", "--console", "--console-port", "0"]
    command += ["--rate", "1000", *LOADED_MACHINE_WATCHDOG]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
    env[CACHE_ENV] = str(folder / "mechanisms")
    proc = subprocess.Popen(command, cwd=folder, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=env)  # fmt: skip
    lines: queue.Queue = queue.Queue()

    def read() -> None:
        for line in proc.stdout or ():
            lines.put(line)
        lines.put(None)

    threading.Thread(target=read, daemon=True).start()
    seen = []
    deadline = time.monotonic() + START_TIMEOUT
    while True:
        try:
            line = lines.get(timeout=max(deadline - time.monotonic(), 0.01))
        except queue.Empty:
            line = None
        if line is None:
            proc.kill()
            pytest.fail("the renderer printed no console URL:\n" + "".join(seen))
        seen.append(line)
        if line.startswith("console "):
            return proc, line.split()[1]


def test_the_page_of_a_rendered_drawer(tmp_path):
    driver = headless_chromium()
    proc = None
    try:
        proc, url = _render(tmp_path)
        driver.get(url)
        _wait(driver, lambda d: d.find_element(By.ID, "connection").text == "connected", "page")
        _wait(driver, lambda d: _in_force(d, "box.mass") is not None, "the drawer's sliders")
        # the drawer's page: its name, its handle in m, no door, latch zoom or JND panel
        assert "soft-close-drawer" in driver.find_element(By.ID, "door-title").text
        assert not driver.find_element(By.ID, "jnd-panel").is_displayed()
        assert not driver.find_element(By.ID, "zoom-latch").is_displayed()
        assert driver.find_elements(By.ID, "slider-stop.at") == []
        mass = driver.find_element(By.ID, "slider-box.mass")
        assert float(mass.get_attribute("max")) == 12.0
        assert "kg" in driver.find_element(By.ID, "value-box.mass").text
        _wait(driver, lambda d: d.execute_script("return (window.evoConsole.curve||{}).unit;")
              == "m", "the drawer's curve")  # fmt: skip
        label = driver.execute_script("return document.getElementById('force-angle')"
                                      ".getAttribute('aria-label');")  # fmt: skip
        assert "position in m" in label
        # a key steps the mass by its step (0.5 kg); the renderer applies it
        driver.execute_script("if (document.activeElement) document.activeElement.blur();")
        driver.find_element(By.TAG_NAME, "body").send_keys("A")
        _wait(driver, lambda d: _in_force(d, "box.mass") == 3.5, "box.mass 3.5 kg in force")
        # a stop too stiff for the loop: the renderer's reason, the set in force kept
        driver.execute_script(
            "const s = document.getElementById('slider-stop.k');"
            "s.value = '8000';"
            "s.dispatchEvent(new Event('input', {bubbles: true}));"
            "s.dispatchEvent(new Event('change', {bubbles: true}));"
        )
        _wait(driver, lambda d: "not passive" in d.find_element(By.ID, "message").text,
              "the refusal's reason")  # fmt: skip
        assert "(stop.k)" in driver.find_element(By.ID, "message").text
        assert _in_force(driver, "stop.k") == 2000.0
    finally:
        driver.quit()
        stop(proc)
