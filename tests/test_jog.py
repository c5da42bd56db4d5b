"""Live jogging (telemanipulation) of a real-time run over the `jog` key: a joint and a Cartesian jog
move the arm while their messages come, and the deadman stops it when they stop."""

from __future__ import annotations

import threading
import time

import numpy as np
from simecs.mesh import codec, keys
from simecs.mesh import messages as m
from simecs.mesh.client import SessionClient

from tests.conftest import Service, wait_until
from tests.test_commands import SPIDER_Q0, kinematics

HOLD = m.JointPath([m.PathNode(SPIDER_Q0)])  # the arm holds its initial pose: only the jog moves it


def jog_for(s: SessionClient, run_id: str, seconds: float, **fields: object) -> None:
    """Send a jog message every 50 ms for `seconds`, as a held jog button does."""
    z = s.client.z
    key = keys.jog(s.user, s.id)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        z.put(key, codec.dumps(m.JogInput(run_id=run_id, **fields)))  # type: ignore[arg-type]
        time.sleep(0.05)


def running(s: SessionClient, stop_time: float) -> str:
    s.set_initial(SPIDER_Q0)
    s.set_command(HOLD)
    s.set_settings(stop_time=stop_time, output_interval=0.002, pacing="realtime")
    run_id = s.run()
    wait_until(lambda: s.snapshot().state.phase == "running", timeout=20, what="run going")
    return run_id


def test_a_joint_jog_moves_the_joint_and_the_deadman_stops_it(service: Service) -> None:
    s = service.client.create_session("ann", "spider")
    run_id = running(s, 3.0)
    time.sleep(0.3)
    s.client.z.put(
        keys.jog(s.user, s.id), codec.dumps(m.JogInput(run_id="r99", qd=[0.2] + [0.0] * 6))
    )  # not ours
    jog_for(s, run_id, 1.0, qd=[0.2] + [0.0] * 6)
    released = time.monotonic()
    assert s.wait_for(["finished", "failed"], 30, run_id).phase == "finished"
    _, rows = s.results(run_id, ["joint1.q_ref", "joint1.q", "joint2.q"])
    t, ref, q = rows[:, 0], rows[:, 1], rows[:, 2]
    moved = ref[-1] - SPIDER_Q0[0]
    assert 0.12 < moved < 0.26, f"joint1 jogged {moved:.3f} rad in ~1 s at 0.2 rad/s"
    assert abs(q[-1] - ref[-1]) < 5e-3 and np.allclose(rows[:, 3], SPIDER_Q0[1], atol=2e-3)
    # The set point moved at 0.2 rad/s while jogged, then stood still: the deadman stopped it.
    slope = np.diff(ref) / np.diff(t)
    assert slope.max() < 0.2 + 1e-6
    still = t > t[np.nonzero(slope > 0.1)[0][-1]] + 0.05
    assert np.ptp(ref[still]) < 1e-9 and still.sum() > 100
    assert time.monotonic() - released < 30


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
    _, rows = s.results(run_id, ["joint1.q_ref"])
    assert np.allclose(rows[:, 1], rows[0, 1])
