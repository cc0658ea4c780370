"""The recorder's log-time logic (biped_sim.recording.log_time.LogTimeQueue), without ROS: each message's log time
is the sim time of the latest /clock published before it, whatever order DDS hands the topics over in."""

import numpy as np
import pytest

from biped_sim.recording.log_time import LogTimeError, LogTimeQueue


def _step_stream(n, rng):
    """Steps k = 0..n-1 as the simulator publishes them: /clock k (source 10 k + 1, sim 1000 k), then /sim/state k
    (source 10 k + 2). Each topic is delivered in its own order (a reliable reader), the two topics interleaved
    at random, as a lagging or repairing reader can take them."""
    clocks = [("clock", k, 10 * k + 1) for k in range(n)]
    states = [("state", k, 10 * k + 2) for k in range(n)]
    out, i, j = [], 0, 0
    while i < n or j < n:
        if j >= n or (i < n and rng.random() < 0.5):
            out.append(clocks[i])
            i += 1
        else:
            out.append(states[j])
            j += 1
    return out


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_every_state_gets_its_own_clock_whatever_the_interleaving(seed):
    rng = np.random.default_rng(seed)
    q = LogTimeQueue(wait=1e9)
    got = []
    for t, (kind, k, src) in enumerate(_step_stream(300, rng)):
        q.push(float(t), (kind, k), src, 1000 * k if kind == "clock" else None)
        got += q.release(float(t))
    got += q.release(1e9, flush=True)
    assert [item for item, _ in got if item[0] == "state"] == [("state", k) for k in range(300)]
    assert all(lt == 1000 * k for (kind, k), lt in got), [g for g in got if g[1] != 1000 * g[0][1]][:5]


def test_a_state_taken_before_its_own_clock_is_held_until_it_comes():
    """The CI failure this logic exists for: /sim/state k taken while /clock k is still being repaired. Looked up at
    once (the former recorder) it got /clock k-1; held, it gets its own, and the bag keeps the order taken. A
    message is written once a /clock published after it has been taken."""
    q = LogTimeQueue(wait=5.0)
    q.push(0.0, "clock 1", 11, 1000)
    q.push(0.0, "state 1", 12)
    assert q.release(0.0) == [("clock 1", 1000)]      # state 1 waits for a /clock published after it
    q.push(0.1, "state 2", 22)          # /clock 2 (source 21) not taken yet
    assert q.release(0.1) == [] and len(q) == 2
    assert q.log_time(22) == 1000       # what an immediate lookup would have written
    q.push(0.2, "clock 2", 21, 2000)
    assert q.release(0.2) == [("state 1", 1000)]      # state 2 (source 22) is after /clock 2 too: held
    q.push(0.3, "clock 3", 31, 3000)
    assert q.release(0.3) == [("state 2", 2000), ("clock 2", 2000), ("clock 3", 3000)]
    assert len(q) == 0


def test_a_held_message_waits_at_most_wait_seconds_then_takes_the_newest_clock():
    q = LogTimeQueue(wait=5.0)
    q.push(0.0, "clock 1", 11, 1000)
    q.push(1.0, "state 1", 12)
    q.push(2.0, "last torque", 13)      # the graph's last message: no /clock after it
    assert q.release(2.0) == [("clock 1", 1000)]
    assert q.release(5.999) == []
    assert q.release(6.0) == [("state 1", 1000)]
    assert q.release(7.0) == [("last torque", 1000)]
    q.push(8.0, "at the end", 40)
    assert q.release(8.0, flush=True) == [("at the end", 1000)]


def test_a_clock_waits_behind_an_earlier_held_message_and_the_order_is_kept():
    q = LogTimeQueue(wait=5.0)
    q.push(0.0, "state 0", 2)           # before any /clock
    q.push(0.0, "clock 0", 1, 0)        # taken after it, published before it
    q.push(0.0, "state 0b", 3)
    assert q.release(0.0) == []         # state 0 (source 2) waits for a /clock published at or after it
    q.push(0.5, "clock 1", 11, 1000)
    assert q.release(0.5) == [("state 0", 0), ("clock 0", 0), ("state 0b", 0), ("clock 1", 1000)]


def test_before_any_clock_and_without_a_source_timestamp():
    q = LogTimeQueue(wait=5.0)
    q.push(0.0, "no info", 0)
    assert q.release(0.0) == [("no info", None)]    # the caller's clock
    q.push(0.0, "latched", 5)
    assert q.release(5.0) == [("latched", None)]    # waited, still no /clock
    q.push(6.0, "clock 3", 31, 3000)
    q.push(6.0, "no info 2", 0)
    assert q.release(6.0) == [("clock 3", 3000), ("no info 2", 3000)]


def test_history_is_trimmed_and_older_messages_get_the_newest_clock():
    q = LogTimeQueue(history=3, wait=0.0)
    for k in range(10):
        q.push(0.0, f"clock {k}", 10 * k + 1, 1000 * k)
    q.release(0.0)
    assert q.log_time(10 * 9 + 5) == 9000
    assert q.log_time(10 * 6 + 5) == 6000      # still kept (at most 2 x history)
    assert q.log_time(2) == 9000               # older than every /clock kept: the newest


@pytest.mark.parametrize("kwargs", [{"history": 0}, {"wait": -1.0}, {"wait": float("nan")}])
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(LogTimeError):
        LogTimeQueue(**kwargs)
