"""A controller in the loop over `hil/sensors` and `hil/actuators` (PROTOCOL.md §6.3), against real
nodes: the reference controller (docs/examples/external_controller.py) in its own process matches the
built-in cascade, a silent one fails the run and frees the slot, a late one is counted, bad actuator
frames are refused by name, and a controller on another host (a network namespace) closes the loop."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
from simecs.mesh.client import RemoteError, SessionClient
from simecs.mesh.protocol import frames, hil, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.local_mesh import LocalMesh, clean_env
from simecs.testing import netns

from tests.conftest import Service, start_service

EXAMPLE = Path(__file__).resolve().parent.parent / "docs" / "examples" / "external_controller.py"
START = [0.3, -0.4, 0.2, 0.6, -0.3, 0.2, 0.1]
PATH = [([0.8, 0.1, 0.6, 1.0, -0.7, 0.6, 0.5], 100.0, 100.0), (START, 100.0, 100.0)]
JOINTS = [f"joint{j + 1}" for j in range(7)]
#: The reference controller samples the cascade once a millisecond where the built-in one is
#: continuous: PROTOCOL.md §6.3 explains this bound (measured: about 0.1 mrad).
TOLERANCE_RAD = 0.5e-3


def controller(
    endpoint: str, s: SessionClient, *extra: str, prefix: tuple[str, ...] = ()
) -> subprocess.Popen[str]:
    argv = [*prefix, sys.executable, str(EXAMPLE), endpoint, "--user", s.user, "--session", s.id, *extra]
    proc = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=clean_env()
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line.startswith("serving"), line + proc.stdout.read()
    return proc


def angles(s: SessionClient, run_id: str) -> np.ndarray:
    _, rows = s.results(run_id, [f"{j}.q" for j in JOINTS])
    return rows[:, 1:]


def session(service: Service, stop_time: float, **settings: object) -> SessionClient:
    s = service.client.create_session("hil", "spider")
    s.set_initial(START)
    s.set_joint_path(PATH)
    s.set_settings(stop_time=stop_time, output_interval=0.001, **settings)
    return s


def run(s: SessionClient, timeout: float = 60.0) -> m.SessionState:
    run_id = s.run()
    return s.wait_for(["finished", "failed", "aborted"], timeout, run_id)


@pytest.mark.shares_service
def test_the_reference_controller_in_another_process_matches_the_builtin_cascade(service: Service) -> None:
    s = session(service, 2.0, pacing="fast")
    builtin = run(s)
    assert builtin.phase == "finished"
    proc = controller(service.mesh.endpoint, s, "--runs", "1")
    try:
        s.set_settings(stop_time=2.0, output_interval=0.001, pacing="fast", controller="external")
        ext = run(s)
        assert proc.wait(30) == 0
    finally:
        proc.kill()
    assert ext.phase == "finished", ext.reason
    assert ext.hil is not None and ext.hil.periods == 2000 and ext.hil.misses == 0  # fast: no deadlines
    a, b = angles(s, builtin.run_id), angles(s, ext.run_id)
    assert a.shape == b.shape == (2001, 7)
    assert float(np.abs(a - b).max()) < TOLERANCE_RAD
    assert float(np.abs(a - np.array(START)).max()) > 0.3  # the path did move the arm
    layout_settings = s.snapshot().settings
    assert layout_settings.controller == "external"


def test_a_silent_controller_fails_the_run_with_its_reason_and_frees_the_slot(mesh: LocalMesh) -> None:
    service = start_service(mesh, max_running=1)
    s = session(service, 1.0, pacing="fast", controller="external", hil_timeout=0.3)
    failed = run(s, timeout=30)
    assert failed.phase == "failed"
    assert "external controller silent: no actuator frame for period 0 (t = 0.0000 s)" in failed.reason
    assert "hil_timeout = 0.3 s" in failed.reason
    s.set_settings(stop_time=0.2, output_interval=0.001, pacing="fast")  # the one slot is free again
    assert run(s, timeout=30).phase == "finished"


@pytest.mark.shares_service
def test_late_answers_are_counted_and_told_on_a_paced_run(service: Service) -> None:
    s = session(service, 0.3, pacing="realtime", controller="external")
    proc = controller(service.mesh.endpoint, s, "--runs", "1", "--delay-ms", "3")
    try:
        st = run(s)
    finally:
        proc.kill()
    assert st.phase == "finished", st.reason
    assert st.hil is not None and st.hil.periods == 300
    assert st.hil.misses > 250 and st.hil.worst_late_ms > 1.0  # 3 ms answers to 1 ms deadlines
    assert any("external controller" in w and "late" in w for w in st.warnings), st.warnings


class Answerer:
    """A hand-made controller: answers each sensor frame with `reply(seq, row)` (raw bytes)."""

    def __init__(self, s: SessionClient, reply: object) -> None:
        self.reply = reply
        self.rows: list[np.ndarray] = []
        self.attempts: set[int] = set()  # of the sensor frames
        self.sealed: set[bool] = set()  # whether each carried the service's seal
        self.seal = s.client.seal
        z = s.client.z
        self.pub = z.declare_publisher(keys.hil_actuators(s.user, s.id))
        self.sub = z.declare_subscriber(keys.hil_sensors(s.user, s.id), self.on_sensors)

    def on_sensors(self, sample: object) -> None:
        frame = frames.decode(sample.payload.to_bytes())  # type: ignore[attr-defined]
        self.rows.append(frame.rows[0].copy())
        self.attempts.add(frame.attempt)
        self.sealed.add(self.seal is not None and self.seal.sample_valid(sample))
        self.pub.put(self.reply(frame))  # type: ignore[operator]

    def close(self) -> None:
        self.sub.undeclare()
        self.pub.undeclare()


@pytest.mark.shares_service
def test_bad_actuator_frames_are_refused_by_name_and_only_the_external_joints_obey(service: Service) -> None:
    s = session(service, 0.5, pacing="fast", controller="external", external_joints=["joint7"])
    answered: set[int] = set()
    lock = threading.Lock()

    def reply(frame: frames.Frame) -> bytes:
        with lock:
            first = frame.seq not in answered
            answered.add(frame.seq)
        if frame.seq == 3 and first:  # the first time: three wrong answers, then none (a repeat comes)
            s.client.z.put(keys.hil_actuators(s.user, s.id), b"garbage")
            s.client.z.put(
                keys.hil_actuators(s.user, s.id), hil.actuator_frame(frame.run_index, 3, 0, [0.0] * 3)
            )
            return hil.actuator_frame(frame.run_index, 3, 0, [float("nan")] * 7)
        stale = hil.actuator_frame(frame.run_index + 1, frame.seq, 0, [9.0] * 7)  # another run's: dropped
        s.client.z.put(keys.hil_actuators(s.user, s.id), stale)
        # another attempt's (a host taken for lost that goes on): dropped too
        other = hil.actuator_frame(frame.run_index, frame.seq, 0, [9.0] * 7, attempt=frame.attempt + 1)
        s.client.z.put(keys.hil_actuators(s.user, s.id), other)
        return hil.actuator_frame(frame.run_index, frame.seq, 0, [5.0] * 6 + [0.25], attempt=frame.attempt)

    answerer = Answerer(s, reply)
    try:
        st = run(s)
    finally:
        answerer.close()
    assert st.phase == "finished", st.reason
    warnings = " | ".join(st.warnings)
    assert "hil/actuators frame refused: not a frame" in warnings
    assert "1x3 values: an actuator frame is 1 row of 7 (one per joint)" in warnings
    assert "i_ref of joint 1 is not a finite number" in warnings
    _, rows = s.results(st.run_id, [f"{j}.i_ref" for j in JOINTS])
    assert np.all(rows[1:, 7] == 0.25)  # joint7 follows the controller
    assert np.all(np.abs(rows[:, 1:7]) < 4.0)  # the others keep the built-in cascade, not 5 A
    sensors = np.array(answerer.rows)
    assert answerer.attempts == {1} and answerer.sealed == {True}  # the run's attempt, from the worker
    assert sensors.shape[1] == 1 + len(hil.SENSOR_JOINT_FIELDS) * 7
    assert np.allclose(sensors[0, 1::9], START, atol=1e-9)  # q of every joint at t = 0


def test_settings_naming_a_joint_the_model_lacks_or_a_period_off_the_step_are_refused(
    service: Service,
) -> None:
    s = service.client.create_session("hil", "spider")
    with pytest.raises(RemoteError) as bad_joint:
        s.set_settings(controller="external", external_joints=["joint9"])
    assert bad_joint.value.field == "settings.external_joints[0]" and "joint9" in str(bad_joint.value)
    with pytest.raises(RemoteError) as bad_period:
        s.set_settings(controller="external", step=0.001, control_period=0.0015)
    assert bad_period.value.field == "settings.control_period"
    s.set_settings(step=0.001, control_period=0.0015)  # the built-in controller has no period to keep


def test_a_controller_on_another_host_closes_the_loop() -> None:
    """The hub listens on a LAN address in its own network namespace; the controller runs in another
    namespace and reaches it over a virtual Ethernet link, as from another machine."""
    try:
        lan = netns.Lan(("hub", "ctl")).up()
    except netns.NetnsUnavailable as exc:
        pytest.fail(f"network namespaces are needed for this test: {exc}")

    class HubOnLan(LocalMesh):
        def argv_prefix(self, module: str) -> list[str]:
            return lan.prefix("hub") if module == "simecs.nodes.hub" else []

    lan_endpoint = f"tcp/{lan.address('hub')}:7447"
    mesh = HubOnLan()
    try:
        mesh.spawn(
            "hub", "simecs.nodes.hub", "--listen", mesh.endpoint, "--listen", lan_endpoint, node_id="hub"
        )
        mesh.client()
        service = start_service(mesh)
        s = session(service, 0.5, pacing="realtime", controller="external")
        proc = controller(lan_endpoint, s, "--runs", "1", prefix=tuple(lan.prefix("ctl")))
        try:
            st = run(s)
            assert proc.wait(30) == 0
        finally:
            proc.kill()
        assert st.phase == "finished", st.reason
        assert st.hil is not None and st.hil.periods == 500
    finally:
        mesh.close()
        lan.down()
