"""The hot-feedback node's decimation, by injecting samples (no mesh): the rate limit from a run's
first frame, the final frame always forwarded, zero rows for an aborted run, frames before layouts,
nothing but the final frame forwarded for a session nobody watches."""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import pytest
from simecs.mesh.process.config import MeshConfig
from simecs.mesh.process.seal import Seal
from simecs.mesh.protocol import codec, columns, frames, keys
from simecs.mesh.protocol import messages as m
from simecs.nodes.hotfeedback import MATCHING_SETTLE_NS, HotFeedback

SID = keys.new_session_id()
USER = "ann"
COLS = ["time", "joint1.q", "joint1.qd"]


SEAL = Seal(bytes(range(32)))  # the service's, in these tests


@dataclass
class Sample:
    """A zenoh sample as a worker puts it: sealed, unless `forged`."""

    key_expr: str
    data: bytes
    forged: bool = False

    @property
    def attachment(self) -> Any:
        mac = b"\0" * 16 if self.forged else SEAL.mac(self.key_expr, self.data)
        return type("Attachment", (), {"to_bytes": lambda _self: mac})()

    @property
    def payload(self) -> Any:
        data = self.data

        class Payload:
            def to_bytes(self) -> bytes:
                return data

        return Payload()


class Publisher:
    """A live publisher; `watched`: what zenoh's matching status says (a subscriber on the key)."""

    def __init__(self) -> None:
        self.sent: list[tuple[float, frames.Frame]] = []
        self.watched = True

    @property
    def matching(self) -> bool:
        return self.watched

    def put(self, payload: bytes) -> None:
        self.sent.append((time.monotonic(), frames.decode(payload)))


def node(rate_hz: float = 10.0) -> tuple[HotFeedback, Publisher, m.RunLayout]:
    hf = HotFeedback(MeshConfig())
    hf.seal = SEAL
    pub = Publisher()
    hf.publisher = lambda key, **kw: pub  # type: ignore[method-assign]
    settings = m.RunSettings(stop_time=1.0, output_interval=0.01)
    context = m.RunContext("ann", {}, [0.0], None, settings)
    layout = m.RunLayout(
        SID, "r1", 1, "spider", COLS, ["s", "rad", "rad/s"], COLS, rate_hz, 1.0, 0.01, context
    )
    return hf, pub, layout


def layout_sample(layout: m.RunLayout) -> Sample:
    return Sample(keys.layout(USER, SID), codec.dumps(layout))


def frame_sample(
    seq: int, t: float, final: bool = False, rows: int = 1, forged: bool = False, attempt: int = 0
) -> Sample:
    data = np.array([[t - (rows - 1 - k) * 0.01, 0.1 * t, 1.0] for k in range(rows)]).reshape(rows, 3)
    fr = frames.Frame(1, seq, time.time_ns(), data, frames.FLAG_FINAL if final else 0, attempt)
    return Sample(keys.vars_full(USER, SID), frames.encode(fr), forged)


def test_frames_that_come_before_their_layout_are_not_lost() -> None:
    hf, pub, layout = node()
    for seq in range(4):  # a short run, all of it before the layout was handled
        hf._on_full(frame_sample(seq, 0.1 * seq, final=seq == 3))  # type: ignore[arg-type]
    assert pub.sent == []
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and pub.sent[0][1].final
    assert pub.sent[0][1].rows[0, 0] == pytest.approx(0.3) and pub.sent[0][1].flags & frames.FLAG_LIVE


def test_the_limit_holds_from_the_first_frame_and_the_final_frame_always_goes() -> None:
    hf, pub, layout = node(rate_hz=10.0)
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    for seq in range(5):  # a burst, 2 ms apart: only the first goes at once
        hf._on_full(frame_sample(seq, 0.01 * seq))  # type: ignore[arg-type]
        time.sleep(0.002)
    assert len(pub.sent) == 1
    hf._on_full(frame_sample(5, 0.05, final=True))  # type: ignore[arg-type]
    assert len(pub.sent) == 2 and pub.sent[-1][1].final and pub.sent[-1][1].rows[0, 0] == pytest.approx(0.05)


