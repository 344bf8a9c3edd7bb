"""The operator's web console in a real browser.

``evo-door render --params seed_trial --device sim --user swing --console`` runs as a
user starts it, in its own process; headless Chromium (Debian's ``chromium`` and
``chromium-driver``, driven by Selenium) opens the URL it prints and works the page:
sliders, keys, a forged out-of-range change, A/B, the final choice. Then the render is
stopped with Ctrl-C (SIGINT) and its log says what the renderer applied and when:
each change between two cycles (at a multiple of the loop period), one parameter set
per change, the chosen set, and ``evo-door show`` summarises the session.

The tests share one renderer and one page and run in file order (a session); the last
one stops the renderer. They are skipped where Chromium, its driver or Selenium is
missing, except on CI (``CI`` set) unless ``EVO_DOOR_BROWSER_TESTS=0``: there a missing
browser is a failure, so the browser tests cannot silently drop out.

Run them alone: ``pytest -m browser``. ``EVO_DOOR_WRITE_FIGURES=1`` writes the page's
screenshot to ``docs/figures/console.png`` (else to the test's temporary folder).
"""

from __future__ import annotations

import json
import math
import os
import queue
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.browser import (
    By,
    NoAlertPresentException,
    TimeoutException,
    WebDriverWait,
    headless_chromium,
    skip_if_missing,
    stop,
)
from tests.helpers import LOADED_MACHINE_WATCHDOG

pytestmark = [pytest.mark.browser, pytest.mark.slow]

ROOT = Path(__file__).resolve().parents[1]


skip_if_missing()

from evo_door.cli import main  # noqa: E402
from evo_door.models import get_model  # noqa: E402
from evo_door.models.haptic import PARAMS  # noqa: E402
from evo_door.render.keys import GROUP, key_map  # noqa: E402
from evo_door.render.session import format_session, read_session  # noqa: E402

RATE = 2500.0  # Hz, the loop rate (render's default)
CONTROL_TOKEN = "browser-test-token"
PERIOD = 1.0 / RATE  # s
#: how long the renderer gets to print its console URL (numba's cache, the console's start)
START_TIMEOUT = 60.0
#: how long the page gets to show what the renderer applied (s)
APPLY_TIMEOUT = 10.0
SENSATIONS = [p.name for p in PARAMS if p.group == GROUP]
STEP = {name: abs(step) for name, step in key_map().values()}
UP_KEY = {name: key for key, (name, step) in key_map().items() if step > 0}
DOWN_KEY = {name: key for key, (name, step) in key_map().items() if step < 0}

#: run in the page before its own script: keeps every WebSocket the page opens, what
#: the page sent and what it received, so a test can check every message and send a
#: forged one on the page's socket (with the native send, which the record skips)
CAPTURE_SOCKETS = """
(() => {
  const Native = window.WebSocket;
  const nativeSend = Native.prototype.send;
  window.__sockets = [];
  window.__sent = [];
  window.__received = [];
  window.__closed = [];
  window.WebSocket = function (url, protocols) {
    const sock = protocols === undefined ? new Native(url) : new Native(url, protocols);
    window.__sockets.push(sock);
    sock.send = function (data) {
      try { window.__sent.push(JSON.parse(data)); } catch (err) {}
      return nativeSend.call(this, data);
    };
    sock.addEventListener("close", (ev) => {
      window.__closed.push({code: ev.code, reason: ev.reason, at_ms: performance.now()});
    });
    sock.addEventListener("message", (ev) => {
      try { window.__received.push(JSON.parse(ev.data)); } catch (err) {}
    });
    return sock;
  };
  window.WebSocket.prototype = Native.prototype;
  for (const k of ["CONNECTING", "OPEN", "CLOSING", "CLOSED"]) window.WebSocket[k] = Native[k];
})();
"""


