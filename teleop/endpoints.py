"""ZeroMQ endpoint text taken apart: the one reading of it, for the settings' ``[bus]`` table and the bus.

:func:`parse_endpoint` gives an :class:`Endpoint`; :data:`BUS_TRANSPORTS` are those a bus endpoint
may use.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "BUS_TRANSPORTS",
    "ENDPOINT_FORMS",
    "NAME_TRANSPORTS",
    "PORT_TRANSPORTS",
    "WILDCARD_HOSTS",
    "Endpoint",
    "parse_endpoint",
    "same_socket",
]

#: The ZeroMQ transports by how an endpoint names its peer: HOST:PORT (``tcp://SRC;HOST:PORT`` also
#: names a source address, ``epgm://IFACE;GROUP:PORT`` an interface, ``ws://HOST:PORT/PATH`` a path),
#: or a path or name of the transport's own. Which of them other hosts reach is
#: :mod:`teleop.bus.security`'s to say.
PORT_TRANSPORTS = frozenset({"tcp", "udp", "ws", "wss", "pgm", "epgm", "norm"})
NAME_TRANSPORTS = frozenset({"inproc", "ipc", "tipc", "vmci"})
#: The transports a ``[bus]`` endpoint may use: tcp between hosts, ipc between the processes of one
#: host, inproc within one process. The others carry no pub/sub or need a libzmq built for them.
BUS_TRANSPORTS = ("tcp", "ipc", "inproc")
ENDPOINT_FORMS = "tcp://HOST:PORT, ipc://PATH or inproc://NAME"
#: Hosts that bind every interface: such an endpoint holds its port on every address of the host.
WILDCARD_HOSTS = frozenset({"*", "0.0.0.0", "::"})


@dataclass(frozen=True)
class Endpoint:
    """A ZeroMQ endpoint taken apart (:func:`parse_endpoint`): its ``scheme``, what follows ``://``
    (``address``), for a HOST:PORT transport its ``hosts`` (a source address or interface first,
    the peer's last) and its ``port``: None for ``*`` (any free port, for the end that binds) and
    for a transport without ports."""

    scheme: str
    address: str
    hosts: tuple[str, ...] = ()
    port: int | None = None

    @property
    def host(self) -> str:
        """The host bound or connected to ('' for a transport without hosts)."""
        return self.hosts[-1] if self.hosts else ""

    @property
    def ipv6(self) -> bool:
        """Whether a host is an IPv6 address: ZeroMQ takes one only on a socket with ``ZMQ_IPV6``,
        which is set for such endpoints alone (with it, a name such as localhost may resolve to ::1,
        where a peer bound to 127.0.0.1 does not listen)."""
        return any(":" in h for h in self.hosts)


def _without_port(source: str) -> str:
    """A source address without the port it may name (``SRC:PORT``; an IPv6 one in brackets)."""
    host, colon, port = source.rpartition(":")
    return host if colon and port.isdigit() and not source.endswith("]") else source


def parse_endpoint(endpoint: str) -> Endpoint:
    """``endpoint`` taken apart: the one reading of endpoint text, for the settings and the bus.

    Raises ValueError saying what is wrong and what was expected (the caller names the endpoint).
    """
    scheme, sep, address = endpoint.partition("://")
    if not sep or scheme not in PORT_TRANSPORTS | NAME_TRANSPORTS:
        raise ValueError(f"not a ZeroMQ endpoint: expected {ENDPOINT_FORMS}")
    if not address:
        raise ValueError(f"nothing after {scheme}://: expected {ENDPOINT_FORMS}")
    if scheme in NAME_TRANSPORTS:
        return Endpoint(scheme, address)
    place, colon, port = address.split("/", 1)[0].rpartition(":")  # ws: a path follows the port
    if not colon or "]" in port:  # "[::1]" alone: the colons are the IPv6 address's
        raise ValueError(f"no port: expected {scheme}://HOST:PORT")
    *sources, host = place.split(";")
    hosts = (*(_without_port(s) for s in sources), host)
    if not all(hosts):
        raise ValueError(f"no host: expected {scheme}://HOST:PORT")
    if port == "*":
        return Endpoint(scheme, address, hosts)
    # ZeroMQ itself reads a port modulo 65536 (99999 binds 34463): refuse what it would not say
    if not (port.isascii() and port.isdigit() and 1 <= int(port) <= 65535):
        raise ValueError(f"port {port!r}: expected an integer in 1..65535, or * for any free one")
    return Endpoint(scheme, address, hosts, int(port))


def _bound_host(host: str) -> str:
    """``host`` as the address it binds: without IPv6 brackets, lower case, ``localhost`` as
    127.0.0.1 (the one name read without a DNS lookup, which a settings file must not wait on)."""
    host = host.removeprefix("[").removesuffix("]").lower()
    return "127.0.0.1" if host == "localhost" else host


def same_socket(a: Endpoint, b: Endpoint) -> bool:
    """Whether binding ``a`` and ``b`` would need the same socket: a HOST:PORT transport's same port
    on the same host (a wildcard host is every one of them; a source address is not bound), or
    the same path or name of a transport without ports. A port of ``*`` (any free one) clashes
    with nothing."""
    if a.scheme != b.scheme:
        return False
    if not a.hosts:
        return a.address == b.address
    if a.port is None or a.port != b.port:
        return False
    hosts = {_bound_host(a.host), _bound_host(b.host)}
    return len(hosts) == 1 or bool(hosts & WILDCARD_HOSTS)