def test_an_aborted_run_ends_with_an_empty_final_frame_not_a_stale_sample() -> None:
    hf, pub, layout = node(rate_hz=1.0)
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    hf._on_full(frame_sample(0, 0.0))  # type: ignore[arg-type]
    hf._on_full(frame_sample(1, 0.02))  # held back by the 1 Hz limit
    empty = frames.Frame(1, 2, time.time_ns(), np.empty((0, len(COLS))), frames.FLAG_FINAL)
    hf._on_full(Sample(keys.vars_full(USER, SID), frames.encode(empty)))  # type: ignore[arg-type]
    last = pub.sent[-1][1]
    assert last.final and last.rows.shape[0] == 0
    assert COLS[0] == columns.TIME


def settled(hf: HotFeedback) -> None:
    """As if the session's live publisher were declared long enough ago for zenoh to know its match."""
    hf.streams[(USER, SID)].declared_ns -= MATCHING_SETTLE_NS


def test_a_session_nobody_watches_live_gets_no_frames_until_someone_does() -> None:
    hf, pub, layout = node(rate_hz=100.0)
    pub.watched = False
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    settled(hf)
    for seq in range(3):
        hf._on_full(frame_sample(seq, 0.025 * seq))  # type: ignore[arg-type]
        time.sleep(0.011)
    assert pub.sent == [] and hf.unwatched == 3
    pub.watched = True  # a viewer subscribes mid-run: the next frame goes
    hf._on_full(frame_sample(3, 0.075))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and pub.sent[0][1].rows[0, 0] == pytest.approx(0.075)
    pub.watched = False  # it leaves before the end: the stream still ends, and is freed later
    hf._on_full(frame_sample(4, 0.1, final=True, forged=True))  # type: ignore[arg-type]
    stream = hf.streams[(USER, SID)]
    assert stream.ended_ns == 0 and hf.unsealed == 1  # a forged end changes nothing
    hf._on_full(frame_sample(4, 0.1, final=True))  # type: ignore[arg-type]
    assert len(pub.sent) == 2 and pub.sent[-1][1].final and pub.sent[-1][1].rows[0, 0] == pytest.approx(0.1)
    assert stream.ended_ns > 0 and stream.pending is None and hf.unwatched == 3


def test_a_new_publisher_forwards_before_zenoh_reports_its_subscriber() -> None:
    """zenoh's matching status is false until the hub answers the publisher's declaration (seconds on
    a loaded machine), while the puts do reach a subscriber: a run's first frames must not be lost."""
    hf, pub, layout = node(rate_hz=100.0)
    pub.watched = False
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    hf._on_full(frame_sample(0, 0.0))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and hf.unwatched == 0
    time.sleep(0.011)
    settled(hf)  # still no subscriber once zenoh has had time to say: nothing more goes
    hf._on_full(frame_sample(1, 0.025))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and hf.unwatched == 1
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]  # the next run keeps the publisher
    hf._on_full(frame_sample(2, 0.05))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and hf.unwatched == 2


def test_a_forged_frame_of_a_watched_session_is_not_forwarded() -> None:
    hf, pub, layout = node(rate_hz=100.0)
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    hf._on_full(frame_sample(0, 0.5, forged=True))  # type: ignore[arg-type]
    assert pub.sent == [] and hf.unsealed == 1
    hf._on_full(frame_sample(0, 0.025))  # type: ignore[arg-type]
    assert len(pub.sent) == 1 and pub.sent[0][1].rows[0, 0] == pytest.approx(0.025)


def test_a_frame_of_an_earlier_attempt_is_not_forwarded() -> None:
    """A run started again after its host was lost has a new layout (context.attempt 2); a host that was
    only cut off may still send frames of attempt 1: they are nobody's (issue 33, 1: the fence)."""
    hf, pub, layout = node(rate_hz=100.0)
    layout.context.attempt = 2
    hf._on_layout(layout_sample(layout))  # type: ignore[arg-type]
    hf._on_full(frame_sample(0, 0.5, attempt=1))  # type: ignore[arg-type]
    hf._on_full(frame_sample(1, 0.6, final=True, attempt=1))  # type: ignore[arg-type]
    assert pub.sent == [] and hf.stale == 2
    hf._on_full(frame_sample(0, 0.025, attempt=2))  # type: ignore[arg-type]
    assert (
        len(pub.sent) == 1
        and pub.sent[0][1].attempt == 2
        and pub.sent[0][1].rows[0, 0] == pytest.approx(0.025)
    )
    assert frames.belongs(1, 0, 1, 2) and not frames.belongs(1, 1, 1, 2) and not frames.belongs(2, 2, 1, 2)