class Session:
    """The renderer's process, its console URL, the page, and what the page did."""

    def __init__(self, proc, url: str, folder: Path, log: Path, lines: list[str]):
        self.proc = proc
        self.url = url
        self.folder = folder
        self.log = log
        self.lines = lines  # the renderer's stdout
        self.started = time.monotonic()
        self.driver = None
        self.applied: list[dict] = []  # each change the page made, in order
        self.refused: list[dict] = []  # forged changes that must not be in the log
        self.chosen: dict | None = None
        self.participant = ""
        self.preferred: str | None = None
        self.control: tuple[str, int] | None = None  # the renderer's control port
        self.jnd: dict = {}  # the JND session the page ran: what was felt and answered


def _read_lines(stream, out: queue.Queue, lines: list[str]) -> None:
    for line in stream:
        lines.append(line.rstrip("\n"))
        out.put(line)
    out.put(None)


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium on a blank page, started before the renderer (as an operator's
    browser already runs: its start-up costs the loop's cores a second or two)."""
    driver = headless_chromium()
    try:
        driver.execute_cdp_cmd("Page.addScriptToEvaluateOnNewDocument", {"source": CAPTURE_SOCKETS})
        driver.get("about:blank")
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def session(browser, tmp_path_factory):
    """``evo-door render ... --console`` in its own process, in a fresh folder (the
    page's Save writes there), until the last test stops it with Ctrl-C."""
    folder = tmp_path_factory.mktemp("console")
    log = folder / "session.h5"
    command = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    command += ["--device", "sim", "--user", "swing", "--realtime"]
    command += LOADED_MACHINE_WATCHDOG  # paced beside the suite's workers and CI's jobs
    command += ["--console", "--console-port", "0", "--log", str(log)]
    # a control port of known token: the JND test reads what the renderer has in force
    command += ["--control", "127.0.0.1:0", "--token", CONTROL_TOKEN]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(
        command,
        cwd=folder,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env=env,
    )
    lines: list[str] = []
    out: queue.Queue = queue.Queue()
    threading.Thread(target=_read_lines, args=(proc.stdout, out, lines), daemon=True).start()
    url = None
    control = None
    deadline = time.monotonic() + START_TIMEOUT
    try:
        while url is None:
            try:
                line = out.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                break
            if line is None:
                break
            if line.startswith("control port "):
                host, _, port = line.split()[2].rpartition(":")
                control = (host, int(port))
            if line.startswith("console "):
                url = line.split()[1]
        if url is None:
            pytest.fail("the renderer printed no console URL:\n" + "\n".join(lines))
        s = Session(proc, url, folder, log, lines)
        s.control = control
        yield s
    finally:
        stop(proc)  # a test failed before the last one stopped it


@pytest.fixture(scope="module")
def page(browser, session):
    """The console's page in the browser, connected to the renderer."""
    browser.get(session.url)
    wait(browser, lambda d: d.find_element(By.ID, "connection").text == "connected")
    wait(browser, lambda d: all(_in_force_or_none(d, n) is not None for n in SENSATIONS))
    session.driver = browser
    return browser


# -- helpers ---------------------------------------------------------------------------
def wait(driver, condition, timeout: float = APPLY_TIMEOUT, what: str = ""):
    try:
        return WebDriverWait(driver, timeout, poll_frequency=0.05).until(condition)
    except TimeoutException:
        message = driver.find_element(By.ID, "message").text
        closed = driver.execute_script("return window.__closed;")
        raise AssertionError(
            f"timed out: {what} (#message: {message!r}; sockets closed: {closed})"
        ) from None


def _in_force_or_none(driver, name: str) -> float | None:
    value = driver.find_element(By.ID, f"slider-{name}").get_attribute("data-in-force")
    return None if value in (None, "") else float(value)


def in_force(driver, name: str) -> float:
    """The SI value the renderer applied, as the page shows it (``data-in-force``)."""
    value = _in_force_or_none(driver, name)
    assert value is not None, f"slider-{name} has no data-in-force"
    return value


def same(a: float, b: float) -> bool:
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def wait_in_force(driver, name: str, value: float) -> None:
    wait(
        driver,
        lambda d: same(in_force(d, name), value),
        what=f"{name} in force {value!r} (now {in_force(driver, name)!r})",
    )


def set_slider(driver, name: str, value: float) -> float:
    """Move a slider to ``value`` as a drag does (input events, then change on release);
    returns the value the slider took."""
    return float(
        driver.execute_script(
            "const s = document.getElementById(arguments[0]);"
            "s.value = String(arguments[1]);"
            "s.dispatchEvent(new Event('input', {bubbles: true}));"
            "s.dispatchEvent(new Event('change', {bubbles: true}));"
            "return s.value;",
            f"slider-{name}",
            value,
        )
    )


def press(driver, key: str) -> None:
    """A key on the page (not in a text field)."""
    driver.execute_script("if (document.activeElement) document.activeElement.blur();")
    driver.find_element(By.TAG_NAME, "body").send_keys(key)


def received(driver, kind: str) -> list[dict]:
    return driver.execute_script(
        "return window.__received.filter((m) => m.type === arguments[0]);", kind
    )


def sent(driver, kind: str) -> list[dict]:
    """What the page itself sent (not the forged messages)."""
    return driver.execute_script(
        "return window.__sent.filter((m) => m.type === arguments[0]);", kind
    )


def forge(driver, text: str) -> None:
    """Send raw text on the page's own (open) WebSocket, as a hostile script could."""
    driver.execute_script(
        "const open = window.__sockets.filter((s) => s.readyState === 1);"
        "WebSocket.prototype.send.call(open[open.length - 1], arguments[0]);",
        text,
    )


def click(driver, element_id: str) -> None:
    driver.find_element(By.ID, element_id).click()


def accept_confirmation(driver) -> None:
    """Accept the page's confirmation: a window.confirm, or its own dialog."""
    try:
        driver.switch_to.alert.accept()
        return
    except NoAlertPresentException:
        pass
    wait(driver, lambda d: d.find_element(By.ID, "choose-confirm").is_displayed(), 5.0)
    click(driver, "choose-confirm")


def change(session, name: str, value: float) -> None:
    """A change the page made; the log must hold it."""
    session.applied.append({name: value})


# -- the page ----------------------------------------------------------------------------
def test_page_connects_and_shows_the_loop_health_and_the_declaration(session, page):
    assert page.find_element(By.ID, "connection").text == "connected"
    wait(page, lambda d: "2500" in d.find_element(By.ID, "health").text, what="rate in #health")
    health = page.find_element(By.ID, "health").text
    assert "Hz" in health and "%" in health, health
    assert "running" in health, health
    # the loop's health came with the hello, and the status is the loop's own, not a
    # stale one ("running (no data)")
    hello = received(page, "hello")[0]
    assert hello["health"]["status"] == "running", hello.get("health")
    assert page.find_element(By.ID, "h-status").text == "running"
    # a slider per sensation, with the declared bounds, at the set in force
    start = get_model("haptic").load_params("seed_trial")
    for name in SENSATIONS:
        slider = page.find_element(By.ID, f"slider-{name}")
        p = PARAMS[name]
        assert float(slider.get_attribute("min")) == pytest.approx(p.lower, rel=1e-12, abs=1e-15)
        assert float(slider.get_attribute("max")) == pytest.approx(p.upper, rel=1e-12, abs=1e-15)
        assert same(in_force(page, name), start[name]), name
        assert page.find_element(By.ID, f"value-{name}").text.strip(), name


def test_screenshot_of_the_page_in_motion(session, page, tmp_path):
    # the virtual user swings the door for about 9 s: the strip chart and the
    # force-angle trace fill while it does
    time.sleep(max(0.0, 6.0 - (time.monotonic() - session.started)))

    def swing(driver):  # degrees the ticks' rows cover (none yet: 0)
        thetas = [row[1] for m in received(driver, "tick") for row in m.get("rows", [])]
        return math.degrees(max(thetas) - min(thetas)) if thetas else 0.0

    # a fresh clone compiles the kernels first (numba's cache is empty): rows come later
    wait(page, lambda d: swing(d) > 20.0, timeout=60.0, what="the door swinging in the ticks")
    png = page.get_screenshot_as_png()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    write = os.environ.get("EVO_DOOR_WRITE_FIGURES") == "1"
    path = ROOT / "docs" / "figures" / "console.png" if write else tmp_path / "console.png"
    from evo_door.files import atomic_write

    with atomic_write(path) as tmp:
        tmp.write_bytes(png)
    # the ticks carry the door's motion: the swing covers tens of degrees
    assert swing(page) > 20.0


def test_moving_a_slider_changes_the_renderers_set(session, page):
    name = "friction_closing"  # N, 0 .. 100, step 5
    assert same(in_force(page, name), 1.5)
    assert set_slider(page, name, 10.0) == 10.0
    wait_in_force(page, name, 10.0)
    change(session, name, 10.0)
    assert page.find_element(By.ID, f"value-{name}").text.replace(" ", "") == "10N"


def test_a_parameter_key_steps_it_by_its_step(session, page):
    name = "friction_opening"  # N, step 5: keys c (down) and C (up)
    before = in_force(page, name)
    press(page, UP_KEY[name])
    wait_in_force(page, name, before + STEP[name])
    change(session, name, before + STEP[name])
    press(page, DOWN_KEY[name])
    wait_in_force(page, name, before)
    change(session, name, before)


def test_the_page_cannot_set_a_value_outside_the_declaration(session, page):
    # the slider stops at its bound: friction_scale_3 already sits on its upper bound 1,
    # and neither the slider nor its up key sends anything
    name = "friction_scale_3"
    assert same(in_force(page, name), 1.0)
    assert set_slider(page, name, 5.0) == 1.0
    press(page, UP_KEY[name])
    press(page, DOWN_KEY["inertia"])  # a key that does send, after the one that must not
    wait_in_force(page, "inertia", 1.2 - STEP["inertia"])
    change(session, "inertia", 1.2 - STEP["inertia"])
    assert not [m for m in sent(page, "set") if name in m["values"]]
    # a hostile script on the page's socket: the server refuses and nothing changes
    name = "friction_closing"
    before = in_force(page, name)
    forged = {"type": "set", "values": {name: 1000.0}, "source": "slider"}
    forge(page, json.dumps(forged))
    wait(page, lambda d: received(d, "refused"), what="refused")
    refusal = received(page, "refused")[-1]
    assert refusal["values"] == {name: 1000.0}
    assert "1000" in refusal["error"] and "100" in refusal["error"], refusal
    wait(page, lambda d: "Refused" in d.find_element(By.ID, "message").text, what="alert")
    alert = page.find_element(By.ID, "message")
    assert alert.get_attribute("role") == "alert" and name in alert.text
    session.refused.append({name: 1000.0})
    # not a number, infinity, a name the declaration does not have, a device parameter
    for text in (
        '{"type": "set", "values": {"friction_closing": NaN}}',
        '{"type": "set", "values": {"friction_closing": 1e999}}',
        '{"type": "set", "values": {"friction_closing": "5"}}',
        '{"type": "set", "values": {"bogus": 1.0}}',
        '{"type": "set", "values": {"k_radial": 1e5}}',
    ):
        n = len(received(page, "refused")) + len(received(page, "error"))
        forge(page, text)
        wait(
            page,
            lambda d, n=n: len(received(d, "refused")) + len(received(d, "error")) > n,
            what=f"refusal of {text}",
        )
    time.sleep(0.5)  # two params polls of the console (4 Hz)
    assert same(in_force(page, name), before)


def test_ab_store_feel_prefer_and_choose(session, page):
    damping = "viscous_damping"  # N s/rad, 0 .. 100, step 5
    a_value = in_force(page, damping)
    click(page, "store-a")
    wait(page, lambda d: any(m.get("A") for m in received(d, "ab")), what="A stored")
    assert set_slider(page, damping, 5.0) == 5.0
    wait_in_force(page, damping, 5.0)
    change(session, damping, 5.0)
    click(page, "store-b")
    wait(page, lambda d: any(m.get("B") for m in received(d, "ab")), what="B stored")
    click(page, "feel-a")
    wait_in_force(page, damping, a_value)
    change(session, damping, a_value)
    assert same(in_force(page, "friction_closing"), 10.0)  # A holds the earlier changes
    # blind: the participant sees 1 and 2, not which set is A
    click(page, "blind")
    wait(page, lambda d: "1" in d.find_element(By.ID, "feel-a").text, what="blind labels")
    assert "A" not in page.find_element(By.ID, "feel-a").text.replace("Feel", "")
    click(page, "feel-b")
    wait_in_force(page, damping, 5.0)
    change(session, damping, 5.0)
    click(page, "prefer-b")
    session.preferred = "B"
    click(page, "blind")
    wait(page, lambda d: "A" in d.find_element(By.ID, "feel-a").text, what="labels back")
    # the participant, then the final choice (confirmed)
    field = page.find_element(By.ID, "participant")
    field.clear()
    field.send_keys("P07\n")
    session.participant = "P07"
    click(page, "choose")
    accept_confirmation(page)
    wait(page, lambda d: received(d, "chosen"), what="chosen")
    session.chosen = {name: in_force(page, name) for name in SENSATIONS}
    assert session.chosen[damping] == 5.0


def test_save_writes_the_set_in_force(session, page):
    field = page.find_element(By.ID, "save-name")
    field.clear()
    field.send_keys("../browser choice")  # a hostile stem stays in the console's folder
    click(page, "save")
    wait(page, lambda d: received(d, "saved"), what="saved")
    path = Path(received(page, "saved")[-1]["path"])
    assert path.parent.resolve() == session.folder.resolve() and path.suffix == ".yaml"
    saved = get_model("haptic").load_params(str(path))
    for name in SENSATIONS:
        assert same(saved[name], in_force(page, name)), name


def test_every_value_the_page_sent_is_within_the_declaration(session, page):
    # and the page kept its one socket all along (a drop would have lost clicks)
    assert page.execute_script("return window.__closed;") == []
    assert page.execute_script("return window.__sockets.length;") == 1
    changes = sent(page, "set")
    assert len(changes) >= 4
    for message in changes:
        assert message["source"] in ("slider", "key"), message
        for name, value in message["values"].items():
            p = PARAMS[name]
            assert p.group == GROUP and math.isfinite(value), message
            assert p.lower <= value <= p.upper, message


# -- a JND session -----------------------------------------------------------------------
JND_PARAM = "friction_closing"  # N: 10 N in force since the slider test
JND_TRIALS = 12  # enough for a fit and a track; each trial is about 1 s
JND_WEBER = 0.15  # the simulated participant's


class _Felt:
    """What the participant felt: the parameter's values in interval 1 and 2."""

    def __init__(self, values):
        self.values = values


def _in_force_on_renderer(session, name: str) -> float:
    """The value the renderer has in force now, asked on its control port."""
    from evo_door.render.control import request

    host, port = session.control
    answer = request(host, port, {"token": CONTROL_TOKEN, "get": "params"})
    assert answer.get("ok"), answer
    return float(answer["params"][name])


def _jnd_phase(driver) -> tuple[str, int]:
    phase, trial = driver.execute_script(
        "const j = window.evoConsole.jnd;"
        "return j ? [document.getElementById('jnd-phase').dataset.phase || '', j.trial]"
        " : ['', -1];"
    )
    return phase, int(trial)


def _wait_phase(driver, phase: str, trial: int) -> None:
    wait(
        driver,
        lambda d: _jnd_phase(d) == (phase, trial),
        what=f"JND phase {phase!r} of trial {trial} (now {_jnd_phase(driver)})",
    )


def _wait_told(driver, phase: str, trial: int) -> None:
    """Until the page was told that ``phase`` of ``trial`` began (its record of what it
    received: a poll of the display may miss an interval of 0.25 s on a loaded machine)."""
    wait(
        driver,
        lambda d: (
            {"phase": phase, "trial": trial}
            in [{"phase": m["phase"], "trial": m["trial"]} for m in received(d, "jnd_phase")]
        ),
        what=f"JND phase {phase!r} of trial {trial} (now {_jnd_phase(driver)})",
    )


def _felt_in_log(s: dict, name: str) -> list[tuple[float, float]]:
    """Each JND trial's two values of ``name`` as the renderer's log has them in force:
    the set in force when the trial's event came, then the changes until its answer
    (the console sends only what differs: interval 1 may need no change)."""
    sets = s["sets"]
    events = s["events"]
    trials = [e["t"] for e in events if e["kind"] == "jnd_trial"]
    answers = [e["t"] for e in events if e["kind"] == "jnd_answer"]
    felt = []
    for start, end in zip(trials, answers, strict=True):
        before = [values[name] for t, values in sets if t <= start][-1]
        during = [values[name] for t, values in sets if start < t <= end]
        felt.append(tuple([before, *during][-2:]))
    return felt


def test_a_jnd_session_answered_through_the_page(session, page, tmp_path):
    """The operator starts a blind JND session from the page; a simulated participant
    answers each trial from the values the renderer had in force in interval 1 and 2
    (its control port), by the page's buttons and by keys 1 and 2. Interval 2's value
    stays in force until the answer; interval 1's is read when the page was told of it,
    which on a loaded machine may be after it: the log test checks both intervals of every
    trial from the renderer's own log."""
    from evo_door.perception.jnd_file import read_jnd_file
    from evo_door.perception.procedures import SimParticipant

    assert session.control is not None, "the renderer printed no control port"
    reference = in_force(page, JND_PARAM)
    assert _in_force_on_renderer(session, JND_PARAM) == reference
    select = page.find_element(By.ID, "jnd-param")
    options = [o.get_attribute("value") for o in select.find_elements(By.TAG_NAME, "option")]
    assert JND_PARAM in options and "viscous_damping" in options and "return_angle" not in options
    page.execute_script(
        "document.getElementById('jnd-param').value = arguments[0];"
        "document.getElementById('jnd-param').dispatchEvent(new Event('change'));",
        JND_PARAM,
    )
    assert page.find_element(By.ID, "jnd-unit").text == "N"
    for element_id, value in (
        ("jnd-trials", str(JND_TRIALS)),
        ("jnd-seed", "11"),
        ("jnd-interval", "0.25"),
        ("jnd-pause", "0.1"),
    ):
        field = page.find_element(By.ID, element_id)
        field.clear()
        field.send_keys(value)
    assert page.find_element(By.ID, "jnd-blind").is_selected()  # blind by default
    started = time.monotonic()
    click(page, "jnd-start")
    wait(page, lambda d: d.find_element(By.ID, "jnd-view").is_displayed(), what="JND view")
    assert page.find_element(By.ID, "jnd-question").text == "Which felt stronger?"
    participant = SimParticipant(JND_WEBER, seed=5)
    felt, answers, blind_track = [], [], []
    for k in range(JND_TRIALS):
        _wait_told(page, "1", k)
        v1 = _in_force_on_renderer(session, JND_PARAM)
        _wait_phase(page, "answer", k)  # shown until the answer, as interval 2's value
        v2 = _in_force_on_renderer(session, JND_PARAM)
        # blind: the page shows the reference, and the track only the answers so far
        assert in_force(page, JND_PARAM) == reference
        marks = page.find_elements(By.CSS_SELECTOR, "#jnd-track circle.mark")
        blind_track.append([m.get_attribute("data-step") for m in marks])
        answer = participant.answer(_Felt((v1, v2)))
        if k % 2:
            press(page, str(answer))
        else:
            click(page, f"jnd-answer-{answer}")
        felt.append((v1, v2))
        answers.append(answer)
    wait(page, lambda d: "Weber fraction" in d.find_element(By.ID, "jnd-result").text, 20.0, "fit")
    wall = time.monotonic() - started
    # blind until the end: no step on the page, nor in what the page was sent
    assert [len(t) for t in blind_track] == list(range(JND_TRIALS))
    assert all(step is None for t in blind_track for step in t)
    running = [
        m
        for m in received(page, "jnd") + received(page, "jnd_phase")
        if m.get("status", "running") == "running"
    ]
    assert running and all("step" not in m and "order" not in m for m in running)
    assert all(m.get("fit") is None for m in running if m["type"] == "jnd")
    assert all(set(t) == {"answer"} for m in running for t in m.get("track", []))
    assert all(m["params"][JND_PARAM] == reference for m in received(page, "params")[-10:])
    # the end: one mark per trial with its step, the fitted function, the estimate
    wait(page, lambda d: d.find_element(By.ID, "jnd-result").text.count("saved to"), 10.0, "file")
    marks = page.find_elements(By.CSS_SELECTOR, "#jnd-track circle.mark")
    assert len(marks) == JND_TRIALS
    assert all(float(m.get_attribute("data-step")) > 0 for m in marks)
    assert [int(m.get_attribute("data-answer")) for m in marks] == answers
    curve = page.find_element(By.ID, "jnd-fit-curve").get_attribute("d")
    assert curve.startswith("M") and curve.count("L") >= 50
    result = page.find_element(By.ID, "jnd-result").text
    assert "Weber fraction" in result and " N at " in result and "95 % interval" in result
    (end,) = [m for m in received(page, "jnd") if m["status"] == "complete"]
    fit = end["fit"]
    assert fit["trials"] == JND_TRIALS and fit["ci95"][0] <= fit["weber"] <= fit["ci95"][1]
    # the page was told every phase of every trial, in order
    told = [(m["trial"], m["phase"]) for m in received(page, "jnd_phase")]
    trial_phases = ["pause", "1", "pause", "2", "answer"]
    assert told == [(k, p) for k in range(JND_TRIALS) for p in trial_phases] + [
        (JND_TRIALS, "fitting")
    ], told
    # interval 2's value, in force at the answer, as the track's order and step say
    for (_, v2), t in zip(felt, end["track"], strict=True):
        stronger = reference * (1 + t["step"])
        assert v2 == pytest.approx(reference if t["order"] == 1 else stronger, rel=1e-9)
    # the file, beside the console's saves; the set in force back
    path = Path(end["path"])
    assert path.parent.resolve() == session.folder.resolve() and path.suffix == ".h5"
    record = read_jnd_file(path)
    assert record.complete and record.trials["answer"].tolist() == answers
    assert record.participant == "P07" and "numpy" in record.attrs["versions"]
    png = page.get_screenshot_as_png()
    write = os.environ.get("EVO_DOOR_WRITE_FIGURES") == "1"
    shot = ROOT / "docs" / "figures" / "console-jnd.png" if write else tmp_path / "jnd.png"
    from evo_door.files import atomic_write

    with atomic_write(shot) as tmp:
        tmp.write_bytes(png)
    wait_in_force(page, JND_PARAM, reference)
    assert _in_force_on_renderer(session, JND_PARAM) == reference
    click(page, "jnd-close")
    assert not page.find_element(By.ID, "jnd-view").is_displayed()
    session.jnd = {"felt": felt, "answers": answers, "track": end["track"], "wall_s": wall}
    assert wall < 60.0, f"the session took {wall:.1f} s"


# -- the log -----------------------------------------------------------------------------
def test_the_log_holds_each_change_between_two_cycles_and_the_choice(session, capsys):
    if session.driver is None:  # run alone: no page, nothing to check
        pytest.skip("the page did not open (see the tests above)")
    proc = session.proc
    proc.send_signal(signal.SIGINT)  # the operator's Ctrl-C: the render ends, log written
    assert proc.wait(60) == 0, "\n".join(session.lines)
    assert session.log.is_file() and not Path(str(session.log) + ".partial").exists()
    s = read_session(session.log)
    changes, sets = s["changes"], s["sets"]
    # every change came into force between two cycles, at the start of one, and the
    # parameter-set table has one row per change, at its time
    assert len(sets) == len(changes) + 1 and sets[0][0] == 0.0
    for change_, (t, values) in zip(changes, sets[1:], strict=True):
        cycle = change_["t"] / PERIOD
        assert abs(cycle - round(cycle)) < 1e-6, change_["t"]
        assert t == change_["t"]
        for name, value in change_["values"].items():
            assert same(values[name], value), (name, values[name], value)
    # each change made from the page is there, in order (undo/A-B push whole sets)
    i = 0
    for wanted in session.applied:
        while i < len(changes) and not all(
            name in changes[i]["values"] and same(changes[i]["values"][name], value)
            for name, value in wanted.items()
        ):
            i += 1
        assert i < len(changes), f"{wanted} not in the log's changes {changes}"
        i += 1
    # nothing refused reached the renderer, nothing left the declaration
    for t, values in sets:
        for name in SENSATIONS:
            p = PARAMS[name]
            assert p.lower <= values[name] <= p.upper, (t, name, values[name])
    assert session.refused and all(
        not same(values[name], value)
        for forged in session.refused
        for name, value in forged.items()
        for _, values in sets
    )
    # the session record: participant, A/B preference, the chosen set
    assert s["participant"] == session.participant == "P07"
    assert [c["slot"] for c in s["choices"]] == [session.preferred]
    assert s["chosen"] is not None and s["chosen_t"] > 0
    for name, value in session.chosen.items():
        assert same(s["chosen"][name], value), name
    kinds = {e["kind"] for e in s["events"]}
    assert {"participant", "ab_store", "ab_switch", "ab_choice", "chosen", "save"} <= kinds
    # the loop ran until the operator stopped it, without its watchdog
    assert s["statistics"]["status"] == "stopped", s["statistics"]
    assert s["stopped"] == "stopped by the operator"
    # evo-door show summarises it
    capsys.readouterr()
    assert main(["show", str(session.log)]) == 0
    text = capsys.readouterr().out
    assert "participant P07" in text and "1 A/B choices" in text, text
    assert f"{len(changes)} parameter changes" in text, text
    assert "chosen at" in text and "viscous_damping" in text and "friction_closing" in text, text


def test_the_log_holds_every_jnd_presentation_and_answer(session):
    if not session.jnd or session.proc.poll() is None:
        pytest.skip("the JND session or the log test did not run")
    s = read_session(session.log)
    events = s["events"]
    rendered = _felt_in_log(s, JND_PARAM)
    (start,) = [e for e in events if e["kind"] == "jnd_start"]
    reference = start["reference"]
    assert start["param"] == JND_PARAM and start["blind"] is True and start["trials"] == JND_TRIALS
    assert (start["interval_s"], start["pause_s"], start["seed"]) == (0.25, 0.1, 11)
    trials = [e for e in events if e["kind"] == "jnd_trial"]
    answers = [e for e in events if e["kind"] == "jnd_answer"]
    assert len(trials) == len(answers) == JND_TRIALS
    for k, (shown, answered, felt, track) in enumerate(
        zip(trials, answers, session.jnd["felt"], session.jnd["track"], strict=True)
    ):
        assert shown["trial"] == answered["trial"] == k and shown["t"] < answered["t"]
        assert felt[1] == rendered[k][1]  # interval 2's, read at the answer
        # the rendered values: one the reference, the other the track's step above it,
        # in the track's order, as the console said it would show them
        v1, v2 = rendered[k]
        assert v1 != v2 and reference in (v1, v2), rendered[k]
        assert track["order"] == (1 if v1 > v2 else 2)
        assert max(v1, v2) == pytest.approx(reference * (1 + track["step"]), rel=1e-9)
        assert tuple(shown["values"]) == rendered[k]
        assert (answered["order"], answered["step"]) == (track["order"], track["step"])
        assert answered["answer"] == session.jnd["answers"][k]
        assert answered["correct"] == (answered["answer"] == answered["order"])
    (end,) = [e for e in events if e["kind"] == "jnd_end"]
    assert end["status"] == "complete" and end["answers"] == JND_TRIALS
    (saved,) = [e for e in events if e["kind"] == "jnd_save"]
    assert Path(saved["path"]).is_file()
    order = [e["kind"] for e in events if e["kind"].startswith("jnd_")]
    assert order[0] == "jnd_start" and order[-2:] == ["jnd_end", "jnd_save"]
    # evo-door show says it
    text = format_session(read_session(session.log))
    assert f"JND session on {JND_PARAM} complete, {JND_TRIALS} answers, Weber fraction" in text
