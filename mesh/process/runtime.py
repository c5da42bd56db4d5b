"""The one runtime every simecs process uses: session, presence, logging, errors, clean exit.

A node subclasses `Node`, declares what it serves in `start()`, and lets the runtime do the rest:
it opens the zenoh session (retrying while the hub comes up), announces a liveliness token and a
`NodeStatus`, turns SIGINT/SIGTERM into a normal exit that undeclares everything and closes the
session (a declared callback otherwise keeps the process alive forever: zenoh's threads hold it),
answers every bad request with an `Error` naming what was wrong, and keeps running whatever a
handler raises.

Callbacks from zenoh must return at once (a slow one stalls the whole link), so `subscribe()` hands
samples to a worker thread through a bounded queue that drops the oldest sample when full.
"""

from __future__ import annotations

import argparse
import ctypes
import faulthandler
import logging
import os
import signal
import socket
import sys
import threading
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import zenoh
import zenoh.ext

from ..protocol import codec, keys
from ..protocol.messages import Error, NodeStatus, Ok
from . import affinity
from . import seal as seals
from .config import MeshConfig, open_session
from .config import load as load_config
from .logs import setup_logging
from .workers import BoundedWorker

log = logging.getLogger("simecs")


class RequestError(Exception):
    """Raise in a handler to answer with an Error of this code, message and field."""

    def __init__(self, code: str, message: str, field: str = "") -> None:
        super().__init__(message)
        self.code, self.message, self.field = code, message, field

    def to_error(self) -> Error:
        return Error(code=self.code, message=self.message, field=self.field)  # type: ignore[arg-type]


class NotMine(Exception):
    """Raise in a handler to leave a query unanswered: another node holds what it asks for (one
    answer per query, from the node that owns the thing asked)."""


#: An error reply quotes at most this much of its message and field: a refusal may echo the input
#: (an unknown op, a name), and a hostile input must not make the reply itself too large to decode.
MAX_ERROR_MESSAGE = 2000
MAX_ERROR_FIELD = 200

#: A request payload from this size on gives its memory back to the system once answered.
LARGE_PAYLOAD = 8 * 1024 * 1024


def release_memory() -> None:
    """Hand freed heap back to the system (glibc keeps it otherwise: a node that refused one 256 MiB
    upload kept ~200 MB for good, and grew with each). A no-op where there is no malloc_trim."""
    try:
        ctypes.CDLL(None).malloc_trim(0)
    except (OSError, AttributeError):
        pass


_PAGE = os.sysconf("SC_PAGE_SIZE")


def process_mb(pid: int) -> float:
    """Resident memory of process `pid` (MB; 0 when it cannot be read): a host's load, and what a
    large request's release is logged with."""
    try:
        with open(f"/proc/{pid}/statm") as f:
            return int(f.read().split()[1]) * _PAGE / 2**20
    except (OSError, IndexError, ValueError):
        return 0.0


def _shortened(text: str, most: int) -> str:
    return text if len(text) <= most else text[: most - 1] + "…"


def error_of(exc: BaseException) -> Error:
    """The Error reply for an exception raised while handling a request."""
    if isinstance(exc, RequestError):
        err = exc.to_error()
    elif isinstance(exc, codec.DecodeError):
        err = Error(code="bad_request", message=str(exc), field=exc.field)
    elif isinstance(exc, keys.KeyProblem):
        err = Error(code="bad_request", message=str(exc), field=exc.chunk)
    else:
        err = Error(code="internal", message=f"{type(exc).__name__}: {exc}")
    err.message = _shortened(err.message, MAX_ERROR_MESSAGE)
    err.field = _shortened(err.field, MAX_ERROR_FIELD)
    return err


@dataclass
class Request:
    """A query as a handler sees it."""

    key: str
    payload: bytes | None
    parameters: dict[str, str]
    sealed: bool = False  # sent by a service node (mesh/process/seal.py)

    def from_service(self, what: str) -> None:
        """Refuse the request unless a service node sent it."""
        if not self.sealed:
            raise RequestError("forbidden", f"{what} come from service nodes only (no valid seal)")

    def json(self, cls: Any) -> Any:
        if self.payload is None:
            raise RequestError("bad_request", "this request needs a JSON payload")
        return codec.loads(cls, self.payload)


@dataclass
class Binary:
    """A binary reply, with an optional JSON attachment describing it."""

    payload: bytes
    attachment: Any = None


