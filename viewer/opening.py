"""The models window's side of a tab's session controller: the library and the user's sessions listed,
a new session made, another one opened or closed for good. Part of `SessionController` (session.py),
which attaches the session opened."""

from __future__ import annotations

from typing import TYPE_CHECKING

from simecs.mesh import messages as m
from simecs.mesh.client import NoReply, RemoteError

from . import events as ev
from .identity import NotLoggedIn

if TYPE_CHECKING:
    from .session import SessionController


class Opening:
    """Listing and opening sessions for one controller."""

    def __init__(self, controller: SessionController) -> None:
        self.c = controller

    def open_library(self, can_dismiss: bool = True) -> None:
        self.c.submit("Models", lambda: self.list_library(can_dismiss))

    def list_library(self, can_dismiss: bool) -> None:
        try:
            models = self.c.host.mc.list_models()  # the library is everyone's
        except (RemoteError, NoReply) as exc:
            self.c.fail("Cannot list the models", exc)
            models = []
        try:
            sessions = self.c.mc.list_sessions(self.c.user)
        except (RemoteError, NoReply, NotLoggedIn):
            sessions = []
        current = self.c.session.id if self.c.session is not None else ""
        login = not self.c.identity.logged_in
        self.c.emit(
            ev.LibraryListed(self.c.user, models, sessions, current, can_dismiss and bool(current), login)
        )

    def set_user(self, name: str) -> None:
        try:
            changed = self.c.identity.choose(name)
        except ValueError as exc:
            self.c.notify("User name refused", str(exc), "error")
            return
        if not changed:
            return
        self.c.emit(ev.UserChanged(self.c.user))
        if self.c.identity.secured:
            self.c.notify("User", f"Log in as **{self.c.user}** with your password.", "info")
        else:
            self.c.notify(
                "User", f"You are now **{self.c.user}**; reopen Models to see this user's sessions.", "ok"
            )

    def load_model(self, model_id: str) -> None:
        """A new session on `model_id` with its defaults, shown in this tab."""
        self.c.submit(f"Load {model_id}", lambda: self.open_new_now(model_id))

    def open_new_now(self, model_id: str) -> bool:
        """Create a session on `model_id` and show it (on a worker: it waits for the server)."""
        sc = self.c.mc.create_session(self.c.user, model_id)
        return self.open(sc.id, sc.created)

    def open_session(self, sid: str) -> None:
        self.c.submit("Open session", lambda: self.open(sid))

    def open(self, sid: str, snapshot: m.SessionSnapshot | None = None) -> bool:
        if (self.c.session is not None and self.c.session.id == sid) or self.c._attach(sid, snapshot):
            self.c.emit(ev.LibraryClosed())
            return True
        return False

    def close_session(self, sid: str) -> None:
        """End another of the user's sessions for good (from the models window)."""

        def job() -> None:
            if self.c.host.claims.held_by_other(sid, self.c):
                raise ValueError("that session is open in another tab: close it there")
            self.c.mc.session(self.c.user, sid).close()
            self.c.notify("Session closed", f"Session {sid[:8]}… is closed.", "ok")
            self.list_library(can_dismiss=True)

        self.c.submit("Close session", job)
