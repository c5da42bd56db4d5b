"""Fixtures that start real node processes on a mesh of their own.

Every test gets its own hub on a unix socket in a fresh temporary folder (no ports, no races, no
cross-talk with other tests or machines), with multicast scouting and shared memory off. Every wait
is bounded; every process is stopped (SIGTERM, then SIGKILL) when the test ends.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
from simecs.mesh.client import MeshClient, NoReply, RemoteError, SessionClient
from simecs.mesh.process.config import open_session
from simecs.nodes.local_mesh import LocalMesh, clean_env
from simecs.nodes.local_mesh import wait_until as wait_until  # the tests import it from here
from simecs.nodes.secure import SecureFolder
from simecs.testing import browser as chromium

ARTIFACTS = Path(__file__).resolve().parent.parent / "artifacts"

Mesh = LocalMesh
mesh_env = clean_env
# In-process clients too never take this machine's user's file (`simecs up`) for the test's mesh.
os.environ["SIMECS_CLIENT_CONFIG"] = ""


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The files with browser tests first, each file's tests in their order: `make test` hands whole
    files to its workers in this order (`--dist loadfile`), and those files are the longest (a minute
    or more each); handed out last, as their names sort, one of them ran alone at the end."""
    with_browser = {item.path for item in items if "browser" in getattr(item, "fixturenames", ())}
    items.sort(key=lambda item: item.path not in with_browser)  # stable: the rest keep their order


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Iterator[None]:
    """A failing test on a mesh shows its nodes' logs in its report and keeps its mesh folder (node
    logs, data, recordings) under artifacts/failed/: a flaky failure can be read after the fact."""
    outcome = yield
    report = outcome.get_result()  # type: ignore[attr-defined]
    if not report.failed:
        return
    funcargs = getattr(item, "funcargs", {})
    meshes = [v.mesh if isinstance(v, (Secured, Service)) else v for v in funcargs.values()]
    for mesh in [m for m in meshes if isinstance(m, LocalMesh)][:1]:
        kept = ARTIFACTS / "failed" / "".join(c if c.isalnum() or c in "-_." else "_" for c in item.nodeid)
        try:
            shutil.rmtree(kept, ignore_errors=True)
            shutil.copytree(mesh.folder, kept, ignore=shutil.ignore_patterns("*.sock"), dirs_exist_ok=True)
            where = f"mesh folder kept in {kept}"
        except OSError as e:
            where = f"mesh folder not kept: {e}"
        logs = [f"--- {name}.log (last 4000 characters)\n{mesh.log(name)}" for name in mesh.procs]
        report.sections.append((f"node logs ({report.when})", "\n".join([where, *logs])))
        browser = funcargs.get("browser")
        if isinstance(browser, ConsoleKeepingBrowser):
            browser.keep_pages(kept)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class Secured:
    """A secured mesh as `simecs up --secure` makes it: TLS hub on loopback, users ann and bob, the
    watcher eve, the generated access rules, the service nodes joined as the service."""

    mesh: LocalMesh
    folder: SecureFolder
    passwords: dict[str, str]
    node_config: str

    def login(self, user: str, password: str | None = None) -> MeshClient:
        cfg = self.mesh.config.as_user(user, self.passwords[user] if password is None else password, 800)
        client = MeshClient.open(cfg, timeout=3.0)
        self.mesh.clients.append(client)
        return client


@pytest.fixture
def secured() -> Iterator[Secured]:
    mesh = LocalMesh(endpoint=f"tls/127.0.0.1:{free_port()}")
    try:
        service = mesh.start_secured({"ann": "user", "bob": "user", "eve": "watcher"})
        yield Secured(mesh, service.folder, service.passwords, service.node_config)
    finally:
        mesh.close()


@pytest.fixture
def mesh() -> Iterator[LocalMesh]:
    m = LocalMesh()
    try:
        m.start_hub()
        yield m
    finally:
        m.close()


@dataclass
class Service:
    mesh: LocalMesh
    data_dir: Path

    @property
    def client(self) -> MeshClient:
        return self.mesh.client()


