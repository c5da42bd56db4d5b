"""`simecs run` and `simecs sweep`: simulations from a shell or CI, without the browser.

`run` gives one session a model, parameter values, an initial pose, a command and settings, runs it
with a progress bar on stderr and writes the run's recording (.mcap, the recorder's own file) or its
results (.csv). `sweep` runs a grid or a list of parameter variations, several at once over every
simulator on the mesh, and writes one table of outcome measures (mesh/batch.py). Both work against a
running mesh (`--connect`, `--mesh-config`) or start a private one (`--embedded`).

Exit codes: 0 the run finished (sweep: every case did), 1 a run failed or was aborted (sweep: some
case did), 2 bad input (a file, an argument, or a refusal of the service: the field and the reason
are printed), 3 no service (nothing answered, a timeout).
"""

from __future__ import annotations

import argparse
import csv
import json
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from simecs.mesh import batch
from simecs.mesh.client import MeshClient, NoReply, RemoteError
from simecs.mesh.process.config import load_client
from simecs.mesh.protocol import codec, keys
from simecs.mesh.protocol import messages as m
from simecs.mesh.rules import table_csv

EXIT_OK, EXIT_RUN_FAILED, EXIT_BAD_INPUT, EXIT_NO_SERVICE = 0, 1, 2, 3


class BadInput(Exception):
    """A file or an argument that cannot be used."""


def add_arguments(parser: argparse.ArgumentParser, sweep: bool) -> None:
    parser.add_argument("--model", required=True, help="model id (simecs ls / the library)")
    parser.add_argument(
        "--command", dest="command_file", required=True, help="JSON file: a robot command (PROTOCOL.md §5.2)"
    )
    parser.add_argument("--params", help='JSON file: {"name": value, ...} (or a saved set {"values": {...}})')
    parser.add_argument("--initial", help="rad, one per joint: 'q1,q2,...' or a JSON file of a list")
    parser.add_argument("--settings", help="JSON file: RunSettings (omitted fields take their defaults)")
    parser.add_argument("--stop-time", type=float, help="s (overrides --settings)")
    parser.add_argument("--output-interval", type=float, help="s (overrides --settings)")
    parser.add_argument(
        "--pacing",
        choices=["fast", "realtime", "scaled"],
        default=None,
        help="default: fast (overrides --settings)",
    )
    parser.add_argument(
        "--user", default="", help="whose sessions (default: the mesh config's user, or batch)"
    )
    parser.add_argument("--connect", default="", help="hub endpoint, e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--mesh-config", default="", help="a mesh configuration file (JSON5)")
    parser.add_argument("--embedded", action="store_true", help="start a private mesh for this command")
    parser.add_argument("--timeout", type=float, default=3600.0, help="s a run may take")
    if sweep:
        parser.add_argument(
            "--grid", action="append", default=[], help="NAME=v1,v2,... (repeat: every combination)"
        )
        parser.add_argument("--list", help='JSON file: a list of {"name": value, ...} cases')
        parser.add_argument(
            "--measure",
            action="append",
            default=[],
            help=f"KIND:VARIABLE, KIND one of {', '.join(batch.MEASURES)}",
        )
        parser.add_argument("--out", required=True, help="the table (.csv)")
        parser.add_argument("--recordings", help="a folder for each case's recording (.mcap)")
        parser.add_argument("--parallel", type=int, default=4, help="cases running at once")
    else:
        parser.add_argument("--out", required=True, help="results.mcap (the recording) or results.csv")
        parser.add_argument("--vars", default="", help="CSV: these variables only (comma-separated)")
        parser.add_argument("--quiet", action="store_true", help="no progress bar")


# -- inputs ------------------------------------------------------------------------------------------
def _json_file(path: str, what: str) -> Any:
    try:
        return json.loads(Path(path).read_text("utf-8"))
    except (OSError, ValueError) as exc:
        raise BadInput(f"{what} {path}: {exc}") from None


def _decode(tp: Any, obj: Any, what: str) -> Any:
    try:
        return codec.from_obj(tp, obj)
    except codec.DecodeError as exc:
        raise BadInput(f"{what}: {exc}") from None


