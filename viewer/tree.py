"""Component trees of parameters and variables (paper §2.2: "a tree in which those belonging to the
same component are grouped together under the same branch"), and how an item is labelled.

Pure data: the GUI panels in params.py draw these; tests check them without a browser.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from simecs.mesh.protocol.model import Parameter, Variable

from .units import labelled


@dataclass
class Component:
    """One branch: `path` is the dotted component name, `items` the parameters or variables on it."""

    path: str
    children: list[Component] = field(default_factory=list)
    items: list[Any] = field(default_factory=list)

    @property
    def label(self) -> str:
        return self.path.rsplit(".", 1)[-1]

    def count(self) -> int:
        """Items on this branch and below it."""
        return len(self.items) + sum(c.count() for c in self.children)

    def walk(self) -> Iterable[Component]:
        yield self
        for child in self.children:
            yield from child.walk()


def build_tree(items: Sequence[Parameter | Variable]) -> list[Component]:
    """Roots of the component tree of `items`, in the order components first appear.

    A component "joint1.motor" becomes the child "motor" of "joint1"; intermediate components are
    created even when they hold no items of their own.
    """
    roots: list[Component] = []
    index: dict[str, Component] = {}

    def node(path: str) -> Component:
        found = index.get(path)
        if found is not None:
            return found
        comp = Component(path)
        index[path] = comp
        if "." in path:
            node(path.rsplit(".", 1)[0]).children.append(comp)
        else:
            roots.append(comp)
        return comp

    for item in items:
        node(item.component or "(model)").items.append(item)
    return roots


def find(roots: Sequence[Component], path: str) -> Component | None:
    for root in roots:
        for comp in root.walk():
            if comp.path == path:
                return comp
    return None


def short_name(item: Parameter | Variable) -> str:
    """The item name without its component prefix: `joint1.motor.R` on `joint1.motor` is `R`."""
    prefix = item.component + "."
    return item.name[len(prefix) :] if item.component and item.name.startswith(prefix) else item.name


def fmt(value: float) -> str:
    """A number as people read it: no float noise, no exponent for ordinary magnitudes."""
    if value == 0:
        return "0"
    if value.is_integer() and abs(value) < 1e9:
        return str(int(value))
    text = f"{value:.6g}"
    return text


#: What may stand between typed numbers: commas, spaces, semicolons.
_BETWEEN_NUMBERS = re.compile(r"[\s,;]+")


def parse_numbers(text: str) -> list[float]:
    """Numbers as people type them in a field ("0.1, 0.2 0.3"); ValueError when one is not a number."""
    return [float(part) for part in _BETWEEN_NUMBERS.split(text.strip()) if part]


def numbers_text(values: Sequence[float]) -> str:
    """Numbers as `parse_numbers` reads them back."""
    return ", ".join(fmt(float(x)) for x in values)


def param_label(p: Parameter, whole_name: bool = False) -> str:
    """`kp_pos [1/s]` under its component; `joint3.ctrl.kp_pos [1/s]` among others' (a search)."""
    return labelled(p.name if whole_name else short_name(p), p.unit)


def param_hint(p: Parameter, default: float | None = None) -> str:
    """The tool tip of a parameter (paper §5.2: descriptions appear as tool tip texts)."""
    unit = "" if p.unit in ("", "-") else f" {p.unit}"
    parts = [p.description.rstrip(".") + "." if p.description else p.name]
    parts.append(
        f"Allowed: {fmt(p.min)} … {fmt(p.max)}{unit}" + (", whole numbers" if p.integer else "") + "."
    )
    if default is not None:
        parts.append(f"Default {fmt(default)}{unit}.")
    if p.appearance:
        parts.append("Changes the 3D shape.")
    parts.append(f"({p.name})")
    return " ".join(parts)


def var_label(v: Variable, whole_name: bool = False) -> str:
    return labelled(v.name if whole_name else short_name(v), v.unit)


def var_hint(v: Variable) -> str:
    return f"{v.description} ({v.name})" if v.description else v.name


def search(items: Sequence[Any], text: str, limit: int = 40) -> list[Any]:
    """Items whose name or description contains every word of `text` (case-insensitive)."""
    words = [w for w in text.lower().split() if w]
    if not words:
        return []
    out = []
    for item in items:
        hay = f"{item.name} {getattr(item, 'description', '')}".lower()
        if all(w in hay for w in words):
            out.append(item)
            if len(out) >= limit:
                break
    return out
