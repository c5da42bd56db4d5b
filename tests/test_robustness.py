"""Leak and thread-safety checks of the service nodes, in the spirit of MuJoCo's binding tests."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import zenoh.ext
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m

from .conftest import Service, wait_until


def watch_status(service: Service, role: str) -> tuple[list[m.NodeStatus], object]:
    seen: list[m.NodeStatus] = []

    def on_status(sample: zenoh.Sample) -> None:
        st = codec.loads(m.NodeStatus, sample.payload.to_bytes())
        if st.role == role:
            seen.append(st)

    sub = zenoh.ext.declare_advanced_subscriber(
        service.client.z,
        keys.NODES_STATUS,
        on_status,
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
    )
    return seen, sub


def test_sessions_leave_nothing_behind(service: Service) -> None:
    seen, sub = watch_status(service, "proxy")
    try:
        wait_until(lambda: seen, what="proxy status")
        base = seen[-1].detail["declared"]
        for _ in range(3):
            # 20 users (one user may hold only sessions_per_user sessions)
            sessions = [service.client.create_session(f"u{i}", "spider") for i in range(20)]
            wait_until(lambda: seen[-1].detail["sessions"] == 20, timeout=10, what="20 sessions")
            assert seen[-1].detail["declared"] == base + 4 * 20  # state, params, obstacles, command each
            for s in sessions:
                s.close()
            wait_until(lambda: seen[-1].detail["sessions"] == 0, timeout=10, what="sessions closed")
            assert seen[-1].detail["declared"] == base
    finally:
        sub.undeclare()
    assert not list((service.data_dir / "sessions").glob("*.json"))


def test_concurrent_commands_are_applied_whole(service: Service) -> None:
    client = service.client
    s = client.create_session("ann", "spider")
    names = [f"joint{i}.ctrl.kp_pos" for i in range(1, 8)]
    errors: list[BaseException] = []
    states: list[m.SessionState] = []
    lock = threading.Lock()

    def writer(i: int) -> None:
        try:
            for k in range(20):
                s.set_params({names[i]: 10.0 + k})
                s.set_initial([0.01 * k] * 7)
        except BaseException as exc:  # noqa: BLE001 - collected for the assertion below
            with lock:
                errors.append(exc)

    with s.watch(on_state=states.append), ThreadPoolExecutor(len(names)) as pool:
        list(pool.map(writer, range(len(names))))
    assert not errors
    values = s.snapshot().values
    assert [values[n] for n in names] == [29.0] * 7
    seqs = [st.seq for st in states]
    assert seqs == sorted(seqs)


def test_a_flood_of_bad_commands_leaves_the_proxy_serving(service: Service) -> None:
    client = service.client
    s = client.create_session("ann", "spider")
    key = keys.cmd(s.user, s.id)
    payloads = [b"{", b'{"op":"set_params","values":{"x":1}}', b'{"op":"run"}', b"\xff" * 1000]

    def flood(i: int) -> int:
        bad = 0
        for k in range(50):
            for reply in client.z.get(key, payload=payloads[(i + k) % len(payloads)], timeout=5):
                bad += reply.err is not None
        return bad

    with ThreadPoolExecutor(4) as pool:
        assert sum(pool.map(flood, range(4))) == 200
    assert s.snapshot().state.phase == "created"