def read_inputs(
    args: argparse.Namespace,
) -> tuple[m.RobotCommand, dict[str, float], list[float] | None, m.RunSettings]:
    command = _decode(
        m.RobotCommand, _json_file(args.command_file, "command file"), f"command file {args.command_file}"
    )
    values: dict[str, float] = {}
    if args.params:
        raw = _json_file(args.params, "parameter file")
        raw = raw.get("values", raw) if isinstance(raw, dict) else raw
        if not isinstance(raw, dict) or not all(isinstance(v, int | float) for v in raw.values()):
            raise BadInput(f"parameter file {args.params}: expected an object of numbers")
        values = {str(k): float(v) for k, v in raw.items()}
    initial = None
    if args.initial:
        if Path(args.initial).is_file():
            initial = _json_file(args.initial, "initial pose file")
        else:
            try:
                initial = [float(x) for x in args.initial.split(",")]
            except ValueError:
                raise BadInput(
                    f"--initial {args.initial!r}: numbers separated by commas, or a file"
                ) from None
        if not isinstance(initial, list) or not all(isinstance(x, int | float) for x in initial):
            raise BadInput("--initial: a list of numbers")
    settings_obj = _json_file(args.settings, "settings file") if args.settings else {}
    if not isinstance(settings_obj, dict):
        raise BadInput(f"settings file {args.settings}: expected an object")
    settings_obj.setdefault("pacing", "fast")
    for name in ("stop_time", "output_interval", "pacing"):
        value = getattr(args, name)
        if value is not None:
            settings_obj[name] = value
    settings = _decode(m.RunSettings, settings_obj, "settings")
    return command, values, initial, settings


# -- the mesh ----------------------------------------------------------------------------------------
@contextmanager
def mesh_client(args: argparse.Namespace) -> Iterator[MeshClient]:
    """A client of the mesh the arguments name, or of a private one started (and stopped) here."""
    if args.embedded:
        from simecs.nodes.local_mesh import LocalMesh

        args.user = args.user or "batch"

        with tempfile.TemporaryDirectory(prefix="smr") as folder:
            mesh = LocalMesh(folder)
            try:
                mesh.start_hub()
                mesh.start_service(max_running=max(1, getattr(args, "parallel", 1)))
                mesh.start("recorder", "--dir", str(Path(folder) / "rec"))
                yield mesh.client()
            finally:
                mesh.close()
        return
    connect = [args.connect] if args.connect else None
    cfg = load_client(args.mesh_config or None).with_overrides(connect=connect)
    args.user = args.user or cfg.user or "batch"  # on a private mesh, a user acts in their own space
    client = MeshClient.open(cfg, timeout=10.0)
    try:
        yield client
    finally:
        client.close()


def save_recording(client: MeshClient, user: str, session: str, run_id: str, path: Path) -> None:
    name = keys.recording_name(session, run_id)
    batch.wait_for_recording(client, user, name)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(client.download_recording(user, name, timeout=120.0))