def start_service(
    mesh: LocalMesh,
    max_running: int = 4,
    extra_simulator: tuple[str, ...] = (),
    extra_proxy: tuple[str, ...] = (),
) -> Service:
    return Service(mesh, mesh.start_service(max_running, extra_simulator, extra_proxy))


def restart_every_node(mesh: LocalMesh) -> Service:
    """Stop the service nodes and the hub, start them again on the same data (a server reboot)."""
    for name in ("hotfeedback", "simulator", "proxy"):
        mesh.stop(name)
    mesh.stop("hub")
    mesh.clients.clear()
    mesh.start_hub()
    return start_service(mesh)


@pytest.fixture
def service(request: pytest.FixtureRequest) -> Iterator[Service]:
    """Hub, proxy, simulator and hot-feedback on an isolated mesh, for this test alone (it may stop,
    kill or restart its nodes); with the mark `shares_service`, the module's (`shared_service`)."""
    if request.node.get_closest_marker("shares_service") is not None:
        yield from shared_service(request.getfixturevalue("service_keeper"))
    else:
        yield start_service(request.getfixturevalue("mesh"))


class SessionKeepingClient(MeshClient):
    """A client that keeps the sessions it opened, so that a test on a shared service closes them
    after it: the next test finds no run going and its user's quotas free."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.opened: list[SessionClient] = []

    def create_session(self, user: str, model_id: str) -> SessionClient:
        session = super().create_session(user, model_id)
        self.opened.append(session)
        return session

    def close_opened(self) -> None:
        for session in self.opened:
            try:
                session.close()
            except (RemoteError, NoReply):
                pass  # closed by the test already, or its node gone (the next test gets a new service)
        self.opened.clear()


@dataclass
class SharedService(Service):
    """The module's service as one test sees it: its own client, whose sessions close after it."""

    own_client: SessionKeepingClient

    @property
    def client(self) -> MeshClient:
        return self.own_client


#: The processes of a service (`start_service`) and its hub.
SERVICE_NODES = ("hub", "proxy", "simulator", "hotfeedback")


class ServiceKeeper:
    """One service for the tests of a module that leave its nodes alone (starting one costs 2-4 s on a
    loaded 2-core machine): a new one after a test whose nodes did not all survive it."""

    def __init__(self) -> None:
        self.service: Service | None = None

    def healthy(self) -> Service:
        if self.service is not None:
            procs = self.service.mesh.procs
            if all(name in procs and procs[name].poll() is None for name in SERVICE_NODES):
                return self.service
            self.service.mesh.close()
        self.service = None
        mesh = LocalMesh()
        try:
            mesh.start_hub()
            self.service = start_service(mesh)
        except BaseException:
            mesh.close()  # a node that never came up: stop the others, or they outlive the tests
            raise
        return self.service

    def close(self) -> None:
        if self.service is not None:
            self.service.mesh.close()


@pytest.fixture(scope="module")
def service_keeper() -> Iterator[ServiceKeeper]:
    keeper = ServiceKeeper()
    try:
        yield keeper
    finally:
        keeper.close()


def shared_service(service_keeper: ServiceKeeper) -> Iterator[SharedService]:
    """The module's service (hub, proxy, simulator, hot-feedback), shared by the tests marked
    `shares_service`: they neither stop nor restart its nodes, and the sessions a test opens through
    `client` are closed after it."""
    base = service_keeper.healthy()
    client = SessionKeepingClient(
        open_session(base.mesh.config), timeout=10.0, owns_session=True, seal=base.mesh.client().seal
    )
    try:
        yield SharedService(base.mesh, base.data_dir, client)
    finally:
        client.close_opened()
        client.close()


@pytest.fixture
def browser() -> Iterator[Any]:
    """A headless chromium. Missing, it fails the test with what to install (`make test` installs it):
    a browser test that skips hides a missing install step."""
    missing = chromium.browser_missing()
    if missing:
        pytest.fail(f"the browser tests need chromium: {missing}", pytrace=False)
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        b = chromium.launch(pw)
        kept = ConsoleKeepingBrowser(b)
        try:
            yield kept
        finally:
            if kept.lines:  # shown by pytest when the test failed
                print("----- browser console (errors, warnings, ours) -----", *kept.lines[-100:], sep="\n")
            b.close()


