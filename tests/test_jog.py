"""Live jogging (telemanipulation) of a real-time run over the `jog` key: a joint and a Cartesian jog
move the arm while their messages come, and the deadman stops it when they stop. An idle arm is jogged
in a run until stopped (real time, no command needed), which `stop` ends as finished."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from simecs.mesh.client import RemoteError, SessionClient
from simecs.mesh.protocol import codec, frames, keys, session_commands
from simecs.mesh.protocol import messages as m
from simecs.nodes import pacing

from tests.conftest import Service, wait_until
from tests.test_commands import SPIDER_Q0, kinematics

HOLD = m.JointPath([m.PathNode(SPIDER_Q0)])  # the arm holds its initial pose: only the jog moves it
ENDED = ["finished", "failed", "aborted"]


def jog_for(s: SessionClient, run_id: str, seconds: float, **fields: object) -> float:
    """Send a jog message every 50 ms for `seconds`, as a held jog button does; returns the time from
    the first message to the last (a loaded machine's sleeps overrun: more than `seconds` at times)."""
    z = s.client.z
    key = keys.jog(s.user, s.id)
    first = time.monotonic()
    end, last = first + seconds, first
    while time.monotonic() < end:
        last = time.monotonic()
        z.put(key, codec.dumps(m.JogInput(run_id=run_id, **fields)))  # type: ignore[arg-type]
        time.sleep(0.05)
    return last - first


def running(s: SessionClient, stop_time: float) -> str:
    s.set_initial(SPIDER_Q0)
    s.set_command(HOLD)
    s.set_settings(stop_time=stop_time, output_interval=0.002, pacing="realtime")
    run_id = s.run()
    wait_until(lambda: s.snapshot().state.phase == "running", timeout=20, what="run going")
    return run_id


@pytest.mark.shares_service
def test_a_joint_jog_moves_the_joint_and_the_deadman_stops_it(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    full: list[frames.Frame] = []
    with s.watch(on_full=full.append):
        run_id = running(s, 5.0)
        time.sleep(0.3)
        s.client.z.put(
            keys.jog(s.user, s.id), codec.dumps(m.JogInput(run_id="r99", qd=[0.2] + [0.0] * 6))
        )  # not ours
        held = jog_for(s, run_id, 1.0, qd=[0.2] + [0.0] * 6)
        released = time.monotonic()
        assert s.wait_for(["finished", "failed"], 30, run_id).phase == "finished"
        wait_until(lambda: full and full[-1].final, timeout=10, what="the final frame")
    # Jogged, the run simulates 5 ms frames (a jog shows within one), from its first jog message until
    # JOG_MODE_S after the last; before and after, 25 ms ones (2 ms samples: 2-3 rows, and 12-13).
    # (The run's last call may be short: frames up to 0.1 s before its end are looked at.)
    sizes = [f.rows.shape[0] for f in full if f.rows.shape[0] and f.rows[-1, 0] < 5.0 - 0.1]
    small = [k for k, n in enumerate(sizes) if n <= 3]
    assert small and small == list(range(small[0], small[-1] + 1)), sizes
    assert min(sizes[1 : small[0]]) >= 12 and min(sizes[small[-1] + 1 :]) >= 12, sizes
    # it lasted the jog and JOG_MODE_S after it (simulated time in it; its end: the 25 ms frames above)
    assert 0.005 * len(small) > 0.8 * (held + pacing.JOG_MODE_S), sizes
    _, rows = s.results(run_id, ["joint1.q_ref", "joint1.q", "joint2.q"])
    t, ref, q = rows[:, 0], rows[:, 1], rows[:, 2]
    moved = ref[-1] - SPIDER_Q0[0]
    # The worker reads the held velocity before each solver call (50 ms at real time, 5 ms once
    # jogged): the jog starts at the call after the first message and goes on until the call after
    # the deadman ran out past the last one.
    most = 0.2 * (held + m.JOG_DEADMAN_S + 2 * 0.05)
    assert 0.12 < moved < most, f"joint1 jogged {moved:.3f} rad, messages over {held:.3f} s at 0.2 rad/s"
    assert abs(q[-1] - ref[-1]) < 5e-3 and np.allclose(rows[:, 3], SPIDER_Q0[1], atol=2e-3)
    # The set point moved at 0.2 rad/s while jogged, then stood still: the deadman stopped it.
    slope = np.diff(ref) / np.diff(t)
    assert slope.max() < 0.2 + 1e-6
    still = t > t[np.nonzero(slope > 0.1)[0][-1]] + 0.05
    assert np.ptp(ref[still]) < 1e-9 and still.sum() > 100
    assert time.monotonic() - released < 30


@pytest.mark.shares_service
def test_a_cartesian_jog_moves_the_tool_along_its_axis(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    run_id = running(s, 2.5)
    time.sleep(0.2)
    jog_for(s, run_id, 1.0, space="cartesian", twist=[0.0, 0.0, -0.05, 0.0, 0.0, 0.0])
    jog_for(s, run_id, 0.2, qd=[0.1] * 3)  # a bad message: stops the jog, and the user is told
    assert s.wait_for(["finished", "failed"], 30, run_id).phase == "finished"
    _, rows = s.results(run_id, ["pose.tool.x", "pose.tool.y", "pose.tool.z"])
    p0, _ = kinematics("spider").tool_pose(np.array(SPIDER_Q0))
    moved = rows[-1, 1:] - p0
    assert -0.065 < moved[2] < -0.03, f"tool moved {moved} for 1 s at -0.05 m/s in z"
    assert np.hypot(moved[0], moved[1]) < 0.1 * abs(moved[2])
    warnings = wait_until(lambda: s.snapshot().state.warnings, timeout=10, what="a notice")
    assert any("qd has 3 values for a 7-joint arm" in w for w in warnings), warnings


@pytest.mark.shares_service
def test_jog_messages_to_a_run_paced_as_fast_as_possible_change_nothing(service: Service) -> None:
    """Jog messages to a run paced as fast as possible change nothing (jogging is real-time only)."""
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    s.set_command(HOLD)
    s.set_settings(stop_time=2.0, output_interval=0.002, pacing="fast")
    run_id = s.run()
    stop = threading.Event()

    def spam() -> None:
        while not stop.is_set():
            s.client.z.put(keys.jog(s.user, s.id), codec.dumps(m.JogInput(run_id=run_id, qd=[0.5] * 7)))
            time.sleep(0.01)

    thread = threading.Thread(target=spam)
    thread.start()
    try:
        assert s.wait_for(["finished", "failed"], 30, run_id).phase == "finished"
    finally:
        stop.set()
        thread.join()
    att, rows = s.results_of(run_id, ["joint1.q_ref"])
    assert np.allclose(rows[:, 1], rows[0, 1])
    assert att.run.jogged_s == 0.0 and next(r for r in s.runs() if r.run_id == run_id).jogged_s == 0.0


def sim_time_past(s: SessionClient, t: float, what: str) -> m.SessionState:
    """The session's state once its run has simulated past `t` s (still running)."""

    def past() -> m.SessionState | None:
        state = s.snapshot().state
        assert state.phase in ("queued", "running"), state
        return state if state.phase == "running" and state.sim_time > t else None

    return wait_until(past, timeout=60, what=what)


@pytest.mark.shares_service
def test_an_idle_arm_is_jogged_in_a_run_until_stopped_and_stop_finishes_it(service: Service) -> None:
    """No command, settings that say fast and 0.2 s: the run goes on in real time, holding the pose,
    until `stop`; a jog of joint 2 moves it at the jog's speed and the pose then holds."""
    s = service.client.create_session("ann", "spider")
    s.set_initial(SPIDER_Q0)
    s.set_settings(stop_time=0.2, output_interval=0.002, pacing="fast")
    with pytest.raises(RemoteError) as err:  # a timed run still needs a command
        s.run()
    assert err.value.code == "bad_request" and err.value.field == "command"
    with pytest.raises(RemoteError) as err:
        s.stop()
    assert err.value.code == "conflict" and err.value.error.message == session_commands.refusal(
        "stop", "configured"
    )

    full: list[frames.Frame] = []
    layouts: list[m.RunLayout] = []
    with s.watch(on_full=full.append, on_layout=layouts.append):
        run_id = s.run(until_stopped=True)
        sim_time_past(s, 0.3, "the run under way")
        jog_for(s, run_id, 0.5, qd=[0.0, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0])
        jogged = s.snapshot().state.sim_time
        # past its settings' stop_time, and held for a while after the jog (deadman 0.25 s)
        before = sim_time_past(s, max(jogged + 0.8, 1.2), "the run going on after the jog")
        assert before.rtf < 1.5, before  # real time (fast runs the Spider at several times that)
        assert s.stop() == run_id
        end = s.wait_for(ENDED, 30, run_id)
        wait_until(lambda: full and full[-1].final, timeout=10, what="the final frame")
    assert end.phase == "finished" and end.reason.startswith("stopped by the user at t = "), end

    layout = next(lay for lay in layouts if lay.run_id == run_id)
    assert layout.context.until_stopped and layout.context.settings.pacing == "realtime"
    assert layout.stop_time > 60.0  # the bound (open_run_s, or what the results may hold), not 0.2 s
    info = next(r for r in s.runs() if r.run_id == run_id)
    assert info.until_stopped and info.phase == "finished" and info.stop_time == layout.stop_time
    # paced in wall time: simulated time never ran ahead of the wall clock (one solver call at most)
    mine = [f for f in full if f.run_index == layout.run_index and f.rows.shape[0]]
    assert mine[-1].final, "a stopped run's final frame holds its last samples"
    went = mine[-1].rows[-1, 0] - mine[0].rows[-1, 0]
    assert went <= (mine[-1].wall_ns - mine[0].wall_ns) / 1e9 + 0.1, went
    # ready to be jogged throughout: frames of 5 ms (2-3 samples of 2 ms), not 25 ms
    assert max(f.rows[-1, 0] - f.rows[0, 0] for f in mine) <= pacing.JOG_FRAME_S + 1e-9

    att, rows = s.results_of(run_id, ["joint2.q_ref", "joint2.q", "joint1.q_ref"])
    assert att.run.until_stopped and att.run.phase == "finished" and att.run.reason == end.reason
    t, ref, q = rows[:, 0], rows[:, 1], rows[:, 2]
    assert t[-1] > 1.0 and abs(t[-1] - info.sim_time) < 1e-6 and abs(t[-1] - end.sim_time) < 1e-6
    assert np.allclose(rows[:, 3], SPIDER_Q0[0])  # the other joints hold their initial pose
    slope = np.diff(ref) / np.diff(t)
    assert slope.max() < 0.2 + 1e-6
    moving = np.nonzero(slope > 0.1)[0]
    span = t[moving[-1] + 1] - t[moving[0]]
    moved = ref[-1] - SPIDER_Q0[1]
    assert 0.05 < moved < 0.2, f"joint2 jogged {moved:.3f} rad in ~0.5 s at 0.2 rad/s"
    assert abs(moved - 0.2 * span) < 0.005, (moved, span)  # the jog's speed for as long as it lasted
    held = t > t[moving[-1] + 1]
    assert np.ptp(ref[held]) < 1e-9 and t[-1] - t[moving[-1] + 1] > 0.3  # then the pose holds
    assert abs(q[-1] - ref[-1]) < 5e-3


@pytest.mark.shares_service
def test_stop_finishes_a_timed_run_early_even_paused(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    run_id = running(s, 5.0)
    sim_time_past(s, 0.3, "the run under way")
    s.pause()
    s.wait_for(["paused"], 30, run_id)
    assert s.stop() == run_id
    end = s.wait_for(ENDED, 30, run_id)
    assert end.phase == "finished" and end.reason.startswith("stopped by the user at t = "), end
    info = next(r for r in s.runs() if r.run_id == run_id)
    assert info.phase == "finished" and info.stop_time == 5.0 and not info.until_stopped
    assert 0.3 < info.sim_time < 5.0 and info.reason == end.reason
    _, rows = s.results(run_id, ["joint1.q"])
    assert abs(rows[-1, 0] - info.sim_time) < 1e-6 and rows.shape[0] == info.samples
    with pytest.raises(RemoteError) as err:  # nothing runs any more
        s.stop()
    assert err.value.code == "conflict" and err.value.error.message == session_commands.refusal(
        "stop", "finished"
    )


@pytest.mark.shares_service
def test_a_run_says_how_long_it_was_jogged_and_an_unjogged_run_says_zero(service: Service) -> None:
    """Two real-time runs of the same command and settings: the jogged one says for how long (in the
    session's list of runs and in its results), the other says 0; the comparison is no longer blind."""
    s = service.client.create_session("ann", "spider")
    jogged_run = running(s, 2.5)
    sim_time_past(s, 0.3, "the run under way")
    jog_for(s, jogged_run, 0.4, qd=[0.2] + [0.0] * 6)
    assert s.wait_for(ENDED, 30, jogged_run).phase == "finished"
    info = next(r for r in s.runs() if r.run_id == jogged_run)
    assert 0.2 <= info.jogged_s <= 1.0, info  # ~0.4 s of messages, the deadman, whole solver calls
    att, rows = s.results_of(jogged_run, ["joint1.q_ref"])
    assert att.run.jogged_s == info.jogged_s, (att.run, info)
    # It is the time the set point moved at the jog's speed (each solver call it held for counted).
    t, ref = rows[:, 0], rows[:, 1]
    moving = float(np.sum(np.diff(t)[np.diff(ref) / np.diff(t) > 0.1]))
    assert abs(info.jogged_s - moving) < 0.01, (info.jogged_s, moving)

    plain_run = s.run()  # the same command and settings, nobody jogs
    assert s.wait_for(ENDED, 30, plain_run).phase == "finished"
    runs = {r.run_id: r for r in s.runs()}
    assert runs[plain_run].jogged_s == 0.0 and runs[jogged_run].jogged_s == info.jogged_s
    plain, _ = s.results_of(plain_run, ["joint1.q_ref"])
    assert plain.run.jogged_s == 0.0 and plain.context == att.context  # told apart by jogged_s only
