"""A tab's viser client whose every widget and scene callback runs on the tab's loop (loop.py).

viser runs a callback of a user's click on its thread pool, several at once and beside the tab's
events and ticks; the panels would then change under each other. The tab hands its panels this
client instead: every `add_*` of its `gui` and `scene` returns the real handle, with its callback
registrars (`on_click`, `on_update`, ...) wrapped so the callbacks they take run on the loop, in the
order the page's messages came (`TabLoop.wrap_widget`). Nothing
else changes: a panel uses viser's API as documented. `tests/test_viewer_loop.py` checks that every
callback a loaded page registered is one of these.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from .loop import TabLoop

#: The methods of viser's handles that take a callback.
REGISTRARS = ("on_click", "on_update", "on_upload", "on_hold", "on_drag", "on_drag_start", "on_drag_end")


def bind_callbacks(handle: Any, loop: TabLoop) -> Any:
    """`handle` with every callback registrar it has wrapped to run its callbacks on `loop`."""
    for name in REGISTRARS:
        register = getattr(handle, name, None)
        if callable(register):
            setattr(handle, name, _registrar(register, loop))
    return handle


def _registrar(register: Callable[..., Any], loop: TabLoop) -> Callable[..., Any]:
    def on_loop(func: Callable[..., Any] | None = None, *args: Any, **kwargs: Any) -> Any:
        if func is None:  # used as a decorator with arguments: @button.on_hold(callback_hz=10)
            decorate = register(None, *args, **kwargs)
            return lambda f: decorate(loop.wrap_widget(f))
        register(loop.wrap_widget(func), *args, **kwargs)
        return func

    return on_loop


class LoopApi:
    """viser's GUI or scene API of one client, every handle it adds bound to the loop."""

    def __init__(self, api: Any, loop: TabLoop) -> None:
        self._api = api
        self._loop = loop

    def __getattr__(self, name: str) -> Any:
        attr = getattr(self._api, name)
        if not (name.startswith("add_") and callable(attr)):
            return attr

        def add(*args: Any, **kwargs: Any) -> Any:
            return bind_callbacks(attr(*args, **kwargs), self._loop)

        return add


class LoopClient:
    """A viser client (`ClientHandle`) as a tab's panels use it: `gui` and `scene` bound to the loop,
    everything else (camera, notifications, downloads, `atomic`) the client's own."""

    def __init__(self, client: Any, loop: TabLoop) -> None:
        self._client = client
        self.loop = loop
        self.gui = LoopApi(client.gui, loop)
        self.scene = LoopApi(client.scene, loop)

    def __getattr__(self, name: str) -> Any:
        return getattr(self._client, name)
