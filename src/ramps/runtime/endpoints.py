"""Addresses a node is given: Zenoh endpoints and the metrics address.

Rules: each check raises ``ValueError`` with a message for users, before
Zenoh or a server sees the text (``ramps.runtime.settings`` calls them while
it validates a node's settings).
"""

from __future__ import annotations

#: Zenoh link protocols whose address is HOST:PORT
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
_OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")


def check_endpoint(endpoint: str) -> None:
    """A Zenoh endpoint looks like ``tcp/192.168.1.12:7447`` (or ``tls/``, ``udp/``,
    ``quic/``, ``ws/``; ``[::1]`` for IPv6; ``#iface=eth0`` or ``?`` options after it).
    Raise ValueError saying what is wrong, before Zenoh sees it."""
    proto, sep, addr = endpoint.partition("/")
    example = "e.g. tcp/192.168.1.12:7447"
    if not sep or not addr:
        raise ValueError(f"endpoint {endpoint!r} must look like PROTOCOL/HOST:PORT, {example}")
    if proto in _OTHER_PROTOCOLS:
        return
    if proto not in _IP_PROTOCOLS:
        raise ValueError(f"endpoint {endpoint!r}: unknown protocol {proto!r} "
                         f"(use one of {', '.join(_IP_PROTOCOLS + _OTHER_PROTOCOLS)}), {example}")
    hostport = addr.split("#", 1)[0].split("?", 1)[0]
    host, colon, port = hostport.rpartition(":")
    if not colon or not host.strip("[]") or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"endpoint {endpoint!r} needs a host and a port 0-65535 after {proto}/, {example}")


def parse_metrics_address(text: str) -> tuple[str, int]:
    """``"ADDR:PORT"``, ``":PORT"`` or ``"PORT"`` -> (addr, port); addr
    defaults to 127.0.0.1 (metrics are not for the whole network unless
    asked: ``0.0.0.0:9464``). Raises ValueError with a message for users."""
    text = text.strip()
    host, sep, port = text.rpartition(":")
    if not sep:
        host, port = "", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        number = int(port)
    except ValueError:
        raise ValueError(f"metrics address {text!r} must look like ADDR:PORT, e.g. 127.0.0.1:9464 "
                         "or 0.0.0.0:9464") from None
    if not 0 <= number <= 65535:
        raise ValueError(f"metrics port {number} is not in 0..65535")
    return host, number