class ConsoleKeepingBrowser:
    """The browser, keeping what its pages say went wrong (console errors and warnings, uncaught
    exceptions): a failure on a CI machine, where the page is gone, is read from them."""

    def __init__(self, browser: Any) -> None:
        self._browser = browser
        self.lines: list[str] = []
        self.pages: list[Any] = []

    def keep_pages(self, folder: Path) -> None:
        """A screenshot and the visible text of every page still open, beside the mesh folder of a
        failed test: what the page showed when the test gave up."""
        for k, page in enumerate(self.pages):
            try:
                if page.is_closed():
                    continue
                page.screenshot(path=str(folder / f"page{k + 1}.png"), timeout=10_000)
                (folder / f"page{k + 1}.txt").write_text(page.inner_text("body", timeout=10_000))
                sent = page.evaluate(
                    "() => [performance.now(), window.__simecsSent || [],"
                    " (window.__simecs || {}).pointer || [], (window.__simecs || {}).clicks || []]"
                )
                (folder / f"page{k + 1}.sent.json").write_text(json.dumps(sent))  # viewer/send_order.py
            except Exception as exc:  # the page or the browser may be gone: keep what can be kept
                self.lines.append(f"page {k + 1} not kept: {exc}")

    def __getattr__(self, name: str) -> Any:
        return getattr(self._browser, name)

    def _watch(self, page: Any) -> Any:
        def said(msg: Any) -> None:
            if msg.type in ("error", "warning") or msg.text.startswith("simecs "):
                self.lines.append(f"{time.strftime('%H:%M:%S')} console {msg.type}: {msg.text}")

        self.pages.append(page)
        page.on("console", said)
        page.on("pageerror", lambda exc: self.lines.append(f"{time.strftime('%H:%M:%S')} page error: {exc}"))
        return page

    def new_page(self, **options: Any) -> Any:
        return self._watch(self._browser.new_page(**options))

    def new_context(self, **options: Any) -> Any:
        context = self._browser.new_context(**options)
        context.on("page", self._watch)
        return context


@pytest.fixture(scope="module")
def server() -> Iterator[Any]:
    """A viser server on a free loopback port, without a browser: the viewer's panels are built on it
    and driven by injected events (test_viewer_panels.py, test_viewer_tab.py, test_viewer_cartesian.py)."""
    import viser

    srv = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    try:
        yield srv
    finally:
        srv.stop()


def children(parent: int) -> list[tuple[int, str]]:
    """The child processes of `parent`: (pid, command line)."""
    out = subprocess.run(["ps", "-o", "pid=,args=", "--ppid", str(parent)], capture_output=True, text=True)
    return [(int(line.split()[0]), line) for line in out.stdout.splitlines()]


def group_members(leader: int) -> list[tuple[int, int, str]]:
    """The processes of `leader`'s process group but itself: (pid, parent pid, command line)."""
    out = subprocess.run(["ps", "-e", "-o", "pid=,ppid=,pgid=,args="], capture_output=True, text=True)
    rows = [line.split(maxsplit=3) for line in out.stdout.splitlines()]
    return [
        (int(r[0]), int(r[1]), r[3] if len(r) > 3 else "")
        for r in rows
        if int(r[2]) == leader and int(r[0]) != leader
    ]


def worker_forks_of(simulator: int) -> list[int]:
    """The simulator's worker fork server (nodes/worker_forks.py), in its process group: forked from
    the node fork server the tests start nodes from, or started by the simulator as a process."""
    members = group_members(simulator)
    inside = {pid for pid, _, _ in members}
    return [
        pid
        for pid, ppid, args in members
        if ppid not in inside | {simulator} or (ppid == simulator and "simecs.nodes.worker_forks" in args)
    ]


def worker_pids(simulator: int) -> list[int]:
    """The simulator's workers: those its fork server forked, and any it started as processes of
    their own (the rest of its process group)."""
    forks = set(worker_forks_of(simulator))
    return [pid for pid, _, _ in group_members(simulator) if pid not in forks]
