"""A secured mesh for a LAN (`simecs up --secure`, `simecs users ...`): who may join, with which rights.

Everything lives in one folder on the server (`.simecs/secure` by default), readable by its owner only:

- `users.json`: the users, their passwords and roles (`user` or `watcher`), kept by `simecs users`;
- `service.json`: the user name and password the service nodes join as (made once);
- `ca.pem` / `ca.key`: a certificate authority of this server; `hub.pem` / `hub.key`: the hub's TLS
  certificate, signed by it, for the addresses the hub listens on (remade when they change);
- `hub-users.txt`, `hub.json5`, `node.json5`: generated on every start: the hub's password file and
  configuration (TLS, users, access rules from mesh/process/access.py), and the service nodes' configuration.

Users join with their name and password over TLS, checking the hub against `ca.pem`
(`simecs users config NAME` prints their configuration). The hub reads the users when it starts.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import secrets
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simecs.mesh.process import access
from simecs.mesh.protocol import keys

DEFAULT_DIR = ".simecs/secure"
SERVICE_USER = "simecs-service"
HUB_PORT = 7447
CERT_DAYS = 3650
ROLES = ("user", "watcher")


class SecurityError(Exception):
    """A user or a file of the secure folder is not as it must be; the message says what."""


def _write_private(path: Path, text: str | bytes) -> None:
    """Write a file only its owner can read, atomically."""
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    tmp = path.with_name(f".{path.name}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(text.encode() if isinstance(text, str) else text)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def local_user_name() -> str:
    """This account's login as a simecs user name (letters, digits, '_', '-', '.'), "local" if none."""
    import getpass
    import re

    try:
        login = getpass.getuser()
    except (KeyError, OSError):
        login = ""
    name = re.sub(r"[^A-Za-z0-9_.-]", "_", login).lstrip("_.-")[:64]
    return name if keys.NAME_RE.match(name) and name != SERVICE_USER else "local"


def new_password() -> str:
    return secrets.token_urlsafe(12)


@dataclass
class User:
    password: str
    role: str = "user"


