"""`simecs`: the one command-line entry point (`simecs --help`, `simecs COMMAND --help`)."""

from __future__ import annotations

import argparse
import faulthandler
import importlib
import importlib.util
import json
import os
import sys
import time
from pathlib import Path

from simecs.mesh.process.config import CLIENT_FILE, DEFAULT_HUB, MeshConfig, load, load_client

SECURE_DIR = os.path.join(os.environ.get("SIMECS_DATA", ".simecs"), "secure")
UNIX_SOCKET = "unixsock-stream/"

#: Node name -> module with a `main(argv)`. The viewer lives in its own package.
NODES = {
    "hub": "simecs.nodes.hub",
    "proxy": "simecs.nodes.proxy",
    "simulator": "simecs.nodes.simulator",
    "hotfeedback": "simecs.nodes.hotfeedback",
    "recorder": "simecs.nodes.recorder",
    "viewer": "simecs.viewer.app",
}

#: Benchmark name -> "module:function(json_out: bool) -> dict".
BENCHES = {
    "model": "simecs.benchmarks.model:run_model_bench",
    "commands": "simecs.benchmarks.commands:run_commands_bench",
    "service": "simecs.benchmarks.service:run_service_bench",
    "viewer": "simecs.benchmarks.viewer:run_viewer_bench",
    "recorder": "simecs.benchmarks.recorder:run_recorder_bench",
    "lan": "simecs.benchmarks.lan:run_lan_bench",
    "hil": "simecs.benchmarks.hil:run_hil_bench",
    "scale": "simecs.benchmarks.scale:run_scale_bench",
    "control": "simecs.benchmarks.control:run_control_bench",
}


