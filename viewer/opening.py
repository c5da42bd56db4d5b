"""The models window's side of a tab's session controller: the library and the user's sessions listed,
a new session made, another one opened or closed for good. Part of the session controller: it sees
the tab through its state, dispatcher, host and identity, and `attach(sid, snapshot)` makes a session
the tab's."""

from __future__ import annotations

from collections.abc import Callable

from simecs.mesh.client import NoReply, RemoteError
from simecs.mesh.protocol import messages as m

from . import events as ev
from .host import Claimant, Host
from .identity import Identity, NotLoggedIn
from .tab_state import TabState
from .workers import Dispatcher

Attach = Callable[[str, m.SessionSnapshot | None], bool]


class Opening:
    """Listing and opening sessions for one tab (`me`: the tab as a holder of sessions)."""

    def __init__(
        self,
        view: TabState,
        tasks: Dispatcher,
        host: Host,
        identity: Identity,
        attach: Attach,
        me: Claimant,
    ) -> None:
        self.c = view
        self.t = tasks
        self.host = host
        self.identity = identity
        self.attach = attach
        self.me = me

    def open_library(self, can_dismiss: bool = True) -> None:
        self.t.submit("Models", lambda: self.list_library(can_dismiss))

    def list_library(self, can_dismiss: bool) -> None:
        try:
            models = self.host.mc.list_models()  # the library is everyone's
        except (RemoteError, NoReply) as exc:
            self.t.fail("Cannot list the models", exc)
            models = []
        try:
            sessions = self.identity.mc.list_sessions(self.identity.user)
        except (RemoteError, NoReply, NotLoggedIn):
            sessions = []
        current = self.c.session.id if self.c.session is not None else ""
        login = not self.identity.logged_in
        self.t.emit(
            ev.LibraryListed(
                self.identity.user, models, sessions, current, can_dismiss and bool(current), login
            )
        )

    def set_user(self, name: str) -> None:
        try:
            changed = self.identity.choose(name)
        except ValueError as exc:
            self.t.notify("User name refused", str(exc), "error")
            return
        if not changed:
            return
        self.t.emit(ev.UserChanged(self.identity.user))
        if self.identity.secured:
            self.t.notify("User", f"Log in as **{self.identity.user}** with your password.", "info")
        else:
            self.t.notify(
                "User",
                f"You are now **{self.identity.user}**; reopen Models to see this user's sessions.",
                "ok",
            )

    def load_model(self, model_id: str) -> None:
        """A new session on `model_id` with its defaults, shown in this tab."""
        self.t.submit(f"Load {model_id}", lambda: self.open_new_now(model_id))

    def open_new_now(self, model_id: str) -> bool:
        """Create a session on `model_id` and show it (on a worker: it waits for the server)."""
        sc = self.identity.mc.create_session(self.identity.user, model_id)
        return self.open(sc.id, sc.created)

    def open_session(self, sid: str) -> None:
        self.t.submit("Open session", lambda: self.open(sid))

    def open(self, sid: str, snapshot: m.SessionSnapshot | None = None) -> bool:
        if (self.c.session is not None and self.c.session.id == sid) or self.attach(sid, snapshot):
            self.t.emit(ev.LibraryClosed())
            return True
        return False

    def close_session(self, sid: str) -> None:
        """End another of the user's sessions for good (from the models window)."""

        def job() -> None:
            if self.host.claims.held_by_other(sid, self.me):
                raise ValueError("that session is open in another tab: close it there")
            self.identity.mc.session(self.identity.user, sid).close()
            self.t.notify("Session closed", f"Session {sid[:8]}… is closed.", "ok")
            self.list_library(can_dismiss=True)

        self.t.submit("Close session", job)