def write_csv(path: Path, columns: list[str], rows: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        table_csv.write_table(fh, columns, rows)


class Progress:
    """A one-line progress bar on stderr."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet or not sys.stderr.isatty()
        self.last = ""

    def __call__(self, st: m.SessionState) -> None:
        if self.quiet:
            return
        bar = "#" * int(st.progress * 30)
        text = f"\r{st.run_id} {st.phase:9} [{bar:30}] {st.progress * 100:5.1f} %  t = {st.sim_time:.3f} s"
        if st.rtf:
            text += f"  RTF {st.rtf:.1f}"
        if text != self.last:
            sys.stderr.write(text)
            sys.stderr.flush()
            self.last = text

    def end(self) -> None:
        if not self.quiet and self.last:
            sys.stderr.write("\n")


def _failure(exc: BaseException) -> int:
    if isinstance(exc, BadInput | ValueError):  # a file, an argument, a mesh configuration
        print(f"simecs: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if isinstance(exc, RemoteError):
        where = f" ({exc.field})" if exc.field else ""
        print(f"simecs: refused, {exc.code}{where}: {exc.error.message}", file=sys.stderr)
        return EXIT_NO_SERVICE if exc.code == "busy" else EXIT_BAD_INPUT
    print(f"simecs: no service: {exc}", file=sys.stderr)
    return EXIT_NO_SERVICE


# -- the commands ------------------------------------------------------------------------------------
def cmd_run(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix not in (".mcap", ".csv"):
        print(f"simecs run: --out {out}: .mcap or .csv", file=sys.stderr)
        return EXIT_BAD_INPUT
    progress = Progress(args.quiet)
    try:
        command, values, initial, settings = read_inputs(args)
        with mesh_client(args) as client:
            variables = [v for v in args.vars.split(",") if v] or None
            outcome = batch.run_simulation(
                client, args.user, args.model, command, values, initial, settings,
                variables if out.suffix == ".csv" else ["time"], progress, args.timeout, close=False,
            )  # fmt: skip
            progress.end()
            try:
                if outcome.rows.shape[0]:
                    if out.suffix == ".mcap":
                        save_recording(client, args.user, outcome.session, outcome.run_id, out)
                    else:
                        write_csv(out, outcome.columns, outcome.rows)
            finally:
                client.session(args.user, outcome.session).close()
    except (BadInput, RemoteError, NoReply, TimeoutError, OSError, RuntimeError, ValueError) as exc:
        progress.end()
        return _failure(exc)
    say = f"run {outcome.run_id}: {outcome.phase} at t = {outcome.sim_time:.3f} s (RTF {outcome.rtf:.1f})"
    if outcome.reason:
        say += f": {outcome.reason}"
    print(say + (f"; wrote {out}" if outcome.rows.shape[0] else ""), file=sys.stderr)
    return EXIT_OK if outcome.ok else EXIT_RUN_FAILED


def _cases(args: argparse.Namespace) -> list[dict[str, float]]:
    if args.list:
        cases = _json_file(args.list, "case list")
        if not isinstance(cases, list) or not all(
            isinstance(c, dict) and all(isinstance(v, int | float) for v in c.values()) for c in cases
        ):
            raise BadInput(f"case list {args.list}: a list of objects of numbers")
        return [{str(k): float(v) for k, v in c.items()} for c in cases]
    grid: dict[str, list[float]] = {}
    for item in args.grid:
        name, _, raw = item.partition("=")
        try:
            grid[name.strip()] = [float(x) for x in raw.split(",")]
        except ValueError:
            raise BadInput(f"--grid {item!r}: NAME=v1,v2,...") from None
        if not name.strip() or not raw:
            raise BadInput(f"--grid {item!r}: NAME=v1,v2,...")
    if not grid:
        raise BadInput("give the cases: --grid NAME=v1,v2,... or --list FILE")
    return batch.variations(grid)


def cmd_sweep(args: argparse.Namespace) -> int:
    try:
        command, values, initial, settings = read_inputs(args)
        cases = _cases(args)
        if not args.measure:
            raise BadInput("give at least one --measure KIND:VARIABLE")
        for spec in args.measure:
            if spec.partition(":")[0] not in batch.MEASURES or not spec.partition(":")[2]:
                raise BadInput(f"--measure {spec!r}: KIND:VARIABLE, KIND one of {', '.join(batch.MEASURES)}")
        names = sorted({k for c in cases for k in c})
        done: list[int] = []

        def tell(row: batch.SweepRow) -> None:
            done.append(row.index)
            state = row.outcome.phase if row.outcome else "refused"
            print(
                f"case {row.index + 1}/{len(cases)} {state}{': ' + row.error if row.error else ''}",
                file=sys.stderr,
            )

        with mesh_client(args) as client:
            rows = batch.sweep(
                client, args.user, args.model, command, cases, args.measure, values, initial, settings,
                args.parallel, tell, args.timeout,
            )  # fmt: skip
            if args.recordings:
                for row in rows:
                    if row.outcome is not None and row.outcome.rows.shape[0]:
                        path = Path(args.recordings) / f"case{row.index + 1}.mcap"
                        save_recording(client, args.user, row.outcome.session, row.outcome.run_id, path)
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        with out.open("w", newline="") as fh:
            table = csv.writer(fh)
            table.writerow(["case", *names, "run_id", "phase", *args.measure, "error"])
            for row in rows:
                o = row.outcome
                table.writerow(
                    [
                        row.index + 1,
                        *(row.values.get(n, "") for n in names),
                        o.run_id if o else "",
                        o.phase if o else "refused",
                    ]
                    + [repr(row.measures[s]) if s in row.measures else "" for s in args.measure]
                    + [row.error]
                )
    except (BadInput, RemoteError, NoReply, TimeoutError, OSError, RuntimeError, ValueError) as exc:
        return _failure(exc)
    failed = sum(1 for r in rows if r.error)
    print(f"sweep: {len(rows)} cases, {failed} failed or refused; wrote {out}", file=sys.stderr)
    return EXIT_OK if not failed else EXIT_RUN_FAILED
