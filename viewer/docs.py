"""The documentation window (paper §2.2): read-only hypertext over the model's components.

Pages come with the model description; links between them are written `doc:<id>` (as markdown link
targets or bare). A browser cannot follow such a link, and viser calls Python only from its widgets,
so each link becomes two things: a button under the page ("Links on this page"), and an in-text link
(`#simecs-doc/…` naming that button) which the tab's script (`browser.install_doc_links`) turns into
a click on the button. The window keeps a history so the user can go back, and shows each new page
from its top.

A page's raw HTML is escaped (markup.py): a model's text is shown, never run, in the user's browser.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any
from urllib.parse import quote

from simecs.mesh.protocol.model import DocPage

from .markup import escape_html

LINK_RE = re.compile(r"\[([^\]]+)\]\(doc:([A-Za-z0-9][A-Za-z0-9_.-]*)\)")
BARE_RE = re.compile(r"(?<![\w(/:])doc:([A-Za-z0-9](?:[A-Za-z0-9_.-]*[A-Za-z0-9])?)")


@dataclass
class Rendered:
    markdown: str
    links: list[tuple[str, str]]  # (page id, label), in order of first appearance, no repeats


LINK_PREFIX = "#simecs-doc/"  # an in-text link's target: this prefix and its button's label


def button_label(title: str) -> str:
    """The label of the button that follows a link to the page titled `title`."""
    return f"→ {title}"


def link_markdown(label: str, title: str) -> str:
    """An in-text link that clicks the button of the page titled `title`."""
    return f"[{label}]({LINK_PREFIX}{quote(button_label(title))})"


def render(page: DocPage, titles: dict[str, str]) -> Rendered:
    """Markdown of `page` with `doc:` links shown as in-text links, and the list of pages they point
    to; raw HTML shown as text.

    A link to a page the model does not have stays as plain text (it is not offered as a button).
    """
    links: list[tuple[str, str]] = []
    seen: set[str] = set()

    def add(target: str, label: str) -> None:
        if target in titles and target not in seen:
            seen.add(target)
            links.append((target, label))

    def linked(match: re.Match[str]) -> str:
        label, target = match.group(1), match.group(2)
        add(target, label)
        return link_markdown(label, titles[target]) if target in titles else label

    def bare(match: re.Match[str]) -> str:
        target = match.group(1)
        label = titles.get(target, target)
        add(target, label)
        return link_markdown(label, titles[target]) if target in titles else label

    text = LINK_RE.sub(linked, escape_html(page.markdown))
    text = BARE_RE.sub(bare, text)
    return Rendered(text, links)


class DocHistory:
    """Where the reader is, and the way back."""

    def __init__(self, root: str) -> None:
        self.root = root
        self.current = root
        self.back_stack: list[str] = []

    def go(self, page: str) -> None:
        if page != self.current:
            self.back_stack.append(self.current)
            self.current = page

    def back(self) -> bool:
        if not self.back_stack:
            return False
        self.current = self.back_stack.pop()
        return True

    def home(self) -> None:
        self.go(self.root)


class DocsWindow:
    """A docked panel with the current page, its links as buttons, Back / Contents / Up."""

    def __init__(
        self,
        gui: Any,
        pages: Sequence[DocPage],
        root: str,
        fetch: Callable[[str], None],
        place: Callable[[Any], None],
    ):
        self.gui = gui
        self.place = place  # docks the panel (layout.py)
        self.pages = {p.id: p for p in pages}
        self.titles = {p.id: p.title for p in pages}
        self.fetch = fetch  # asks the server for a page not carried in the description
        self.history = DocHistory(root if root in self.pages or not pages else pages[0].id)
        self.panel: Any = None
        self.tab: Any = None
        self.widgets: list[Any] = []
        self.shown = ""  # the page the panel shows

    @property
    def is_open(self) -> bool:
        return self.panel is not None

    def open(self) -> None:
        if self.panel is None:
            self._new_panel()
        self.show()

    def _new_panel(self) -> None:
        self.close()
        self.panel = self.gui.add_panel()
        self.tab = self.panel.add_tab("Documentation")
        self.place(self.panel)

    def close(self) -> None:
        if self.panel is not None:
            self.panel.remove()
        self.panel, self.tab = None, None
        self.widgets.clear()
        self.shown = ""

    def follow(self, page: str) -> None:
        self.history.go(page)
        self.show()

    def back(self) -> None:
        if self.history.back():
            self.show()

    def receive(self, page: DocPage) -> None:
        """A page the server sent: keep it, and show it if the reader is on it."""
        self.pages[page.id] = page
        if self.is_open and self.history.current == page.id:
            self.show()

    def show(self) -> None:
        current = self.history.current
        if self.panel is not None and self.shown not in ("", current):
            self._new_panel()  # a new page starts at its top, with its title and Back in view
        self.shown = current
        page = self.pages.get(current)
        if page is None:
            self.fetch(current)
            page = DocPage(current, "Loading…", f"_Asking the server for page `{current}`…_")
        rendered = render(page, self.titles)
        for w in self.widgets:
            w.remove()
        self.widgets.clear()
        with self.tab:
            nav = [
                label for label, ok in (("◀ Back", bool(self.history.back_stack)), ("Contents", True)) if ok
            ]
            if page.parent and page.parent in self.titles:
                nav.append("Up")
            nav.append("Close")
            group = self.gui.add_button_group("Go", tuple(nav))
            group.on_click(lambda e, parent=page.parent: self._nav(e.target.value, parent))
            self.widgets.append(group)
            body = rendered.markdown
            if not body.lstrip().startswith("#"):  # a page without its own heading gets its title
                body = f"## {page.title}\n\n{body}"
            self.widgets.append(self.gui.add_markdown(body))
            targets = list(rendered.links)
            for child in page.children:
                if child in self.titles and all(child != t for t, _ in targets):
                    targets.append((child, self.titles[child]))
            if targets:
                self.widgets.append(self.gui.add_markdown("**Links on this page**"))
            for target, label in targets:
                title = self.titles.get(target, label)
                b = self.gui.add_button(button_label(title), hint=f"page {target}")
                b.on_click(lambda _e, t=target: self.follow(t))
                self.widgets.append(b)

    def _nav(self, choice: str, parent: str) -> None:
        if choice == "◀ Back":
            self.back()
        elif choice == "Contents":
            self.follow(self.history.root)
        elif choice == "Up":
            self.follow(parent)
        elif choice == "Close":
            self.close()
