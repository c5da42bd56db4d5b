"""The viewer's structure: the controller knows nothing of viser, nothing imports the app, no module
builds column names, keys or phase sets of its own, no import cycle; loopback by default; one live tab
per session."""

from __future__ import annotations

import ast
from pathlib import Path
from types import SimpleNamespace

from simecs.viewer.host import Claims

VIEWER = Path(__file__).resolve().parent.parent / "viewer"
#: Modules of the session controller and what it uses: no viser, no GUI.
HEADLESS = (
    "session",
    "loop",
    "tab_state",
    "opening",
    "edits",
    "results_io",
    "runs",
    "workers",
    "events",
    "errors",
    "host",
    "identity",
    "stream",
    "series",
    "path",
    "cartesian",
    "direct",
    "program",
    "export",
    "tree",
    "jog",
    "compare",
    "markup",
    "units",
)


# -- architecture ---------------------------------------------------------------------------------
def imports_of(path: Path) -> list[tuple[str, int]]:
    """(module, level) of every import in a file (relative imports keep their level)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(a.name, 0) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            out += [(node.module or "", node.level)]
            if node.level and not node.module:
                out += [(a.name, node.level) for a in node.names]
    return out


def test_the_controller_knows_nothing_of_viser_and_nothing_imports_the_app() -> None:
    """The session controller and what it uses import no viser and no panel; only the CLI entry
    point needs app.py (no import loop between the app and the tab)."""
    for stem in HEADLESS:
        for name, level in imports_of(VIEWER / f"{stem}.py"):
            assert "viser" not in name, (stem, name)
            if level:
                assert name in HEADLESS or name == "", (stem, name)
    for file in VIEWER.glob("*.py"):
        if file.stem != "app":
            assert all(name not in ("app", "simecs.viewer.app") for name, _ in imports_of(file)), file


def test_the_viewer_builds_no_column_names_keys_or_phase_sets_of_its_own() -> None:
    """Columns come from mesh.protocol.columns, keys from mesh.protocol.keys, phases from
    mesh.protocol.phases, shape geometry from mesh.rules.shapes; a replay is a run of the session (no
    parallel replay session)."""
    source = "\n".join(p.read_text() for p in VIEWER.glob("*.py"))
    for banned in ('.q"', '"pose.', "pose.{", 'split("/")', "replay_id", "ACTIVE =", "def shape_geometry"):
        assert banned not in source, banned
    assert "def effective_shape" not in source and "def pipe_mesh" not in source


def viewer_imports() -> dict[str, set[str]]:
    """Module stem -> the viewer modules it imports, type-checking imports included."""
    graph: dict[str, set[str]] = {}
    for file in VIEWER.glob("*.py"):
        wanted = set()
        for name, level in imports_of(file):
            stem = name.removeprefix("simecs.viewer.") if not level else name
            if (VIEWER / f"{stem}.py").is_file():
                wanted.add(stem)
        graph[file.stem] = wanted
    return graph


def test_viewer_modules_import_each_other_without_a_cycle() -> None:
    """The parts of the session controller see the tab through its state and dispatcher, never through
    the controller: no module of the viewer reaches back to one that imports it (a circle means a
    part reaching into its owner's privates, one idea badly cut)."""
    graph = viewer_imports()
    done: set[str] = set()

    def visit(stem: str, path: list[str]) -> None:
        assert stem not in path, " -> ".join([*path, stem])
        if stem in done:
            return
        for dep in sorted(graph.get(stem, ())):
            visit(dep, [*path, stem])
        done.add(stem)

    for stem in sorted(graph):
        visit(stem, [])
    for part in ("edits", "runs", "results_io", "opening", "jog"):
        assert "session" not in graph[part], part


def test_viewer_binds_loopback_by_default_and_hides_sharing() -> None:
    from simecs.viewer import app

    parser = __import__("argparse").ArgumentParser()
    app.Viewer.add_arguments(parser)
    args = parser.parse_args([])
    assert args.host == "127.0.0.1" and args.port == 8080
    assert app._no_share() is None
    source = (VIEWER / "app.py").read_text()
    assert "show_share_button=False" in source and "request_share_url = _no_share" in source


def test_claims_give_a_session_to_one_live_tab() -> None:
    a = SimpleNamespace(tab_id=1, closed=False)
    b = SimpleNamespace(tab_id=2, closed=False)
    claims = Claims(lambda c: not c.closed)
    assert claims.claim("s", a) and claims.claim("s", a)
    assert not claims.claim("s", b, wait_s=0.0) and claims.held_by_other("s", b)
    a.closed = True  # the other tab went away (closed, or reloading)
    assert claims.claim("s", b, wait_s=0.0) and not claims.held_by_other("s", b)
    claims.release("s", b)
    assert claims.claim("s", a, wait_s=0.0)
