"""gazelight.Source against the Pupil-Capture-like peer the Rust interop
tests use (crates/gazelight-tracker/tests/pupil_peer.py, pyzmq + msgpack,
run by the system python3 that .ci/test installs them into): states arrive
at the peer's rate with monotonic times, and no thread is left after the
`with` block."""

import os
import shutil
import subprocess
import threading
import time

import pytest

import gazelight
from conftest import ROOT, _missing

PEER = ROOT / "crates/gazelight-tracker/tests/pupil_peer.py"


def _threads() -> int:
    return len(os.listdir("/proc/self/task"))


def _threads_settled(before: int) -> int:
    """The thread count, given the runtime's threads up to 1 s to finish
    exiting: tokio's shutdown returns once each has left its loop, a
    moment before the kernel drops it from /proc/self/task."""
    end = time.monotonic() + 1.0
    while _threads() != before and time.monotonic() < end:
        time.sleep(0.01)
    return _threads()


@pytest.fixture
def peer():
    py = os.environ.get("GAZELIGHT_PEER_PYTHON") or shutil.which("python3")
    ok = py and subprocess.run([py, "-c", "import zmq, msgpack"], capture_output=True).returncode == 0
    if not ok:
        _missing(f"the Pupil peer needs python3 with pyzmq and msgpack ({py})")
    p = subprocess.Popen([py, str(PEER), "--rate", "200", "--timeout", "28"], stdout=subprocess.PIPE, text=True)
    try:
        line = p.stdout.readline()
        ports = dict(w.split("=", 1) for w in line.split() if "=" in w)
        assert "remote" in ports, f"peer said {line!r}"
        yield int(ports["remote"])
    finally:
        p.kill()
        p.wait()


def test_live_source_yields_states_at_the_peer_rate(peer):
    before = _threads()
    states = []
    with gazelight.Source(f"pupil://127.0.0.1:{peer}", timeout=15) as src:
        t_first = None
        for s in src:
            states.append(s)
            if t_first is None:
                t_first = time.monotonic()
            elif time.monotonic() - t_first >= 3.0:
                break
        elapsed = time.monotonic() - t_first
    # The runtime's threads are gone once the block is left.
    assert _threads_settled(before) == before, f"{_threads()} threads after, {before} before"
    assert threading.active_count() == 1
    assert len(states) > 1, "no states from the peer"
    rate = (len(states) - 1) / elapsed
    assert rate >= 150, f"{rate:.0f} states/s"
    t = [s.t_secs for s in states]
    assert all(b >= a for a, b in zip(t, t[1:])), "times go back"
    # A datum's pupils (2D, 3D) and gaze share its time: distinct times
    # are the peer's samples, 200 per eye per second.
    distinct = len(set(t)) / elapsed
    assert distinct >= 150, f"{distinct:.0f} distinct sample times/s"
    # The peer's simulated pupils are millimetres in the physiological range.
    assert all(1.5 <= s.pupil_mm[0] <= 9.0 for s in states)
    # The peer's resting 3D pupils (pupil_peer.py: 3.75 mm right, 4.25 mm
    # left), once the chain has settled on them.
    for e, mm in ((0, 3.75), (1, 4.25)):
        late = [s.pupil_mm[e] for s in states[len(states) // 2:] if s.pupil_origin[e] == "measured"]
        assert late and abs(sorted(late)[len(late) // 2] - mm) < 0.05, (e, late[:5])


def test_a_source_that_cannot_open_raises_and_leaves_no_thread(tmp_path):
    before = _threads()
    with pytest.raises(gazelight.GazelightError, match="source"):
        with gazelight.Source(f"replay://{tmp_path}/missing.csv"):
            pass
    assert _threads_settled(before) == before
    with pytest.raises(gazelight.GazelightError):
        gazelight.Source("nonsense://x")