class SecureFolder:
    """The secure folder of a server."""

    def __init__(self, folder: str | os.PathLike[str] = DEFAULT_DIR) -> None:
        self.dir = Path(folder).expanduser().resolve()

    # -- users ----------------------------------------------------------------------------------------
    def users(self) -> dict[str, User]:
        path = self.dir / "users.json"
        if not path.exists():
            return {}
        try:
            raw = json.loads(path.read_text())
            return {name: User(**entry) for name, entry in raw["users"].items()}
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise SecurityError(f"{path}: not a users file ({exc})") from None

    def _save_users(self, users: dict[str, User]) -> None:
        data = {"users": {n: {"password": u.password, "role": u.role} for n, u in sorted(users.items())}}
        _write_private(self.dir / "users.json", json.dumps(data, indent=1) + "\n")

    def add_user(self, name: str, role: str = "user", password: str = "") -> str:
        """Add (or change) a user; returns their password (`password`, or a new random one)."""
        try:
            keys.check_name(name, "user name")
        except ValueError as exc:
            raise SecurityError(str(exc)) from None
        if name == SERVICE_USER:
            raise SecurityError(f"{SERVICE_USER!r} is the service's own user name")
        if role not in ROLES:
            raise SecurityError(f"role {role!r} must be one of {', '.join(ROLES)}")
        if password and (len(password) < 8 or ":" in password or "\n" in password):
            raise SecurityError("a password has at least 8 characters and no ':' or line break")
        users = self.users()
        users[name] = User(password or new_password(), role)
        self._save_users(users)
        return users[name].password

    def remove_user(self, name: str) -> None:
        users = self.users()
        if name not in users:
            raise SecurityError(f"no user {name!r}")
        del users[name]
        self._save_users(users)

    def service(self) -> User:
        """The service nodes' credentials (made the first time)."""
        path = self.dir / "service.json"
        if not path.exists():
            _write_private(path, json.dumps({"password": new_password(), "role": "service"}) + "\n")
        try:
            return User(**json.loads(path.read_text()))
        except (OSError, ValueError, TypeError) as exc:
            raise SecurityError(f"{path}: {exc}") from None

    # -- TLS --------------------------------------------------------------------------------------------
    @property
    def ca_file(self) -> Path:
        return self.dir / "ca.pem"

    def ensure_certificates(self, hosts: list[str]) -> None:
        """A CA (made once) and a hub certificate for `hosts` (names or addresses), remade when the
        hosts change: zenoh checks the address a client connects to against the certificate's SANs."""
        hosts = sorted({"localhost", "127.0.0.1", *hosts})
        ca_key_path, cert_path = self.dir / "ca.key", self.dir / "hub.pem"
        if not ca_key_path.exists() or not self.ca_file.exists():
            _make_ca(self.dir)
        marker = self.dir / "hub.hosts"
        if cert_path.exists() and marker.exists() and marker.read_text().split() == hosts:
            return
        _make_hub_certificate(self.dir, hosts)
        _write_private(marker, " ".join(hosts) + "\n")

    # -- generated configuration -----------------------------------------------------------------------
    def hub_config(self, listen: list[str]) -> Path:
        """Write the hub's password file and configuration; returns the configuration's path."""
        users, service = self.users(), self.service()
        lines = [f"{SERVICE_USER}:{service.password}"] + [
            f"{n}:{u.password}" for n, u in sorted(users.items())
        ]
        _write_private(self.dir / "hub-users.txt", "\n".join(lines) + "\n")
        roles: dict[str, access.Role] = {
            n: "watcher" if u.role == "watcher" else "user" for n, u in users.items()
        }
        config = {
            "listen": listen,
            "users_file": str(self.dir / "hub-users.txt"),
            "tls": {
                "listen_certificate": str(self.dir / "hub.pem"),
                "listen_private_key": str(self.dir / "hub.key"),
            },
            "access_control": access.hub_access_control(roles, SERVICE_USER),
        }
        path = self.dir / "hub.json5"
        _write_private(path, json.dumps(config, indent=1) + "\n")
        return path

    def node_config(self, hub: str, service_key_file: str) -> Path:
        """Write the service nodes' configuration (they join as the service); returns its path."""
        config = self.client_config(SERVICE_USER, self.service().password, hub)
        config["service_key_file"] = service_key_file
        path = self.dir / "node.json5"
        _write_private(path, json.dumps(config, indent=1) + "\n")
        return path

    def client_config(self, user: str, password: str, hub: str) -> dict[str, Any]:
        """A mesh configuration joining `hub` as `user` (the CA file must be on that machine too)."""
        return {
            "connect": [hub],
            "user": user,
            "password": password,
            "tls": {"root_ca_certificate": str(self.ca_file)},
        }

    def local_user(self) -> tuple[str, str]:
        """The user this machine's own account joins as (`simecs up`'s private default): named after
        the account's login, made the first time; returns (name, password)."""
        name = local_user_name()
        users = self.users()
        if name in users:
            return name, users[name].password
        return name, self.add_user(name)

    def write_local_client(self, path: Path, hub: str, service_key_file: str, tls: bool) -> tuple[str, str]:
        """The local user's client configuration at `path` (owner-only), which the CLI, the Python
        client and the examples read when told nothing else (mesh/process/config.py `load_client`); with the
        service key, so that those clients check the service's seal. Returns (name, password)."""
        name, password = self.local_user()
        config = self.client_config(name, password, hub)
        if not tls:  # a unix socket: only this machine's accounts that may open it reach it
            del config["tls"]
        config["service_key_file"] = service_key_file
        _write_private(path, json.dumps(config, indent=1) + "\n")
        return name, password

    def user_config(self, name: str, hub: str) -> dict[str, Any]:
        users = self.users()
        if name not in users:
            raise SecurityError(f"no user {name!r}: add them with `simecs users add {name}`")
        return self.client_config(name, users[name].password, hub)


# -- certificates (the cryptography package) ------------------------------------------------------------
def _make_ca(folder: Path) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "simecs hub CA")])
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CERT_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), critical=True
        )
        .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
        .sign(key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    key_pem = key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    _write_private(folder / "ca.key", key_pem)
    _write_private(folder / "ca.pem", cert.public_bytes(pem))


def _make_hub_certificate(folder: Path, hosts: list[str]) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    ca_key: Any = serialization.load_pem_private_key((folder / "ca.key").read_bytes(), None)
    ca = x509.load_pem_x509_certificate((folder / "ca.pem").read_bytes())
    key = ec.generate_private_key(ec.SECP256R1())
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    now = datetime.datetime.now(datetime.UTC)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "simecs hub")]))
        .issuer_name(ca.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(minutes=5))
        .not_valid_after(now + datetime.timedelta(days=CERT_DAYS))
        .add_extension(x509.SubjectAlternativeName(names), critical=False)
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH]), critical=False)
        .add_extension(
            x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False
        )
        .sign(ca_key, hashes.SHA256())
    )
    pem = serialization.Encoding.PEM
    key_pem = key.private_bytes(pem, serialization.PrivateFormat.PKCS8, serialization.NoEncryption())
    _write_private(folder / "hub.key", key_pem)
    _write_private(folder / "hub.pem", cert.public_bytes(pem))
