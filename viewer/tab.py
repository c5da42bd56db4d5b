"""One browser tab = one user with their own session (paper §3.2: the Simulation Interface, which
places every visual sub-component on screen).

The tab is glue: a `SessionController` (`session.py`) holds the session and makes every request;
the tab builds the toolbar and the models window for its browser client, builds a `ModelPage`
(`page.py`) when a model is loaded, connects their callbacks to controller actions, and applies the
controller's events to them inside `client.atomic()`. It sees the viewer node only as a `Host`.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from . import browser
from . import events as ev
from .host import Host
from .library import LibraryWindow
from .page import ModelPage
from .run import Toolbar
from .session import SessionController

log = logging.getLogger("simecs.viewer")


class Tab:
    """The session controller and the panels of one browser tab."""

    def __init__(self, host: Host, client: Any) -> None:
        self.client = client
        self.gui = client.gui
        self.controller = SessionController(host, client.client_id)
        self.toolbar: Toolbar | None = None
        self.page: ModelPage | None = None
        self.library: LibraryWindow | None = None
        self.lock = threading.RLock()  # one event or panel change at a time
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
        """Build the page frame, find out who this is and which session the tab had, and restore it."""
        self.build_frame()
        memory = browser.recall(self.client)  # waits for the browser (not for the server)
        if not self.closed:
            self.controller.start(memory.session, memory.user)

    def build_frame(self) -> None:
        """What every tab shows before a model is loaded: the theme, the docked panel, the toolbar."""
        gui = self.gui
        gui.configure_theme(show_share_button=False, control_width="large", show_logo=False)
        gui.main_panel.dock_left()
        gui.main_panel.set_width(400)
        gui.set_panel_label("simecs")
        self.client.scene.set_up_direction("+z")
        self.toolbar = Toolbar(gui, self._on_window, self.controller.control.run_action)

    def close(self) -> None:
        """The tab went away (closed or reloading): the session stays on the server."""
        self.controller.close()

    def tick(self) -> None:
        """About 10 times a second: send edits whose pause has come, redraw plots with new data."""
        if self.closed:
            return
        self.controller.tick()
        page, stream = self.page, self.controller.stream
        if page is not None and stream is not None:
            with self.lock:
                page.plots.redraw(stream.live)

    # -- controller events -------------------------------------------------------------------------
    def _on_event(self, event: ev.Event) -> None:
        if self.closed:
            return
        with self.lock, self.client.atomic():
            handler = self._apply.get(type(event))
            if handler is not None:
                handler(event)
            page = self.page
            if page is not None:
                page.apply(event)

    def _build(self, event: ev.ModelLoaded) -> None:
        if self.page is not None:
            self.page.remove()
            self.page = None
        self.page = ModelPage(self.client, self.controller)
        browser.set_title(self.client, f"simecs · {event.model.name}")

    def _show_state(self, event: ev.StateShown) -> None:
        if self.toolbar is not None:
            self.toolbar.show(event.state, event.replay)

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
    def _on_window(self, name: str) -> None:
        if name == "Models":
            self.controller.opening.open_library(can_dismiss=True)
            return
        page = self.page
        if page is None:
            self.controller.notify(name, "Load a model first (Models).", "warning")
            return
        with self.lock, self.client.atomic():
            if name == "Initialise":
                page.toggle_init()
            elif name == "Settings":
                page.open_settings()
            elif name == "Documentation":
                page.toggle_docs()