class Node:
    """Base of every simecs process. Subclasses set `role` and override `start()` (and `stop()`)."""

    role = "node"
    #: Routes live frames (hub, hot-feedback, viewer): pinned to the shared mesh core (`affinity`).
    live_path = False

    def __init__(self, mesh: MeshConfig, node_id: str | None = None) -> None:
        self.mesh = mesh
        self.cpu_choice = "none"  # `--cpu`; set by main_for, so nodes built in tests stay unpinned
        self.cpu: int | None = None
        self.node_id = node_id or f"{socket.gethostname()[:20]}-{os.getpid()}".replace(".", "-")
        keys.check_name(self.node_id, "node id")
        self.stop_event = threading.Event()
        self.session: zenoh.Session | None = None
        self._declared: list[Any] = []
        self._workers: list[BoundedWorker] = []
        self._status_pub: Any = None
        self._seal: seals.Seal | None = None
        self.unsealed = 0  # samples and queries of service keys refused for want of a valid seal
        self.log = logging.getLogger(f"simecs.{self.role}")

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Node:
        """Build the node from parsed command-line flags (override to read extra flags)."""
        return cls(mesh_from_args(args), node_id=args.node_id)

    # -- to override ---------------------------------------------------------------------------
    def start(self) -> None:
        """Declare subscribers, queryables and publishers."""

    def stop(self) -> None:
        """Release what `start()` took beyond zenoh declarations (those are undeclared for you)."""

    def tick(self) -> None:
        """Called about every `tick_s` seconds from the main thread."""

    tick_s = 0.2

    def status_detail(self) -> dict[str, Any]:
        return {}

    def status_load(self) -> Any:
        """A simulator's `SimulatorLoad` (NodeStatus.load); None for the other roles."""
        return None

    # -- helpers for subclasses ----------------------------------------------------------------
    @property
    def z(self) -> zenoh.Session:
        assert self.session is not None, "node not started"
        return self.session

    @property
    def seal(self) -> seals.Seal:
        """The service's seal (mesh/process/seal.py), from the service key file (made if missing)."""
        if self._seal is None:
            self._seal = seals.load(seals.key_file(self.mesh.service_key_file), create=True)
        return self._seal

    @seal.setter
    def seal(self, value: seals.Seal) -> None:
        self._seal = value

    def declare(self, entity: Any) -> Any:
        self._declared.append(entity)
        return entity

    def publisher(self, key: str, latched: bool = False, **kwargs: Any) -> Any:
        """A publisher whose samples carry the service's seal; `latched` keeps the last sample for
        late joiners (advanced publisher cache)."""
        pub: Any
        if latched:
            pub = zenoh.ext.declare_advanced_publisher(
                self.z, key, cache=zenoh.ext.CacheConfig(1), publisher_detection=True, **kwargs
            )
        else:
            pub = self.z.declare_publisher(key, **kwargs)
        return self.declare(seals.SealedPublisher(pub, key, self.seal))

    def put(self, key: str, payload: bytes) -> None:
        """One sealed sample on `key` (for keys put too seldom to keep a publisher)."""
        self.z.put(key, payload, attachment=self.seal.mac(key, payload))

    def sealed_only(self, handle: Callable[[zenoh.Sample], None]) -> Callable[[zenoh.Sample], None]:
        """`handle`, for samples that carry the service's seal; others are counted and logged."""

        def checked(sample: zenoh.Sample) -> None:
            if self.sealed(sample):
                handle(sample)

        return checked

    def sealed(self, sample: zenoh.Sample, payload: bytes | None = None) -> bool:
        """Whether `sample` (whose payload is `payload`, when already read) carries the service's
        seal; one that does not is counted and logged (the first ten, then every thousandth)."""
        if self.seal.sample_valid(sample, payload):
            return True
        self.unsealed += 1
        if self.unsealed <= 10 or self.unsealed % 1000 == 0:
            self.log.warning(
                "ignored a sample on %s without a valid service seal (%d so far): only service "
                "nodes write this key",
                sample.key_expr,
                self.unsealed,
            )
        return False

    def subscribe(
        self,
        key: str,
        handle: Callable[[zenoh.Sample], None],
        maxlen: int = 1024,
        latched: bool = False,
        remote_only: bool = False,
        inline: bool = False,
        liveliness: bool = False,
        sealed: bool = False,
        history: bool = False,
    ) -> BoundedWorker | None:
        """Run `handle(sample)` in a worker thread, never in zenoh's callback.

        `inline=True` calls it in zenoh's callback instead, saving a thread wake-up (about a
        millisecond on an idle VM): only for handlers that never block and return in microseconds.
        Exceptions are logged either way. `liveliness=True` watches liveliness tokens under `key`
        (PUT when one appears, DELETE when it goes) instead of data; with `history`, the tokens already
        up arrive first as PUTs. `sealed=True`: only samples
        with the service's seal reach `handle` (keys that only service nodes write)."""
        if sealed:
            handle = self.sealed_only(handle)
        worker: BoundedWorker | None = None
        push: Callable[[zenoh.Sample], None]
        if inline:

            def call(sample: zenoh.Sample) -> None:
                try:
                    handle(sample)
                except Exception:
                    self.log.error("handler on %s failed:\n%s", key, traceback.format_exc())

            push = call
        else:
            worker = BoundedWorker(f"{self.role}:{key}", handle, maxlen)
            self._workers.append(worker)
            push = worker.push
        origin = zenoh.Locality.REMOTE if remote_only else zenoh.Locality.ANY
        if liveliness:
            self.declare(self.z.liveliness().declare_subscriber(key, push, history=history))
        elif latched:
            late = zenoh.ext.HistoryConfig(detect_late_publishers=True)
            self.declare(
                zenoh.ext.declare_advanced_subscriber(self.z, key, push, history=late, allowed_origin=origin)
            )
        else:
            self.declare(self.z.declare_subscriber(key, push, allowed_origin=origin))
        return worker

    def subscribe_messages(
        self, key: str, cls: Any, handle: Callable[[Any, str], None], **options: Any
    ) -> None:
        """`subscribe()` for JSON messages of type `cls`: a sample that does not decode is logged with
        what was wrong and dropped; `handle(message, key)` gets only valid messages, with the key they
        came on (what a node trusts, never the payload's claim)."""

        def decoded(sample: zenoh.Sample) -> None:
            try:
                message = codec.loads(cls, sample.payload.to_bytes())
            except codec.DecodeError as exc:
                self.log.warning("bad message on %s: %s", sample.key_expr, exc)
                return
            handle(message, str(sample.key_expr))

        self.subscribe(key, decoded, **options)

    def serve(self, key: str, handle: Callable[[Request], Any], threaded: bool = False) -> None:
        """Answer queries on `key`: `handle` returns `Binary`, or any message value, sent as `Ok{data}`;
        raising answers an `Error` reply, raising `NotMine` answers nothing."""

        def answer(query: zenoh.Query) -> None:
            key_str = str(query.key_expr)
            payload: bytes | None = None
            try:
                payload = query.payload.to_bytes() if query.payload is not None else None
                params = dict(list(query.selector.parameters)) if query.selector.parameters else {}  # type: ignore[call-overload]
                sealed = query.attachment is not None and self.seal.sample_valid(query)
                result = handle(Request(key_str, payload, params, sealed))
                if isinstance(result, Binary):  # sealed with its description (PROTOCOL.md §4)
                    described = b"" if result.attachment is None else codec.dumps(result.attachment)
                    att = self.seal.binary_attachment(key_str, result.payload, described)
                    query.reply(query.key_expr, result.payload, attachment=att)
                else:
                    if not isinstance(result, Ok):
                        result = Ok(data=result)
                    body = codec.dumps(result)  # sealed: a service node may rely on the answer
                    query.reply(query.key_expr, body, attachment=self.seal.mac(key_str, body))
            except NotMine:
                pass
            except Exception as exc:
                err = error_of(exc)
                if err.code == "internal":
                    self.log.error("request on %s failed:\n%s", key_str, traceback.format_exc())
                else:
                    self.log.warning("refused request on %s: %s", key_str, err.message)
                try:
                    query.reply_err(codec.dumps(err))
                except Exception:  # the querier may be gone
                    pass
            finally:
                query.drop()
                if payload is not None and len(payload) >= LARGE_PAYLOAD:
                    size, held = len(payload) >> 20, process_mb(os.getpid())
                    del payload
                    release_memory()
                    self.log.info(
                        "a %d MB request on %s answered: resident memory %.0f -> %.0f MB",
                        size,
                        key_str,
                        held,
                        process_mb(os.getpid()),
                    )

        if threaded:
            worker = BoundedWorker(f"{self.role}:q:{key}", answer, maxlen=4096)
            self._workers.append(worker)
            self.declare(self.z.declare_queryable(key, worker.push))
        else:
            self.declare(self.z.declare_queryable(key, answer))

    def full_status_detail(self) -> dict[str, Any]:
        """The subclass's detail plus what every node has: live declarations and dropped samples."""
        return {
            **self.status_detail(),
            "declared": len(self._declared),
            "dropped": sum(w.dropped for w in self._workers),
            **({"unsealed": self.unsealed} if self.unsealed else {}),
            **({"cpu": self.cpu} if self.cpu is not None else {}),
        }

    def publish_status(self, state: str, detail: dict[str, Any] | None = None) -> None:
        status = NodeStatus(
            role=self.role,
            node_id=self.node_id,
            pid=os.getpid(),
            host=socket.gethostname(),
            state=state,  # type: ignore[arg-type]
            detail=self.full_status_detail() if detail is None else detail,
            load=self.status_load(),
        )
        if self._status_pub is not None:
            self._status_pub.put(codec.dumps(status))

    # -- lifecycle -----------------------------------------------------------------------------
    def run(self) -> int:
        """Run until SIGINT/SIGTERM or `stop_event`; returns the process exit code."""
        self._install_signals()
        _ = self.seal  # a missing or unreadable service key stops the node here, with its reason
        self.session = open_session(self.mesh)
        try:
            if self.live_path:
                # After the session opened, so zenoh's threads exist and are pinned too.
                self.cpu = affinity.place_on_mesh_core(self.cpu_choice)
            self._status_pub = self.publisher(keys.node_status(self.role, self.node_id), latched=True)
            self.publish_status("starting")
            self.start()
            # The token says "ready": declared only once everything `start()` serves is declared.
            self.declare(self.z.liveliness().declare_token(keys.node_token(self.role, self.node_id)))
            self.publish_status("ready")
            self.log.info("ready as %s/%s (pid %d)", self.role, self.node_id, os.getpid())
            last_status, last_detail = time.monotonic(), (self.full_status_detail(), self.status_load())
            while not self.stop_event.wait(self.tick_s):
                try:
                    self.tick()
                except Exception:
                    self.log.error("tick failed:\n%s", traceback.format_exc())
                # Status on every change of its detail (at most 5 per second), and every 5 s anyway.
                now = time.monotonic()
                if now - last_status > 0.2:
                    detail = (self.full_status_detail(), self.status_load())
                    if detail != last_detail or now - last_status > 5.0:
                        self.publish_status("ready", detail[0])
                        last_status, last_detail = now, detail
            self.publish_status("stopping")
            return 0
        finally:
            self.shutdown()

    def shutdown(self) -> None:
        try:
            self.stop()
        except Exception:
            self.log.error("stop failed:\n%s", traceback.format_exc())
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:
                pass
        self._declared.clear()
        for worker in self._workers:
            worker.stop(timeout=1.0)
        if self.session is not None:
            try:
                self.session.close()
            except Exception:
                pass
            self.session = None
        self.log.info("stopped")

    def _install_signals(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return

        def on_signal(signum: int, _frame: Any) -> None:
            self.log.info("signal %d: stopping", signum)
            self.stop_event.set()

        signal.signal(signal.SIGINT, on_signal)
        signal.signal(signal.SIGTERM, on_signal)


def node_arguments(parser: argparse.ArgumentParser) -> None:
    """The mesh flags every node takes."""
    parser.add_argument(
        "--connect", action="append", help="endpoint to connect to (repeatable), e.g. tcp/10.0.0.5:7447"
    )
    parser.add_argument("--listen", action="append", help="endpoint to listen on (repeatable)")
    parser.add_argument("--mode", choices=["peer", "client", "router"], help="zenoh mode (default client)")
    parser.add_argument("--mesh-config", help="JSON5 mesh configuration file (also SIMECS_MESH_CONFIG)")
    parser.add_argument("--node-id", help="unique name of this node on the mesh (default host-pid)")
    parser.add_argument("--log-level", default=None, help="DEBUG, INFO, WARNING (also SIMECS_LOG)")
    parser.add_argument(
        "--cpu",
        default=os.environ.get("SIMECS_CPU", "auto"),
        help="live-path nodes (hub, hot-feedback, viewer): auto = share the highest CPU, none, or a "
        "CPU number (also SIMECS_CPU); other nodes ignore it",
    )


def mesh_from_args(args: argparse.Namespace) -> MeshConfig:
    cfg = load_config(args.mesh_config)
    return cfg.with_overrides(connect=args.connect, listen=args.listen, mode=args.mode)


def main_for(node_cls: type[Node], argv: list[str] | None = None, prog: str | None = None) -> int:
    """Entry point of a node module: parse flags, run, exit cleanly (no lingering threads)."""
    parser = argparse.ArgumentParser(
        prog=prog or f"simecs node {node_cls.role}", description=node_cls.__doc__
    )
    node_arguments(parser)
    add = getattr(node_cls, "add_arguments", None)
    if add is not None:
        add(parser)
    args = parser.parse_args(argv)
    setup_logging(f"{node_cls.role}", args.log_level)
    faulthandler.enable()  # a crash in a native library leaves every thread's stack in the node's log
    try:
        node = node_cls.from_args(args)
        node.cpu_choice = args.cpu
        affinity.mesh_core(args.cpu)  # a bad --cpu fails here, with its reason, before joining the mesh
        code = node.run()
    except Exception as exc:
        log.error("%s failed: %s\n%s", node_cls.role, exc, traceback.format_exc())
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # zenoh's threads are closed with the session; do not wait on anything else
