"""The models window (paper §2.2 step 1, §5.2 toolbar): who you are, the server's model library with
summaries, and your sessions, to load a model or go back to earlier work.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from simecs.mesh.protocol import messages as m
from simecs.mesh.protocol.model import CONTROL_SYSTEM_TITLES, ModelSummary

from .markup import escape_html

LEVEL_NAMES = {
    "direct_input": "direct input",
    "joint_path": "joint path",
    "cartesian_path": "Cartesian path",
    "action": "actions",
    "task": "tasks",
    "mission": "missions",
}


def model_markdown(s: ModelSummary) -> str:
    """The library's entry of a model: as the paper lists them, with its control systems."""
    levels = ", ".join(LEVEL_NAMES.get(c, c) for c in s.command_levels) or "none"
    systems = ", ".join(CONTROL_SYSTEM_TITLES.get(c, c) for c in s.control_systems)
    return (
        f"**{escape_html(s.name)}**  \n{escape_html(s.summary)}\n\n"
        f"{s.joints} joints · commands: {levels} · id `{s.id}`  \n"
        f"control systems (Settings): {systems}"
    )


def session_label(entry: m.SessionEntry) -> str:
    return f"{entry.model_id} · {entry.phase} · {entry.session[:8]}"


class LibraryWindow:
    """A modal: user name, models (Load), the user's sessions (Open / Close)."""

    def __init__(
        self,
        gui: Any,
        user: str,
        models: Sequence[ModelSummary],
        sessions: Sequence[m.SessionEntry],
        current: str,
        on_load: Callable[[str], None],
        on_open: Callable[[str], None],
        on_close_session: Callable[[str], None],
        on_user: Callable[[str], None],
        can_dismiss: bool,
        on_login: Callable[[str], None] | None = None,
    ) -> None:
        self.modal = gui.add_modal("Models")
        with self.modal:
            self.user = gui.add_text(
                "User", user, hint="your name on this server; your sessions are kept under it"
            )
            self.on_user = on_user
            self.user.on_update(self._user_edited)
            if on_login is not None:  # a secured server: nothing before the password
                gui.add_markdown("This server knows its users: log in with your password.")
                password = gui.add_text("Password", "", hint="the password your administrator gave you")
                # viser has no password input: the browser masks this one (CSS). docs/LAN.md: serve the
                # viewer over TLS on a LAN, the password goes to the viewer as typed.
                field = f"label[for='{password._impl.uuid}']"
                gui.add_html(
                    f"<style>div:has(> div > p > {field}) input {{-webkit-text-security: disc;}}</style>"
                )
                login = gui.add_button("Log in", color="green")
                login.on_click(lambda _e: on_login(str(password.value)))
                return
            gui.add_markdown("**Library**: load a model to start a new session with its default values.")
            if not models:
                gui.add_markdown("_The server offers no model (is the proxy node running?)._")
            for s in models:
                gui.add_markdown(model_markdown(s))
                b = gui.add_button(f"Load {s.name}", color="green", hint=f"new session on {s.id}")
                b.on_click(lambda _e, mid=s.id: on_load(mid))
            others = [e for e in sessions if e.session != current]
            mine = next((e for e in sessions if e.session == current), None)
            gui.add_markdown(
                "**Your sessions**: "
                + ("open one to continue it in this tab." if others else "_no other session._")
                + (f"  \nThis tab: {session_label(mine)}" if mine else "")
            )
            for entry in others:
                sid = entry.session
                gui.add_markdown(session_label(entry))
                o = gui.add_button(f"Open {sid[:8]}", hint="continue this session in this tab")
                o.on_click(lambda _e, sid=sid: on_open(sid))
                c = gui.add_button(f"Close {sid[:8]}", color="red", hint="end this session for good")
                c.on_click(lambda _e, sid=sid: on_close_session(sid))
            if can_dismiss:
                done = gui.add_button("Back to the model", color="gray")
                done.on_click(lambda _e: self.close())

    def _user_edited(self, event: Any) -> None:
        if event.client is not None:
            self.on_user(str(self.user.value))

    def close(self) -> None:
        if not self.modal.closed:
            self.modal.close()
