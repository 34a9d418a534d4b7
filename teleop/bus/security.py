"""Who may use the bus: ZeroMQ CURVE encryption and authentication, and the keys it needs.

When CURVE is on
----------------
An endpoint is *loopback* when no other host can reach it: ``inproc://``, ``ipc://`` and
``tcp://`` on 127.0.0.0/8, ``::1`` or ``localhost``. Any other endpoint (a LAN address,
``*``, ``0.0.0.0``, an interface or host name) must run CURVE: a socket refuses to start
on it without keys (:class:`~teleop.errors.BusSecurityError` naming the endpoint and the
fix). Loopback stays plain unless keys are given, and then it runs CURVE as well (which is
how the tests exercise it). ``inproc://`` never runs CURVE: libzmq performs no handshake
inside one process.

Roles
-----
The socket that binds is the CURVE *server*: it proves itself with the server key pair and
admits only clients whose public keys lie in the authorised-keys directory, checked by
one ZAP handler per ZeroMQ context (:class:`zmq.auth.thread.ThreadAuthenticator`, one ZAP
domain per directory). The socket that connects is the *client*: it has its own key pair
and trusts only the server public key it was given, so it neither talks to an impostor nor
is admitted without authorisation. A peer that fails either check gets nothing and
delivers nothing. When both ends run CURVE, both say so, once: the server logs the refused client's
public key, the client the endpoint that refused it. When only one end has keys, both ends say
that the mechanisms differ (:mod:`teleop.bus.handshakes`, which also reconnects an endpoint a
client gave up): set ``bus.keys_dir`` on every host.
The directory is read when a server socket is created, and a file in it that is not a
public certificate stops that server from starting; authorising or revoking a key takes
effect when the servers restart.

Keys directory (``bus.keys_dir``)
---------------------------------
Made by ``teleop keys init DIR`` (see :mod:`teleop.bus.keys_cli`)::

    DIR/server.key         server public certificate (every client of the bus needs it)
    DIR/server.key_secret  server secret certificate, mode 0600 (every host that binds:
                           the one pair, copied to each; ``teleop keys --help``)
    DIR/client.key         this node's client public certificate
    DIR/client.key_secret  this node's client secret certificate, mode 0600
    DIR/authorized/*.key   public certificates of the clients the servers admit

Certificates are the czmq/pyzmq text format (:func:`zmq.auth.create_certificates`), read and checked by
:mod:`teleop.bus.cert_keys`.
A secret certificate other users may read is refused, as ssh refuses such keys; so are folders and public certificates they may write,
and a secret certificate whose secret key does not give its public key (damaged, or from another pair).
"""

from __future__ import annotations

import dataclasses
import hashlib
import ipaddress
import logging
import os
import re
import shutil
import tempfile
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import zmq
import zmq.auth
from zmq.auth.thread import ThreadAuthenticator

from teleop.bus import cert_access
from teleop.bus.cert_access import CertificateAccessError, access_error, is_dir
from teleop.bus.cert_keys import PUBLIC_SUFFIX, SECRET_SUFFIX, read_public_cert, read_secret_cert
from teleop.endpoints import parse_endpoint
from teleop.errors import BusError, BusSecurityError
from teleop.settings import BusSettings

__all__ = [
    "AUTHORIZED_DIR",
    "CLIENT_CERT",
    "CURVE_FRAME_OVERHEAD_BYTES",
    "SERVER_CERT",
    "AuthorizedKey",
    "BusSecurity",
    "KeyListing",
    "apply_security",
    "authorize_key",
    "check_endpoints",
    "host_is_loopback",
    "init_keys",
    "is_loopback",
    "list_keys",
    "read_authorized",
    "revoke_key",
    "security_from_settings",
    "serving_keys",
]

log = logging.getLogger(__name__)

SERVER_CERT = "server"
CLIENT_CERT = "client"
AUTHORIZED_DIR = "authorized"
# A CURVE MESSAGE wraps each frame: "\x07MESSAGE" (8) + nonce (8) + flags (1) + MAC (16).
# ZMQ_MAXMSGSIZE limits the wrapped frame, so a receiver adds this to its payload limit.
CURVE_FRAME_OVERHEAD_BYTES = 33

