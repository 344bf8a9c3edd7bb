"""The renderer's log: rows in blocks, the side file while rendering, recovery."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
import tracemalloc

import numpy as np
import pytest

from evo_door.cli import main
from evo_door.data.io import read_trials
from evo_door.errors import UserError
from evo_door.files import open_h5, read_attrs
from evo_door.models import get_model
from evo_door.models.haptic import PARAMS
from evo_door.render.columns import COMMAND, N_COLUMNS, THETA
from evo_door.render.device import SimDevice
from evo_door.render.log import BLOCK_ROWS, RETAIN_BLOCKS, RenderLog, recover
from evo_door.render.log_file import CHUNK_ROWS, STORED
from evo_door.render.loop import ServoLoop
from evo_door.render.session import read_session, session_params
from evo_door.render.spill import SPILL_ROWS, partial_path, read_partial
from tests.helpers import LOADED_MACHINE_WATCHDOG


def _cycles(n: int, seed: int = 0):
    """Jittered cycle times around 2500 Hz, one long gap (missed cycles), a repeated
    time; random rows."""
    rng = np.random.default_rng(seed)
    dt = rng.uniform(0.0002, 0.0006, n)
    dt[n // 3] = 0.0123  # 12 ticks in one cycle: crosses small blocks
    dt[n // 2] = 0.0  # the same time twice
    t = np.cumsum(dt)
    t -= t[0]
    return t, rng.normal(size=(n, N_COLUMNS))


def _list_log(t, rows, rate):
    """The log as a plain list of rows, built one tick at a time (the reference)."""
    out = []
    k = 0
    for i, (ti, row) in enumerate(zip(t, rows)):
        while k / rate <= ti:
            if i == 0:
                out.append(row.copy())
                k += 1
                break
            span = ti - t[i - 1]
            w = (k / rate - t[i - 1]) / span if span > 0 else 1.0
            out.append(rows[i - 1] + w * (row - rows[i - 1]))
            k += 1
    return np.array(out).reshape(-1, N_COLUMNS)


@pytest.mark.parametrize("block_rows", [1, 7, 64, BLOCK_ROWS])
def test_blocks_hold_the_rows_a_plain_list_would(block_rows):
    t, rows = _cycles(3000)
    log = RenderLog(1000.0, block_rows=block_rows)
    for ti, row in zip(t, rows):
        log.add(ti, row)
    a = log.array()
    ref = _list_log(t, rows, 1000.0)
    assert log.n == a.shape[0] == ref.shape[0] == int(np.floor(t[-1] * 1000.0)) + 1
    np.testing.assert_array_equal(a, ref)
    # and against numpy's interpolation, away from the repeated time
    ticks = np.arange(log.n) / 1000.0
    h = len(t) // 2
    away = (ticks <= t[h - 2]) | (ticks > t[h + 1])
    keep = np.r_[: h - 1, h + 1 : len(t)]
    for j in (0, 7, 14):
        ref_j = np.interp(ticks[away], t[keep], rows[keep, j])
        np.testing.assert_allclose(a[away, j], ref_j, rtol=0, atol=1e-12)
    assert away.sum() >= log.n - 2
    np.testing.assert_array_equal(log.last(), ref[-1])
    np.testing.assert_array_equal(log.rows(5, 40), ref[5:40])


def test_add_allocates_nothing_per_row_in_a_block():
    log = RenderLog(1000.0)
    row = np.ones(N_COLUMNS)
    for k in range(100):
        log.add(k * 0.0004, row)
    tracemalloc.start()
    try:
        before, _ = tracemalloc.get_traced_memory()
        for k in range(100, 3100):  # 1200 rows, within the first block
            log.add(k * 0.0004, row)
        after, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert log.n == 1240 < BLOCK_ROWS
    assert after - before < 2000  # bytes; a list of row arrays takes > 200 000


@pytest.mark.slow
def test_sixty_seconds_of_render_hold_under_ten_megabytes(seed_trial):
    loop = ServoLoop(SimDevice("open", radius=seed_trial["radius"]), seed_trial, 2500.0)
    loop.run(60.0)
    log = loop.log
    assert log.n == 60000
    held = sum(b.nbytes for b in log._blocks)
    assert len(log._blocks) == -(-60000 // BLOCK_ROWS)
    assert 60000 * N_COLUMNS * 8 <= held < 10e6
    assert np.isfinite(log.array()).all()


def _wait_for_size(path, size, timeout=10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if path.exists() and path.stat().st_size >= size:
            return path.stat().st_size
        time.sleep(0.01)
    raise AssertionError(f"{path} did not reach {size} bytes")


def test_the_side_file_grows_and_recovers_the_rows_exactly(tmp_path):
    out = tmp_path / "l.h5"
    log = RenderLog(1000.0, PARAMS)
    vector = np.linspace(1.0, 2.0, len(PARAMS))
    log.params(0.0, vector)
    log.event(0.0, "friction", "a note", values={"k": 1.5})
    side = log.spill_to(out, loop_rate=2500.0, device="sim")
    assert side == partial_path(out) == tmp_path / "l.h5.partial"
    head = side.stat().st_size
    rng = np.random.default_rng(1)
    sizes = []
    k = 0
    for target in (1, 2, 3):
        while log.n < target * BLOCK_ROWS:
            log.add(k * 0.0004, rng.normal(size=N_COLUMNS))
            k += 1
        if target == 2:
            log.params(k * 0.0004, 2 * vector)
        sizes.append(_wait_for_size(side, head + target * BLOCK_ROWS * N_COLUMNS * 8))
    assert sizes[0] < sizes[1] < sizes[2]
    n_spilled = 3 * BLOCK_ROWS
    # not closed: as a crash leaves it
    _, rows, events, times, sets = read_partial(side)
    a = log.array()[:n_spilled]  # read back from the side file where memory freed it
    np.testing.assert_array_equal(rows, a)
    assert [e["kind"] for e in events] == ["friction"] and times[0] == 0.0
    recovered = tmp_path / "r.h5"
    assert recover(side, recovered) == recovered
    assert not side.exists()
    (tr,) = read_trials(recovered)
    assert tr.n == n_spilled and tr.rate == pytest.approx(1000.0)
    np.testing.assert_array_equal(tr.theta, a[:, THETA].astype(np.float32))
    with open_h5(recovered) as f:
        np.testing.assert_array_equal(
            f["render/command"][()], a[:, COMMAND : COMMAND + 3].astype(np.float32)
        )
        attrs = read_attrs(f["render"])
        assert attrs["statistics"] == {"recovered": True}
        assert attrs["rate"] == 2500.0 and attrs["device"] == "sim"
        assert attrs["events"][-1]["kind"] == "recovered"
        assert "without a clean stop" in attrs["events"][-1]["message"]
        np.testing.assert_array_equal(f["render/params/values"][()], [vector, 2 * vector])
        assert list(read_attrs(f["render/params"])["names"]) == list(PARAMS.names)
    log.close()
    log.close()  # idempotent


def test_write_removes_the_side_file_and_a_left_one_is_refused(tmp_path):
    out = tmp_path / "l.h5"
    log = RenderLog(1000.0, PARAMS)
    log.params(0.0, np.ones(len(PARAMS)))
    side = log.spill_to(out)
    for k in range(5000):
        log.add(k * 0.0004, np.full(N_COLUMNS, float(k)))
    log.write(out, loop_rate=2500.0, device="sim", statistics={})
    assert not side.exists()
    (tr,) = read_trials(out)
    assert tr.n == log.n == 2000
    side.write_bytes(b"left by a crash")
    with pytest.raises(UserError, match=r"l\.h5\.partial: .*did not end cleanly"):
        RenderLog(1000.0).spill_to(out)
    with pytest.raises(UserError, match="not the side file of a render log"):
        recover(side)


def test_a_side_file_cut_mid_record_recovers_the_whole_records(tmp_path):
    out = tmp_path / "l.h5"
    log = RenderLog(1000.0, PARAMS)
    log.params(0.0, np.ones(len(PARAMS)))
    side = log.spill_to(out)
    for k in range(int(2.5 * SPILL_ROWS * 2.5)):
        log.add(k * 0.0004, np.full(N_COLUMNS, float(k)))
    log.close()
    data = side.read_bytes()
    side.write_bytes(data[:-100])  # the last record cut short
    _, rows, *_ = read_partial(side)
    assert rows.shape[0] == 2 * SPILL_ROWS
    np.testing.assert_array_equal(rows, log.array()[: 2 * SPILL_ROWS])
    assert recover(side) == out and read_trials(out)[0].n == 2 * SPILL_ROWS


class _FailingDevice(SimDevice):
    """A simulated device whose read (or step) raises after ``after`` cycles."""

    def __init__(self, *args, after: int, error: BaseException, where: str, **kw):
        super().__init__(*args, **kw)
        self.after, self.error, self.where, self.count = after, error, where, 0

    def read(self):
        self.count += 1
        if self.where == "read" and self.count > self.after:
            raise self.error
        return super().read()

    def step(self, dt):
        if self.where == "step" and self.count >= self.after:
            raise self.error
        super().step(dt)


@pytest.mark.parametrize(
    "error, where", [(KeyboardInterrupt(), "read"), (RuntimeError("device on fire"), "step")]
)
def test_a_render_that_raises_still_writes_its_log(tmp_path, monkeypatch, capsys, error, where):
    import evo_door.commands.render as command

    def make(spec, user, radius, seed, damping=None):
        return _FailingDevice(user, radius=radius, after=1000, error=error, where=where), "sim"

    monkeypatch.setattr(command, "make_device", make)
    log = tmp_path / "l.h5"
    args = ["render", "--params", "seed_trial", "--user", "open", "--duration", "2"]
    if isinstance(error, KeyboardInterrupt):
        assert main([*args, "--log", str(log)]) == 130
    else:
        with pytest.raises(RuntimeError, match="device on fire"):
            main([*args, "--log", str(log)])
    err = capsys.readouterr().err
    assert f"wrote {log}" in err and type(error).__name__ in err
    assert not partial_path(log).exists()
    (tr,) = read_trials(log)
    # cycles 0..999 at 2500 Hz: ticks 0..399 at 1 kHz
    assert tr.n == 400 and np.isfinite(tr.theta).all()
    with open_h5(log) as f:
        attrs = read_attrs(f["render"])
        assert attrs["events"][-1]["kind"] == "interrupted"
        assert type(error).__name__ in attrs["statistics"]["interrupted"]
        # the loop's own statistics survive the error
        assert attrs["statistics"]["status"] == "failed"
        assert attrs["statistics"]["cycles_run"] in (999, 1000)  # the last one, cut or not
        assert f["render/position"].shape == (400, 3)


@pytest.mark.slow
def test_recover_a_render_killed_mid_run(tmp_path, capsys):
    log = tmp_path / "x.h5"
    side = partial_path(log)
    cmd = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    cmd += ["--device", "sim", "--user", "open", "--duration", "30", "--realtime"]
    cmd += LOADED_MACHINE_WATCHDOG  # paced beside the suite's workers
    proc = subprocess.Popen([*cmd, "--log", str(log)], stdout=subprocess.DEVNULL)
    try:
        # two chunks of rows (2 s at 1 kHz) on the disk, then a kill
        _wait_for_size(side, 2 * SPILL_ROWS * N_COLUMNS * 8 + 200, timeout=30.0)
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert not log.exists() and side.exists()
    out = tmp_path / "out.h5"
    assert main(["render", "--recover", str(side), "--log", str(out)]) == 0
    assert not side.exists()
    capsys.readouterr()
    assert main(["data", "show", str(out)]) == 0
    assert "render" in capsys.readouterr().out
    (tr,) = read_trials(out)
    assert tr.n >= 2 * SPILL_ROWS and tr.t[-1] >= 1.0
    assert tr.theta[0] > 1.5 and np.isfinite(tr.theta).all()


@pytest.mark.slow
@pytest.mark.parametrize(
    "how", [["--duration", "60", "--realtime"], ["--control", "0"]], ids=["duration", "open"]
)
def test_ctrl_c_stops_a_render_alike_with_or_without_duration(how, tmp_path, capsys):
    """Ctrl-C ended a render with --duration as a failure (exit 130, status failed,
    an "interrupted" log) and one without as done (exit 0): both are an operator's
    stop, exit 0, their log whole and marked so."""
    log = tmp_path / "l.h5"
    cmd = [sys.executable, "-m", "evo_door", "render", "--params", "seed_trial"]
    cmd += ["--device", "sim", "--user", "swing", *how, "--log", str(log)]
    cmd += LOADED_MACHINE_WATCHDOG  # paced beside the suite's workers
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # rendering: a chunk of rows (a second at 1 kHz) in the side file
        _wait_for_size(partial_path(log), SPILL_ROWS * N_COLUMNS * 8 + 200, timeout=60.0)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, err
    assert "(stopped by the operator)" in out and f"wrote {log}" in out and not err
    assert log.is_file() and not partial_path(log).exists()
    s = read_session(log)
    assert s["statistics"]["status"] == "stopped" and s["stopped"] == "stopped by the operator"
    with open_h5(log) as f:
        events = read_attrs(f["render"])["events"]
    assert events[-1]["kind"] == "stopped" and "interrupted" not in {e["kind"] for e in events}
    (tr,) = read_trials(log)
    assert tr.n >= SPILL_ROWS and np.isfinite(tr.theta).all()
    # every slot of the 2.5 kHz loop is either run or counted missed (a loaded machine
    # skips slots; the log resamples over them): together, the logged time at 1 kHz
    st = s["statistics"]
    assert st["cycles_run"] + st["missed_cycles"] == pytest.approx(tr.n * 2.5, abs=3)
    capsys.readouterr()
    assert main(["show", str(log)]) == 0
    assert "status stopped by the operator" in capsys.readouterr().out
    # a log is a parameter set: the one rendered
    values, _ = session_params(log)
    assert values == get_model("haptic").load_params("seed_trial").as_dict()
    assert main(["render", "--params", str(log), "--user", "hold", "--duration", "0.05"]) == 0


def test_recover_refuses_what_is_not_a_side_file(tmp_path, capsys):
    missing = tmp_path / "none.h5.partial"
    assert main(["render", "--recover", str(missing)]) == 2
    garbage = tmp_path / "g.h5.partial"
    garbage.write_text("not a render")
    assert main(["render", "--recover", str(garbage)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert "no such file" in err[0] and "not the side file" in err[1]


def _rows_of(n: int, seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=(n, N_COLUMNS)) * [1.0] * N_COLUMNS


def test_a_spilled_log_frees_its_rows_and_is_written_from_the_side_file(tmp_path):
    """The log held every row in memory (430 MB an hour at 1 kHz): once the side file
    holds a block, the block is freed but the last RETAIN_BLOCKS, and the final log is
    written from the side file. Small blocks stand for a long session."""
    out = tmp_path / "l.h5"
    log = RenderLog(1000.0, PARAMS, block_rows=64)
    log.params(0.0, np.ones(len(PARAMS)))
    side = log.spill_to(out)
    inputs = _rows_of(5000)
    ref = RenderLog(1000.0)  # the same rows, all kept in memory
    held = []
    for k, row in enumerate(inputs):
        log.add(k / 1000.0, row)
        ref.add(k / 1000.0, row)
        if k % 500 == 499:
            _wait_for_written(log, log.n - SPILL_ROWS)
        held.append(sum(b is not None for b in log._blocks))
    # at most the retained blocks, the current one, and what the writer has not synced
    assert max(held) <= RETAIN_BLOCKS + 1 + -(-2 * SPILL_ROWS // 64)
    assert log.held_from > 3000 and log.rows(0, 10).shape == (0, N_COLUMNS)
    rows = ref.array()
    np.testing.assert_array_equal(log.array(), rows)  # read back from the side file
    np.testing.assert_array_equal(log.first(), rows[0])
    np.testing.assert_array_equal(log.last(), rows[-1])
    log.write(out, loop_rate=2500.0, device="sim", statistics={})
    assert not side.exists()
    _check_stored(out, rows)


def _wait_for_written(log, n, timeout=10.0):
    deadline = time.monotonic() + timeout
    while log._spill.written < n:
        assert time.monotonic() < deadline, (log._spill.written, n)
        time.sleep(0.005)


def _check_stored(path, rows) -> None:
    """The final log's layout: time float64, every other channel float32 (the rows to
    float32's rounding), chunked, shuffled, gzip-compressed; /render/t is the trial's t."""
    with open_h5(path) as f:
        t = f["trials/render/t"]
        assert t.dtype == np.float64 and f["render/t"] == t  # one dataset, two names
        np.testing.assert_array_equal(t[()], np.arange(len(rows)) / 1000.0)
        for name, j in (("force", 14), ("theta", 12), ("dtheta", 13)):
            ds = f[f"trials/render/{name}"]
            assert ds.dtype == STORED
            np.testing.assert_array_equal(ds[()], rows[:, j].astype(STORED))
        for name, j in (("position", 0), ("velocity", 3), ("user_force", 6), ("command", 9)):
            ds = f[f"render/{name}"]
            assert ds.dtype == STORED and ds.shape == (len(rows), 3)
            np.testing.assert_array_equal(ds[()], rows[:, j : j + 3].astype(STORED))
        for ds in (t, f["trials/render/theta"], f["render/command"]):
            assert ds.compression == "gzip" and ds.shuffle
            assert ds.chunks[0] == min(len(rows), CHUNK_ROWS)
    (tr,) = read_trials(path)
    assert tr.theta.dtype == np.float64 and tr.n == len(rows)


def test_a_log_without_a_side_file_writes_the_same_layout(tmp_path):
    log = RenderLog(1000.0, PARAMS, block_rows=100)
    log.params(0.0, np.ones(len(PARAMS)))
    for k, row in enumerate(_rows_of(3000)):
        log.add(k / 1000.0, row)
    assert log.held_from == 0  # no side file: every row kept (the API's default)
    log.write(tmp_path / "l.h5", loop_rate=2500.0, device="sim", statistics={})
    _check_stored(tmp_path / "l.h5", log.array())


def test_keep_recent_holds_a_few_blocks_and_the_control_port_starts_there(seed_trial):
    """A render without --log keeps only recent rows; the control port's rows answer
    starts at the first one held, on its 100 Hz grid."""
    from evo_door.render.control import ControlServer

    loop = ServoLoop(SimDevice("swing", radius=seed_trial["radius"]), seed_trial, 2500.0)
    loop.log.block_rows = 256  # a long session in a short test
    loop.log._blocks = [np.empty((256, N_COLUMNS))]
    loop.log._block = loop.log._blocks[0]
    loop.log.keep_recent()
    loop.run(4.0)
    log = loop.log
    assert log.n == 4000 and sum(b is not None for b in log._blocks) <= RETAIN_BLOCKS + 1
    start = loop.device.script.theta_start
    assert log.first()[THETA] == pytest.approx(start, abs=1e-3)  # kept: the summary's
    server = ControlServer(loop)
    try:
        answer = server.answer(b'{"get": "rows", "since": 0}')
    finally:
        server.close()
    first = -(-log.held_from // 10) * 10
    assert answer["ok"] and answer["rows"][0][0] == pytest.approx(first / 1000.0)
    with pytest.raises(UserError, match="early rows were not kept"):
        log.write("never.h5", loop_rate=2500.0, device="sim", statistics={})


def test_a_render_without_a_log_still_summarises_the_door_from_first_to_last(capsys):
    """Without --log the render keeps only recent rows (keep_recent); its summary read
    the door's first angle from the whole array, now from the row kept for it."""
    assert main(["render", "--params", "seed_trial", "--user", "open", "--duration", "3"]) == 0
    out = capsys.readouterr().out
    first, last = map(float, re.search(r"door (\S+) -> (\S+) deg", out).groups())
    assert first > 85.0 and 15.0 < last < 25.0, out  # opened from shut to 20 deg
