"""One browser tab = one user with their own session (paper §3.2: the Simulation Interface, which
places every visual sub-component on screen).

The tab is glue: a `SessionController` (`session.py`) holds the session and makes every request;
the tab builds the toolbar and the models window for its browser client, builds a `ModelPage`
(`page.py`) when a model is loaded, connects their callbacks to controller actions, and applies the
controller's events to them inside `client.atomic()`. It sees the viewer node only as a `Host`.

Everything the tab shows is changed on one thread, the tab's loop (loop.py): the panels get a client
whose callbacks run there (loop_client.py), the controller's events are delivered there, and the
viewer node posts the tab's tick there. So no lock guards a panel, and a tab whose page is slow slows
only itself.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

from simecs.mesh.protocol import phases

from . import browser
from . import events as ev
from .docs import LINK_PREFIX
from .host import Host
from .layout import Layout
from .library import LibraryWindow
from .loop import TabLoop
from .loop_client import LoopClient
from .page import ModelPage
from .run import RunBar, Toolbar, key_buttons
from .send_order import install_send_order
from .session import SessionController

log = logging.getLogger("simecs.viewer")
TICKS_PER_S = 10  # the viewer node ticks every tab this often (app.py)
BEAT_EVERY = round(browser.BEAT_S * TICKS_PER_S)  # ticks between beats: the viewer serves the page
READOUT_EVERY = 2  # ticks between refreshes of the digital readout (5 a second)
VIEW_KEPT_EVERY = 10  # ticks (about a second) between looks at what the tab shows, kept for a reload


class Tab:
    """The session controller and the panels of one browser tab (`loop`: the tab's, by default a
    thread of its own; a test passes a driven one)."""

    def __init__(self, host: Host, client: Any, loop: TabLoop | None = None) -> None:
        self.controller = SessionController(host, client.client_id, loop=loop)
        self.loop = self.controller.loop
        self.raw_client = client  # viser's own: the browser's memory is read through it off the loop
        self.client = LoopClient(client, self.loop)
        self.gui = self.client.gui
        self.toolbar: Toolbar | None = None
        self.run_bar: RunBar | None = None
        self.page: ModelPage | None = None
        self.library: LibraryWindow | None = None
        self.layout = Layout()  # until the browser tells its viewport
        self.remembered_view: dict[str, Any] = {}  # what the tab showed before a reload (browser.py)
        self._kept_view: dict[str, Any] = {}  # what the tab's memory holds now
        self._ticks = 0
        self._apply: dict[type, Callable[[Any], None]] = {
            ev.Notice: lambda e: browser.notify(client, e.title, e.body, e.kind),
            ev.UserChanged: lambda e: browser.remember_user(client, e.user),
            ev.SessionRemembered: lambda e: browser.remember_session(client, e.session),
            ev.LibraryListed: self._show_library,
            ev.LibraryClosed: lambda _e: self._close_library(),
            ev.ModelLoaded: self._build,
            ev.StateShown: self._show_state,
            ev.Download: lambda e: client.send_file_download(e.filename, e.data, save_immediately=True),
        }
        self.controller.subscribe(self._on_event)

    @property
    def closed(self) -> bool:
        return self.controller.closed

    # -- lifecycle ---------------------------------------------------------------------------------
    def start(self) -> None:
        """Build the page frame, find out who this is and which session the tab had, and restore it.
        Returns at once: the browser's memory is read on a worker (it waits for the browser)."""
        self.loop.post(self.build_frame)
        self.controller.submit("Open your session", self._recall, "io")

    def _recall(self) -> None:
        memory = browser.recall(self.raw_client)  # waits for the browser (not for the server)
        log.info(
            "tab %s: the browser remembers session %s, viewport %sx%s",
            self.raw_client.client_id,
            memory.session or "(none)",
            memory.width,
            memory.height,
        )
        self.loop.call(lambda: self._remembered(memory))

    def _remembered(self, memory: browser.TabMemory) -> None:
        """On the loop: the page placed for the browser's viewport, and the tab's session reopened."""
        if self.closed:
            return
        self.remembered_view = memory.view
        if memory.width and memory.height:
            with self.client.atomic():
                self.layout = Layout(memory.width, memory.height)
                self.place_frame()
        self.controller.start(memory.session, memory.user)

    def build_frame(self) -> None:
        """What every tab shows before a model is loaded: the theme, the docked panel, the toolbar."""
        gui = self.gui
        gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        gui.set_panel_label("simecs")
        self.client.scene.set_up_direction("+z")
        self.toolbar = Toolbar(gui, self._on_window, self._on_view)  # in the main panel, at its top
        self.run_bar = RunBar(gui, self.controller.control.run_action, self._on_preview)
        self.place_frame()
        browser.install_doc_links(self.client, LINK_PREFIX)
        browser.install_watchdog(self.client)
        browser.install_page_rules(self.client, {p: key_buttons(p) for p in phases.PHASES})
        install_send_order(self.client)

    def place_frame(self) -> None:
        """The trees' panel and the run bar where this viewport's layout puts them."""
        self.layout.place_main(self.gui)
        if self.run_bar is not None:
            self.layout.place_run_bar(self.run_bar.panel)

    def close(self) -> None:
        """The tab went away (closed or reloading): the session stays on the server."""
        self.controller.close()

    def tick(self) -> None:
        """About 10 times a second, on the loop: send edits whose pause has come, redraw plots with
        new data."""
        if self.closed:
            return
        self.controller.tick()
        page, stream = self.page, self.controller.stream
        if page is not None and stream is not None:
            page.plots.redraw(stream.live)
        if page is not None and self.run_bar is not None and self._ticks % READOUT_EVERY == 0:
            self.run_bar.show_readout(page.readout())
        self._ticks += 1
        if self._ticks % BEAT_EVERY == 0:
            browser.beat(self.client)
        if page is not None and self._ticks % VIEW_KEPT_EVERY == 0:
            self._keep_view(page)

    def _keep_view(self, page: ModelPage) -> None:
        """The camera, the open plots and the shown component into the tab's memory, when changed."""
        view = page.view_state()
        if view != self._kept_view:
            self._kept_view = view
            browser.remember_view(self.client, view)

    # -- controller events -------------------------------------------------------------------------
    def _on_event(self, event: ev.Event) -> None:
        """A controller event (delivered on the loop) applied to the panels in one batch."""
        if self.closed:
            return
        with self.client.atomic():
            handler = self._apply.get(type(event))
            if handler is not None:
                handler(event)
            page = self.page
            if page is not None:
                page.apply(event)
        # An event is what a user waits for (a plan, a state, an answer): sent now, not at the end of
        # viser's next 1/60 s window.
        self.client.flush()

    def _build(self, event: ev.ModelLoaded) -> None:
        if self.page is not None:
            self.page.remove()
            self.page = None
        self.page = ModelPage(
            self.client, self.controller, self.layout, self.run_bar.tab if self.run_bar is not None else None
        )
        view, self.remembered_view = self.remembered_view, {}
        if view.get("session") == event.session:  # a reload of this session: as it was
            self.page.restore(view)
        browser.set_title(self.client, f"simecs · {event.model.name}")

    def _show_state(self, event: ev.StateShown) -> None:
        if self.run_bar is not None:
            self.run_bar.show(event.state, event.replay, event.until_stopped)
        browser.tell_phase(self.client, event.state.phase if event.state is not None else "")

    def _show_library(self, event: ev.LibraryListed) -> None:
        c = self.controller
        self._close_library()
        self.library = LibraryWindow(
            self.gui,
            event.user,
            event.models,
            event.sessions,
            event.current,
            on_load=c.opening.load_model,
            on_open=c.opening.open_session,
            on_close_session=c.opening.close_session,
            on_user=c.opening.set_user,
            can_dismiss=event.can_dismiss,
            on_login=c.login if event.login else None,
        )

    def _close_library(self) -> None:
        if self.library is not None:
            self.library.close()
            self.library = None

    # -- toolbar -------------------------------------------------------------------------------------
    def _on_preview(self) -> None:
        page = self.page
        if page is None:
            self.controller.notify("Preview", "Load a model first (Models).", "warning")
            return
        page.preview_motion()

    def _on_view(self, name: str) -> None:
        page = self.page
        if page is None:
            self.controller.notify(name, "Load a model first (Models).", "warning")
            return
        with self.client.atomic():
            page.look(name)

    def _on_window(self, name: str) -> None:
        log.info("tab %s: window %s asked", self.raw_client.client_id, name)  # a click that arrived
        if name == "Models":
            self.controller.opening.open_library(can_dismiss=True)
            return
        page = self.page
        if page is None:
            self.controller.notify(name, "Load a model first (Models).", "warning")
            return
        with self.client.atomic():
            if name == "Initialise":
                page.show_init()
            elif name == "Settings":
                page.open_settings()
            elif name == "Documentation":
                page.toggle_docs()