_LOOPBACK_SCHEMES = frozenset({"inproc", "ipc"})
_NETWORK_SCHEMES = frozenset({"pgm", "epgm", "norm", "tipc", "vmci"})  # multicast, or a fabric of hosts
_KEY_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
_MAX_REFUSALS_LOGGED = 1000  # refused keys a server names: a flood of keys cannot grow memory


_FIX_HINT = "run `teleop keys init DIR` and set bus.keys_dir = DIR in the settings TOML"


# --------------------------------------------------------------------------- endpoints


def host_is_loopback(host: str) -> bool:
    """Whether no other host can reach a server listening on ``host`` (an address or ``localhost``,
    IPv6 with or without brackets; "" and "0.0.0.0", every interface, can be reached)."""
    host = host.removeprefix("[").removesuffix("]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:  # "*", an interface name or a host name: reachable from elsewhere
        return False


def is_loopback(endpoint: str) -> bool:
    """Whether no other host can reach ``endpoint`` (``inproc``, ``ipc``, tcp on loopback).

    A tcp endpoint with a source address (``tcp://SRC;DST:PORT``) is loopback only when
    both are. Raises BusError for text that is not a ZeroMQ endpoint, a port out of range
    included (:func:`~teleop.endpoints.parse_endpoint`).
    """
    try:
        parsed = parse_endpoint(endpoint)
    except ValueError as exc:
        raise BusError(f"{endpoint!r}: {exc}") from None
    if parsed.scheme in _LOOPBACK_SCHEMES:
        return True
    if parsed.scheme in _NETWORK_SCHEMES:
        return False
    return all(host_is_loopback(host) for host in parsed.hosts)


def check_endpoints(endpoints: Iterable[str], security: BusSecurity | None) -> None:
    """Refuse to use a non-loopback endpoint without CURVE keys.

    Raises
    ------
    BusSecurityError
        Naming the first such endpoint and how to configure keys.
    BusError
        An endpoint is not a ZeroMQ endpoint.
    """
    for endpoint in endpoints:
        if not is_loopback(endpoint) and security is None:
            raise BusSecurityError(
                f"bus endpoint {endpoint!r} is reachable from other hosts and no CURVE keys "
                "are configured, so anyone on the network could read or inject bus traffic: "
                f"{_FIX_HINT}"
            )


# --------------------------------------------------------------------------- certificates


def _check_name(name: str) -> str:
    if not isinstance(name, str) or not _KEY_NAME.fullmatch(name):
        raise BusSecurityError(
            f"key name {name!r}: expected 1-64 letters, digits, '.', '_' or '-', "
            "starting with a letter or digit"
        )
    return name


@dataclass(frozen=True)
class BusSecurity:
    """The CURVE keys of one node, as read from a keys directory by :meth:`load`.

    Secret keys never appear in ``repr``. ``server_secret_key`` is None on a node that
    only connects (its directory holds the server's public certificate alone).
    """

    keys_dir: Path
    server_public_key: bytes
    client_public_key: bytes
    authorized_dir: Path
    client_secret_key: bytes = dataclasses.field(repr=False)
    server_secret_key: bytes | None = dataclasses.field(default=None, repr=False)

    @classmethod
    def load(cls, keys_dir: str | os.PathLike[str]) -> BusSecurity:
        """Read ``keys_dir`` (layout in the module docstring).

        Raises
        ------
        BusSecurityError
            A certificate is missing, malformed, mismatched or readable by other users.
        """
        directory = Path(keys_dir)
        found = is_dir(directory, "CURVE keys directory")
        if not found and directory.exists():
            raise BusSecurityError(f"CURVE keys directory {directory} is a file, not a directory: set "
                                   "bus.keys_dir to the directory `teleop keys init DIR` made")
        if not found:
            raise BusSecurityError(f"CURVE keys directory {directory} does not exist: {_FIX_HINT}")
        cert_access.check_owner_writes(directory, "CURVE keys directory")
        server_public = read_public_cert(directory / f"{SERVER_CERT}{PUBLIC_SUFFIX}")
        client_public = read_public_cert(directory / f"{CLIENT_CERT}{PUBLIC_SUFFIX}")
        server_secret_path = directory / f"{SERVER_CERT}{SECRET_SUFFIX}"
        return cls(
            keys_dir=directory,
            server_public_key=server_public,
            client_public_key=client_public,
            authorized_dir=directory / AUTHORIZED_DIR,
            client_secret_key=read_secret_cert(
                directory / f"{CLIENT_CERT}{SECRET_SUFFIX}", client_public
            ),
            server_secret_key=(
                read_secret_cert(server_secret_path, server_public)
                if server_secret_path.exists()
                else None
            ),
        )

    @property
    def zap_domain(self) -> str:
        """The ZAP domain of this node's authorised-keys directory (one per directory)."""
        digest = hashlib.sha256(str(self.authorized_dir.resolve()).encode("utf-8")).hexdigest()
        return f"teleop-{digest[:16]}"


@dataclass(frozen=True)
class AuthorizedKey:
    """One client the servers admit: its name (file stem) and Z85 public key."""

    name: str
    public_key: str


def read_authorized(authorized_dir: Path) -> tuple[AuthorizedKey, ...]:
    """Every client certificate (``*.key``) in ``authorized_dir``, read and checked, by name.

    Raises
    ------
    BusSecurityError
        The directory is missing, or a file in it is not a public certificate (named): a
        server handed it would admit no client at all.
    """
    if not is_dir(authorized_dir, "authorised-keys directory"):
        raise BusSecurityError(
            f"authorised-keys directory {authorized_dir} does not exist: run `teleop keys init`"
        )
    try:  # glob would take a directory it may not list for an empty one
        os.listdir(authorized_dir)
    except OSError as exc:
        raise access_error(authorized_dir, "authorised-keys directory", exc) from exc
    cert_access.check_owner_writes(authorized_dir, "authorised-keys directory")
    keys = []
    for path in sorted(authorized_dir.glob(f"*{PUBLIC_SUFFIX}")):
        try:
            keys.append(AuthorizedKey(path.stem, read_public_cert(path).decode("ascii")))
        except CertificateAccessError:
            raise  # a permission problem, not a file to remove
        except BusSecurityError as exc:
            raise BusSecurityError(
                f"{exc}: remove it from {authorized_dir}, or put a client's public certificate "
                "there with `teleop keys add`"
            ) from exc
    return tuple(keys)


def serving_keys(security: BusSecurity) -> tuple[AuthorizedKey, ...]:
    """The clients a CURVE server of ``security`` admits, after checking it can serve at all.

    Raises
    ------
    BusSecurityError
        No server secret certificate (the keys can connect but not bind), or the authorised
        directory is missing or holds a file that is not a public certificate.
    """
    if security.server_secret_key is None:
        raise BusSecurityError(
            f"{security.keys_dir} holds no {SERVER_CERT}{SECRET_SUFFIX}: this node can connect "
            "but not bind; to serve, install the bus's server.key_secret there with mode 0600 (the "
            "two-host setup: `teleop keys --help`)"
        )
    return read_authorized(security.authorized_dir)


def security_from_settings(bus: BusSettings) -> BusSecurity | None:
    """The keys in ``bus.keys_dir`` (None when unset), after checking every bus endpoint.

    Raises
    ------
    BusSecurityError
        An endpoint is not loopback and ``keys_dir`` is unset, or the keys cannot be read.
    """
    security = BusSecurity.load(bus.keys_dir) if bus.keys_dir else None
    check_endpoints((bus.robot_pub, bus.estimate_pub, bus.command), security)
    return security


# --------------------------------------------------------------------------- sockets


class _AuthorizedClients:
    """A ZAP domain's CURVE check: the keys of ``authorized_dir``; names a refused key once."""

    def __init__(self, authorized_dir: Path, keys: Iterable[AuthorizedKey]):
        self.authorized_dir = authorized_dir
        self._keys = frozenset(k.public_key.encode("ascii") for k in keys)
        self._refused: set[bytes] = set()  # touched by the ZAP thread only

    def callback(self, domain: str, client_key: bytes) -> bool:
        if client_key in self._keys:
            return True
        if client_key not in self._refused and len(self._refused) < _MAX_REFUSALS_LOGGED:
            self._refused.add(client_key)
            log.warning(
                "refused a CURVE client with public key %s: it is not authorised in %s; if it "
                "should join, authorise its client.key with `teleop keys add` and restart this "
                "node",
                client_key.decode("ascii", "replace"), self.authorized_dir,
            )
        return False


class _ZapHandlers:
    """One ThreadAuthenticator per context, shared by its CURVE servers, counted by lease."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._leases: dict[zmq.Context, tuple[ThreadAuthenticator, int]] = {}

    def lease(
        self, context: zmq.Context, domain: str, authorized_dir: Path, keys: Iterable[AuthorizedKey]
    ) -> Callable[[], None]:
        """Start (or share) the context's handler; admit ``keys`` (of ``authorized_dir``)."""
        keys = tuple(keys)
        if not keys:
            log.warning("%s holds no client keys: every client will be refused", authorized_dir)
        with self._lock:
            authenticator, count = self._leases.get(context, (None, 0))
            if authenticator is None:
                authenticator = ThreadAuthenticator(context, log=log.getChild("zap"))
                try:
                    authenticator.start()
                except zmq.ZMQError as exc:  # another ZAP handler already serves this context
                    authenticator.stop()
                    raise BusSecurityError(
                        f"cannot start the ZAP handler on this ZeroMQ context: {exc}"
                    ) from exc
            # our own reader, not configure_curve's: that one only logs a file it cannot read,
            # then refuses every client
            authenticator.configure_curve_callback(
                domain=domain, credentials_provider=_AuthorizedClients(authorized_dir, keys)
            )
            self._leases[context] = (authenticator, count + 1)
        released = False

        def release() -> None:  # idempotent: a socket gives its lease back once
            nonlocal released
            with self._lock:
                if released:
                    return
                released = True
                authenticator, count = self._leases.pop(context)
                if count > 1:
                    self._leases[context] = (authenticator, count - 1)
                else:
                    authenticator.stop()

        return release

    def running(self, context: zmq.Context) -> bool:
        """Whether a handler serves ``context`` (for tests and diagnostics)."""
        with self._lock:
            return context in self._leases


ZAP_HANDLERS = _ZapHandlers()


def _nothing() -> None:
    return None


def apply_security(
    socket: zmq.Socket, security: BusSecurity | None, *, server: bool
) -> Callable[[], None]:
    """Make ``socket`` a CURVE server or client (nothing when ``security`` is None).

    Call before binding or connecting. A server leases the context's ZAP handler; the
    returned function gives the lease back and must be called once the socket is closed.

    Raises
    ------
    BusSecurityError
        A server without the server secret key or with an unreadable authorised-keys
        directory (:func:`serving_keys`), or keys libzmq refuses.
    """
    if security is None:
        return _nothing
    authorized = serving_keys(security) if server else ()
    try:
        if not server:
            socket.curve_serverkey = security.server_public_key
            socket.curve_publickey = security.client_public_key
            socket.curve_secretkey = security.client_secret_key
            return _nothing
        socket.curve_server = True
        socket.curve_publickey = security.server_public_key
        socket.curve_secretkey = security.server_secret_key
        socket.zap_domain = security.zap_domain.encode("ascii")
        socket.setsockopt(zmq.ZAP_ENFORCE_DOMAIN, 1)  # no ZAP handler answering: refuse
    except zmq.ZMQError as exc:
        raise BusSecurityError(
            f"libzmq refused the CURVE keys from {security.keys_dir}: {exc}"
        ) from exc
    # last, so nothing above can fail while holding a lease; the handler runs before bind
    return ZAP_HANDLERS.lease(
        socket.context, security.zap_domain, security.authorized_dir, authorized
    )


# --------------------------------------------------------------------------- key management


@dataclass(frozen=True)
class KeyListing:
    """What a keys directory holds; public keys only (Z85 text)."""

    keys_dir: str
    server_public_key: str
    can_serve: bool  # the server secret certificate is present
    client_public_key: str
    authorized: tuple[AuthorizedKey, ...]


def list_keys(keys_dir: str | os.PathLike[str]) -> KeyListing:
    """Read and check ``keys_dir``; the public keys it holds and the clients it admits."""
    security = BusSecurity.load(keys_dir)
    authorized = read_authorized(security.authorized_dir)
    return KeyListing(
        keys_dir=str(security.keys_dir),
        server_public_key=security.server_public_key.decode("ascii"),
        can_serve=security.server_secret_key is not None,
        client_public_key=security.client_public_key.decode("ascii"),
        authorized=authorized,
    )


def init_keys(
    keys_dir: str | os.PathLike[str], *, server_cert: str | os.PathLike[str] | None = None
) -> KeyListing:
    """Create the key pairs of a new keys directory and authorise its own client.

    Without ``server_cert`` a server key pair is made (the node can bind and connect);
    with it, that server's public certificate is copied in instead (a node that only
    connects to that server; authorise its ``client.key`` there with ``teleop keys add``).
    Key pairs come from :func:`zmq.auth.create_certificates`, written in a private
    staging directory and moved in with secret files at mode 0600.

    Raises
    ------
    BusSecurityError
        ``keys_dir`` already holds keys, or ``server_cert`` is not a public certificate.
    """
    directory = Path(keys_dir)
    server_public = None if server_cert is None else read_public_cert(Path(server_cert), in_place=False)
    try:
        names = (f"{n}{s}" for n in (SERVER_CERT, CLIENT_CERT) for s in (PUBLIC_SUFFIX, SECRET_SUFFIX))
        existing = [p for p in (directory / name for name in names) if p.exists()]
        has_authorized = (directory / AUTHORIZED_DIR).exists()
    except OSError as exc:  # a folder on the way this user may not search
        raise access_error(directory, "CURVE keys directory", exc) from exc
    if existing or has_authorized:
        found = ", ".join(p.name for p in existing) or AUTHORIZED_DIR
        raise BusSecurityError(
            f"{directory} already holds CURVE keys ({found}): "
            "choose a new directory; keys are never overwritten"
        )
    try:
        cert_access.make_private_dir(directory)
        staging = Path(tempfile.mkdtemp(prefix=".keys-", dir=directory))  # mode 0700
        try:
            names = (CLIENT_CERT,) if server_public is not None else (CLIENT_CERT, SERVER_CERT)
            for name in names:
                public, secret = map(Path, zmq.auth.create_certificates(staging, name))
                secret.chmod(0o600)
                public.chmod(0o644)
                public.replace(directory / public.name)
                secret.replace(directory / secret.name)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        if server_cert is not None:
            cert_access.copy_public(server_cert, directory / f"{SERVER_CERT}{PUBLIC_SUFFIX}")
        (directory / AUTHORIZED_DIR).mkdir(mode=0o755)
        cert_access.copy_public(
            directory / f"{CLIENT_CERT}{PUBLIC_SUFFIX}",
            directory / AUTHORIZED_DIR / f"{CLIENT_CERT}{PUBLIC_SUFFIX}",
        )
    except OSError as exc:
        raise BusSecurityError(f"cannot create CURVE keys in {directory}: {exc}") from exc
    return list_keys(directory)


def authorize_key(
    keys_dir: str | os.PathLike[str], cert: str | os.PathLike[str], *, name: str | None = None
) -> AuthorizedKey:
    """Admit the client whose public certificate is ``cert``, as ``authorized/NAME.key``.

    ``name`` defaults to the certificate's file stem.

    Raises
    ------
    BusSecurityError
        ``cert`` is not a public certificate (a secret one is refused), the name is taken
        or invalid, or the key is already authorised under another name.
    """
    cert = Path(cert)
    name = _check_name(cert.stem if name is None else name)
    public = read_public_cert(cert, in_place=False).decode("ascii")
    listing = list_keys(keys_dir)
    for known in listing.authorized:
        if known.name == name:
            raise BusSecurityError(
                f"a key named {name!r} is already authorised in {keys_dir}: pass --name"
            )
        if known.public_key == public:
            raise BusSecurityError(f"{cert} is already authorised in {keys_dir} as {known.name!r}")
    target = Path(keys_dir) / AUTHORIZED_DIR / f"{name}{PUBLIC_SUFFIX}"
    try:
        cert_access.copy_public(cert, target)
    except OSError as exc:
        raise BusSecurityError(f"cannot write {target}: {exc}") from exc
    return AuthorizedKey(name, public)


def revoke_key(keys_dir: str | os.PathLike[str], name: str) -> AuthorizedKey:
    """Stop admitting the client ``name`` (takes effect when the servers restart).

    Raises
    ------
    BusSecurityError
        No key of that name is authorised (the message lists those that are).
    """
    name = _check_name(name)
    listing = list_keys(keys_dir)
    for known in listing.authorized:
        if known.name == name:
            target = Path(keys_dir) / AUTHORIZED_DIR / f"{name}{PUBLIC_SUFFIX}"
            try:
                target.unlink()
            except OSError as exc:
                raise BusSecurityError(f"cannot remove {target}: {exc}") from exc
            return known
    names = ", ".join(k.name for k in listing.authorized) or "none"
    raise BusSecurityError(
        f"no key named {name!r} is authorised in {keys_dir} (authorised: {names})"
    )