def _available(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def hub_port(endpoint: str) -> int:
    """The port of a hub endpoint such as `tcp/127.0.0.1:7447` (SystemExit naming it if it has none)."""
    try:
        return int(endpoint.rsplit(":", 1)[1])
    except (IndexError, ValueError):
        raise SystemExit(f"simecs up: --hub {endpoint!r} has no port (e.g. tcp/127.0.0.1:7447)") from None


def secure_setup(args: argparse.Namespace) -> tuple[str, list[str], list[str], str]:
    """For `simecs up` (private, its default): (the hub endpoint nodes connect to, the hub's flags, every
    other node's flags, lines for the banner); certificates, credentials and configurations are made
    here, and this machine's user with its client configuration (`client.json5` in the data folder).
    A TCP or TLS `--hub` gives its port to TLS on `--hub-host`; a unix socket stays one (no TLS: only
    accounts that may open the socket reach it, and they need a password too)."""
    from simecs.mesh.process import seal
    from simecs.nodes.secure import SecureFolder

    folder = SecureFolder(args.secure_dir or os.path.join(args.data_dir, "secure"))
    folder.ensure_certificates([args.hub_host])
    if args.hub.startswith(UNIX_SOCKET):
        local, listen, tls = args.hub, [args.hub], False
    else:
        host, port = args.hub_host, hub_port(args.hub)  # `--hub` chooses the port, TLS or not
        local = f"tls/127.0.0.1:{port}"
        listen = [f"tls/{host}:{port}"] + ([local] if host != "127.0.0.1" else [])
        tls = True
    key_file = str(seal.key_file(""))
    seal.load(key_file, create=True)
    client_file = os.path.join(os.path.abspath(args.data_dir), CLIENT_FILE)
    me, password = folder.write_local_client(Path(client_file), local, key_file, tls)
    hub_flags = ["--mesh-config", str(folder.hub_config(listen))]  # after the local user is made
    node_flags = ["--mesh-config", str(folder.node_config(local, key_file))]
    note = (
        f"private: the hub takes users with a password only ({len(folder.users())} in "
        f"{folder.dir}/users.json; `simecs users add NAME` adds one, then start again)\n"
        f"you are {me} (password {password}): simecs commands, the Python client and docs/examples "
        f"read {client_file}; the viewer asks for it once per tab"
    )
    if tls and args.hub_host != "127.0.0.1":
        note += (
            f"\nother machines join with `simecs users config NAME --hub {listen[0]}` and {folder.ca_file}"
        )
    return local, hub_flags, node_flags, note


def cmd_up(args: argparse.Namespace) -> int:
    from simecs.nodes.supervisor import Child, Supervisor, node_argv

    hub = args.hub
    data = os.path.abspath(args.data_dir)
    common = ["--connect", hub]
    hub_flags = ["--listen", hub]
    note = "OPEN: no passwords; any process that reaches the hub acts as any user (docs/LAN.md, open mode)"
    if not args.open:
        hub, hub_flags, common, note = secure_setup(args)
    children = [
        Child("hub", node_argv(NODES["hub"], hub_flags)),
        Child(
            "proxy",
            node_argv(
                NODES["proxy"],
                [*common, "--data-dir", data]
                + (["--max-running", str(args.max_running)] if args.max_running else []),
            ),
        ),
        Child(
            "simulator",
            node_argv(
                NODES["simulator"],
                [*common, "--results-dir", os.path.join(data, "results")]
                + [arg for d in args.models for arg in ("--models", os.path.abspath(d))],
            ),
        ),
        Child("hotfeedback", node_argv(NODES["hotfeedback"], common)),
    ]
    roles = ["hub", "proxy", "simulator", "hotfeedback"]
    if not args.no_recorder and _available(NODES["recorder"]):
        children.append(Child("recorder", node_argv(NODES["recorder"], [*common, "--dir", args.recordings])))
        roles.append("recorder")
    url = ""
    if not args.no_viewer and _available(NODES["viewer"]):
        children.append(
            Child(
                "viewer", node_argv(NODES["viewer"], [*common, "--host", args.host, "--port", str(args.port)])
            )
        )
        roles.append("viewer")
        url = f"http://{'127.0.0.1' if args.host in ('0.0.0.0', '') else args.host}:{args.port}"
    banner = f"simecs is up ({', '.join(roles)}) on hub {hub}"
    if note:
        banner += f"\n{note}"
    if url:
        banner += f"\nOpen the viewer: {url}"
    config = MeshConfig(mode="client", connect=[hub])
    if not args.open:
        config = load(common[1])  # the supervisor checks readiness as the service does
    return Supervisor(children, config).run_forever(roles, banner)


def cmd_users(args: argparse.Namespace) -> int:
    from simecs.nodes.secure import HUB_PORT, SecureFolder, SecurityError

    folder = SecureFolder(args.secure_dir)
    try:
        if args.action == "add":
            password = folder.add_user(args.name, "watcher" if args.watcher else "user", args.password)
            role = "watcher (reads every session, commands nothing)" if args.watcher else "user"
            print(f"{args.name}: {role}, password {password}")
            print("The hub reads its users when it starts: restart `simecs up`.")
        elif args.action == "remove":
            folder.remove_user(args.name)
            print(f"{args.name} removed; the hub forgets them when it restarts")
        elif args.action == "list":
            for name, user in sorted(folder.users().items()):
                print(f"{name:32} {user.role}")
        else:  # config
            hub = args.hub or f"tls/127.0.0.1:{HUB_PORT}"
            print(json.dumps(folder.user_config(args.name, hub), indent=1))
            hint = f"save as {args.name}.json5 on their machine, with a copy of {folder.ca_file} at that path"
            print(hint, file=sys.stderr)
    except SecurityError as exc:
        print(f"simecs users: {exc}", file=sys.stderr)
        return 2
    return 0


def cmd_node(args: argparse.Namespace, rest: list[str]) -> int:
    module = importlib.import_module(NODES[args.name])
    return int(module.main(rest) or 0)


def cmd_ls(args: argparse.Namespace) -> int:
    import zenoh.ext
    from simecs.mesh.process import seal as seals
    from simecs.mesh.process.config import open_session
    from simecs.mesh.protocol import codec, keys
    from simecs.mesh.protocol import messages as m

    cfg = load_client(args.mesh_config).with_overrides(connect=[args.connect] if args.connect else None)
    z = open_session(cfg, deadline_s=3.0)
    try:
        statuses: dict[str, m.NodeStatus] = {}
        states: dict[str, m.SessionState] = {}
        # On a machine of the service, show only what service nodes said (mesh/process/seal.py).
        key_path = seals.key_file(cfg.service_key_file)
        seal = seals.load(key_path) if key_path.exists() else None

        def trusted(s: zenoh.Sample) -> bool:
            return seal is None or seal.sample_valid(s)

        def on_status(s: zenoh.Sample) -> None:
            if trusted(s):
                st = codec.loads(m.NodeStatus, s.payload.to_bytes())
                statuses[f"{st.role}/{st.node_id}"] = st

        def on_state(s: zenoh.Sample) -> None:
            if trusted(s):
                st = codec.loads(m.SessionState, s.payload.to_bytes())
                states[st.session] = st

        history = zenoh.ext.HistoryConfig(detect_late_publishers=True)
        # Every user's sessions (the service and watchers may read them), and one's own: a user of a
        # private mesh may watch only their own (the hub's rules drop the wider subscription).
        state_keys = [keys.ALL_STATE] + ([keys.wildcard("state", user=cfg.user)] if cfg.user else [])
        subs = [
            zenoh.ext.declare_advanced_subscriber(z, keys.NODES_STATUS, on_status, history=history),
            *(zenoh.ext.declare_advanced_subscriber(z, k, on_state, history=history) for k in state_keys),
        ]
        live = []
        for reply in z.liveliness().get(keys.NODE_TOKENS, timeout=2.0):
            if reply.ok is not None:
                token = keys.parse("node_token", reply.ok.key_expr)
                live.append(f"{token['role']}/{token['node']}")
        time.sleep(0.5)
        for sub in subs:
            sub.undeclare()
        live_states = {k: v for k, v in states.items() if v.phase != "closed"}
        if args.json:
            print(
                json.dumps(
                    {
                        "nodes": sorted(live),
                        "sessions": {k: v.phase for k, v in live_states.items()},
                        "hosts": {k: v.host for k, v in live_states.items() if v.host},
                    }
                )
            )
            return 0
        print(f"{'NODE':40} {'PID':>7}  DETAIL")
        for name in sorted(live):
            node = statuses.get(name)
            detail = " ".join(f"{k}={v}" for k, v in (node.detail if node else {}).items())
            if node is not None and node.load is not None:
                ld = node.load
                detail += f" load={ld.demand:.2f}/{ld.capacity:.2f} cores runs={len(ld.runs)}" + (
                    f" behind={ld.behind}" if ld.behind else ""
                )
            print(f"{name:40} {node.pid if node else '?':>7}  {detail}")
        print(f"\n{'SESSION':24} {'PHASE':10} {'RUN':5} {'PROGRESS':>9}  HOST")
        for sid, state in sorted(live_states.items()):
            where = state.host or (f"queued #{state.queue_position}" if state.phase == "queued" else "")
            if state.phase == "queued" and state.wait_s:
                where += f", ~{state.wait_s:.0f} s"
            if state.attempt > 1:
                where += f" (attempt {state.attempt})"
            print(f"{sid:24} {state.phase:10} {state.run_id:5} {state.progress * 100:7.1f} %  {where}")
        return 0
    finally:
        z.close()


def cmd_bench(args: argparse.Namespace) -> int:
    target = BENCHES[args.name]
    module_name, func = target.split(":")
    if not _available(module_name):
        print(f"benchmark {args.name} is not available in this installation ({module_name})", file=sys.stderr)
        return 2
    os.environ["SIMECS_CPU"] = args.cpu  # the nodes a benchmark starts place themselves this way
    result = getattr(importlib.import_module(module_name), func)(args.json)
    return 0 if result is not None else 1


def cmd_model(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    """`simecs model check DIR` and `simecs model import URDF --out DIR`."""
    from simecs.models.model_file import ModelFileError
    from simecs.models.model_import import check_model, import_urdf, read_drive_table
    from simecs.models.urdf import UrdfError

    if args.action == "check":
        return 0 if check_model(args.path, run=not args.no_run) else 1
    if not args.out:
        parser.error("model import needs --out DIR")
    locks = {}
    for item in args.lock:
        name, _, value = item.partition("=")
        try:
            locks[name] = float(value)
        except ValueError:
            parser.error(f"--lock {item!r}: give JOINT=VALUE with a number")
    try:
        table = None if args.drives == "auto" else read_drive_table(args.drives)
        out = import_urdf(
            args.path,
            args.out,
            model_id=args.id,
            base_link=args.base_link,
            tool_link=args.tool_link,
            locked=locks,
            drives=table,
        )
    except (UrdfError, ModelFileError) as exc:
        print(f"refused: {exc}", file=sys.stderr)
        return 1
    return 0 if check_model(out, run=True) else 1


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simecs",
        description="Remote simulation environment for robot arms (Exudyn + Zenoh + viser + MCAP).",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    up = sub.add_parser("up", help="start the hub and every node on this machine (Ctrl-C stops all)")
    up.add_argument(
        "--hub",
        default=DEFAULT_HUB,
        help=f"hub endpoint (default {DEFAULT_HUB}: its port, TLS unless --open; or a unixsock-stream/ path)",
    )
    up.add_argument(
        "--host", default="127.0.0.1", help="viewer address (default loopback; a LAN address on request)"
    )
    up.add_argument("--port", type=int, default=8080, help="viewer port")
    up.add_argument(
        "--data-dir",
        default=os.environ.get("SIMECS_DATA", ".simecs"),
        help="sessions, parameter sets, results",
    )
    up.add_argument("--recordings", default="recordings", help="where MCAP recordings go")
    up.add_argument(
        "--max-running", type=int, default=None, help="a ceiling of runs at once (default: by capacity)"
    )
    up.add_argument("--no-viewer", action="store_true", help="headless: no web viewer")
    up.add_argument(
        "--models",
        action="append",
        default=[],
        metavar="DIR",
        help="more models: a model directory or a folder of them (repeatable; docs/MODELS.md)",
    )
    up.add_argument("--no-recorder", action="store_true", help="do not record runs")
    up.add_argument(
        "--open",
        action="store_true",
        help="no passwords: any process that reaches the hub acts as any user (docs/LAN.md, open mode)",
    )
    up.add_argument(
        "--secure", action="store_true", help="the default (private: users with passwords); kept for scripts"
    )
    up.add_argument(
        "--hub-host",
        default="127.0.0.1",
        help="the address (or name) users reach the hub at (a LAN address to share it); it listens there",
    )
    up.add_argument(
        "--secure-dir", default="", help="users, certificates, keys (default: the data folder's secure/)"
    )

    users = sub.add_parser("users", help="the users of the mesh (simecs up; not with --open)")
    users.add_argument("action", choices=["add", "remove", "list", "config"])
    users.add_argument("name", nargs="?", default="", help="user name (add, remove, config)")
    users.add_argument("--watcher", action="store_true", help="add: may read every session, command none")
    users.add_argument("--password", default="", help="add: this password (default: a random one)")
    users.add_argument("--hub", default="", help="config: the hub endpoint the user connects to")
    users.add_argument("--secure-dir", default=SECURE_DIR)

    node = sub.add_parser(
        "node", help="run one node (for a LAN: --connect tcp/HUB:7447); NAME --help for its flags"
    )
    node.add_argument("name", choices=sorted(NODES))

    ls = sub.add_parser("ls", help="list live nodes and sessions")
    ls.add_argument("--connect", default=None, help=f"hub endpoint (default {DEFAULT_HUB})")
    ls.add_argument("--mesh-config", default=None)
    ls.add_argument("--json", action="store_true")

    bench = sub.add_parser("bench", help="run a benchmark: human table, and with --json one JSON line last")
    bench.add_argument("name", choices=sorted(BENCHES))
    bench.add_argument("--json", action="store_true")
    bench.add_argument(
        "--cpu",
        default=os.environ.get("SIMECS_CPU", "auto"),
        help="placement of the live path, as the nodes' --cpu: auto, none or a CPU number",
    )

    model = sub.add_parser(
        "model", help="check a model directory (model.json5), or import a URDF as a new one (docs/MODELS.md)"
    )
    model.add_argument("action", choices=["check", "import"])
    model.add_argument("path", help="check: a model directory or its model.json5; import: a URDF file")
    model.add_argument("--no-run", action="store_true", help="check: do not run the standard move")
    model.add_argument("--out", default="", help="import: the model directory to write")
    model.add_argument("--id", default="", help="import: the model id (default: from the URDF's robot name)")
    model.add_argument(
        "--base-link", default="", help="import: the link the arm stands on (default: the root)"
    )
    model.add_argument(
        "--tool-link", default="", help="import: the tool frame's link (default: the chain's end)"
    )
    model.add_argument(
        "--lock", action="append", default=[], metavar="JOINT=VALUE", help="import: hold a joint at a value"
    )
    model.add_argument(
        "--drives",
        default="auto",
        help="import: auto (sized from the URDF's limits) or a JSON5 drive table {drives, joints}",
    )

    from simecs.nodes.tools import batch

    run = sub.add_parser("run", help="one simulation from files, to a recording or CSV (no browser)")
    batch.add_arguments(run, sweep=False)
    sweep = sub.add_parser("sweep", help="parameter variations in parallel, to a table of outcome measures")
    batch.add_arguments(sweep, sweep=True)

    for name, help_text in (
        ("replay", "play a recording back onto the mesh as a run of a session"),
        ("export", "export a recording"),
    ):
        p = sub.add_parser(name, help=help_text, add_help=False)
        p.add_argument("rest", nargs=argparse.REMAINDER)
    return parser


def main(argv: list[str] | None = None) -> None:
    faulthandler.enable()  # a crash in a native library leaves every thread's stack on stderr
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    if argv and argv[0] == "node" and len(argv) >= 2:
        args = parser.parse_args(argv[:2])
        sys.exit(cmd_node(args, argv[2:]))
    if argv and argv[0] in ("replay", "export"):
        module = f"simecs.nodes.{argv[0]}"
        if not _available(module):
            print(f"{argv[0]} is not available in this installation", file=sys.stderr)
            sys.exit(2)
        sys.exit(int(importlib.import_module(module).main(argv[1:]) or 0))
    args = parser.parse_args(argv)
    if args.command == "up":
        sys.exit(cmd_up(args))
    if args.command == "ls":
        sys.exit(cmd_ls(args))
    if args.command == "users":
        if args.action != "list" and not args.name:
            parser.error(f"users {args.action} needs a user name")
        sys.exit(cmd_users(args))
    if args.command == "bench":
        sys.exit(cmd_bench(args))
    if args.command == "model":
        sys.exit(cmd_model(args, parser))
    if args.command in ("run", "sweep"):
        from simecs.nodes.tools import batch

        sys.exit(batch.cmd_run(args) if args.command == "run" else batch.cmd_sweep(args))
    parser.error(f"unknown command {args.command}")


if __name__ == "__main__":
    main()
