"""Admission to a secured team: who may join, and why not (``--secure``).

How this works: with the checked ``Credentials`` of ``ramps.runtime.credentials``,
Zenoh uses TLS links only, with mutual authentication against the team CA,
and access control that admits only the team's key expressions
(``ramps/<team>/**``) and denies everything else (``secure_zenoh_json``).

Zenoh refuses a stranger silently (the session opens, the team stays empty),
and its ``connect/exit_on_failure`` wants *every* connect endpoint. So before
opening Zenoh, ``admission`` tries the team's TLS handshake with each connect
endpoint itself (``probe_tls``, all at once, about 1 s at most): a refusal
becomes ``NotAdmitted`` at once, naming who refused and why; fail-fast is
asked of Zenoh only when every endpoint admitted us; nobody listening (the
first robot up) is no error. ``open_session`` sorts out a Zenoh failure after
that, and ``tls_listeners`` tells a client without ``--secure`` that the team
is secured.

Rules: ``secure_zenoh_json`` is a pure function; the "joining" and
"diagnosis" sections touch the network. Nothing here is imported by
``ramps.core``.
"""

from __future__ import annotations

import socket
import ssl
from collections.abc import Callable
from typing import TYPE_CHECKING

from ramps.errors import NotAdmitted
from ramps.runtime.credentials import Credentials

if TYPE_CHECKING:
    import zenoh

#: every message kind a ramps node or client sends or receives
ACL_MESSAGES = ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"]


# ====================================================================== Zenoh
def secure_zenoh_json(team: str, creds: Credentials, *, members: list[str] | None = None) -> dict:
    """The parts of a Zenoh config that make a secured team: mutual TLS
    against the team CA (both listen_* and connect_* keys: every peer of a
    gossip mesh both accepts and opens links), TLS links only, and access
    control that allows the team's key expressions and denies the rest.

    Peers are admitted by certificate: the TLS handshake admits only
    certificates of the team CA, and the access-control subject names the
    common names allowed (``members``; every team certificate when empty).
    Server names are not checked (``verify_name_on_connect: false``): robots
    are reached by whatever address gossip or scouting found, and the team CA,
    not a host name, is what identifies a teammate."""
    subject: dict = {"id": "team"}
    if members:
        subject["cert_common_names"] = sorted(set(members))
    return {
        "transport/link/protocols": ["tls"],
        "transport/link/tls": {
            "root_ca_certificate": str(creds.ca),
            "listen_private_key": str(creds.key), "listen_certificate": str(creds.cert),
            "connect_private_key": str(creds.key), "connect_certificate": str(creds.cert),
            "enable_mtls": True,
            "verify_name_on_connect": False,
        },
        "access_control": {
            "enabled": True,
            "default_permission": "deny",
            "rules": [{"id": "team-keys", "permission": "allow", "flows": ["ingress", "egress"],
                       "messages": ACL_MESSAGES, "key_exprs": [f"ramps/{team}/**"]}],
            "subjects": [subject],
            "policies": [{"rules": ["team-keys"], "subjects": ["team"]}],
        },
    }



# ====================================================================== joining (network)
def probe_all(endpoints: list[str], creds: Credentials | None, timeout: float = 1.0) -> dict[str, str]:
    """``probe_tls`` of every endpoint at once (threads): at most ``timeout`` s or so."""
    from concurrent.futures import ThreadPoolExecutor

    if not endpoints:
        return {}
    with ThreadPoolExecutor(max_workers=min(16, len(endpoints))) as pool:
        verdicts = list(pool.map(lambda e: probe_tls(e, creds, timeout), endpoints))
    return dict(zip(endpoints, verdicts))


def admission(endpoints: list[str], creds: Credentials, *, team: str, timeout: float = 1.0) -> bool:
    """Before opening Zenoh: try the team's TLS handshake with every connect
    endpoint. Raise ``NotAdmitted`` when none admits these credentials and at
    least one refused them (or is not a teammate); return whether every
    endpoint admitted them (then ``connect/exit_on_failure`` is safe: Zenoh
    wants all of them). When nobody listens yet (the first robot up), return
    False and let Zenoh keep trying in the background."""
    verdicts = probe_all(endpoints, creds, timeout)
    admitted = [e for e, v in verdicts.items() if v == ""]
    refused = {e: v for e, v in verdicts.items() if v not in ("", "unreachable")}
    if not admitted and refused:
        raise NotAdmitted(not_admitted_message(team, creds, refused))
    return bool(endpoints) and len(admitted) == len(endpoints)


def not_admitted_message(team: str, creds: Credentials, refused: dict[str, str]) -> str:
    """One sentence per distinct reason, naming the endpoints it came from."""
    by_reason: dict[str, list[str]] = {}
    for endpoint, reason in refused.items():
        by_reason.setdefault(reason, []).append(endpoint)
    return (f"team {team!r} did not admit robot {creds.robot!r}: "
            + "; ".join(f"{', '.join(eps)}: {reason}" for reason, eps in by_reason.items())
            + f". Robots of one team need credentials from the same team CA (`ramps team add`); "
            f"this robot's CA is {creds.ca}")


def open_session(config_for: Callable[[bool], zenoh.Config], endpoints: list[str], creds: Credentials, *,
                 team: str, fail_fast: bool) -> zenoh.Session:
    """``zenoh.open(config_for(fail_fast))``, where ``fail_fast`` (from
    ``admission``) sets ``connect/exit_on_failure``. If Zenoh then fails:
    a refusal is ``NotAdmitted``; a teammate that went away since the
    admission check is no reason to fail (open again, Zenoh keeps trying);
    Zenoh failing where TLS works is ``NotAdmitted`` too, with the reason."""
    import zenoh

    try:
        return zenoh.open(config_for(fail_fast))
    except zenoh.ZError as exc:
        if not fail_fast:
            raise
        verdicts = probe_all(endpoints, creds)
        refused = {e: v for e, v in verdicts.items() if v not in ("", "unreachable")}
        if refused:
            raise NotAdmitted(not_admitted_message(team, creds, refused)) from exc
        if "unreachable" not in verdicts.values():
            raise NotAdmitted(f"team {team!r}: TLS with {', '.join(endpoints)} works but Zenoh could not link "
                              f"to all of them ({exc}); do they run with --secure for team {team}?") from exc
    return zenoh.open(config_for(False))


def tls_listeners(endpoints: list[str], timeout: float = 1.0) -> list[str]:
    """Which of ``endpoints`` answer with TLS: a secured team, seen by a client
    that is not secured."""
    return [e for e, v in probe_all(endpoints, None, timeout).items() if v == "tls"]


# ====================================================================== diagnosis (network)
def _host_port(endpoint: str) -> tuple[str, int] | None:
    """('127.0.0.1', 7447) from 'tls/127.0.0.1:7447', 'tcp/[::1]:7447#iface=lo'."""
    _, sep, addr = endpoint.partition("/")
    if not sep:
        return None
    addr = addr.split("#", 1)[0].split("?", 1)[0]
    host, _, port = addr.rpartition(":")
    if not host or not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def reachable(endpoint: str, timeout: float = 1.0) -> bool:
    """Does anything accept a TCP connection at this endpoint?"""
    hp = _host_port(endpoint)
    if hp is None:
        return False
    try:
        with socket.create_connection(hp, timeout=timeout):
            return True
    except OSError:
        return False


def probe_tls(endpoint: str, creds: Credentials | None = None, timeout: float = 1.0) -> str:
    """Why a TLS link to ``endpoint`` would fail, in words ('' if it would not,
    'unreachable' if nothing listens there).

    With ``creds`` it tries the team handshake (our certificate, their
    certificate checked against our CA); without, it only asks whether a TLS
    server is there ('tls' or 'unreachable' or 'not tls')."""
    hp = _host_port(endpoint)
    if hp is None:
        return "unreachable"
    ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_CLIENT)
    ctx.check_hostname = False
    if creds is None:
        ctx.verify_mode = ssl.CERT_NONE
    else:
        ctx.load_verify_locations(cafile=str(creds.ca))
        ctx.load_cert_chain(str(creds.cert), str(creds.key))
    try:
        raw = socket.create_connection(hp, timeout=timeout)
    except OSError:
        return "unreachable"
    try:
        with ctx.wrap_socket(raw, server_hostname=hp[0]) as s:
            if creds is None:
                return "tls"
            return _await_acceptance(s, timeout / 2)
    except ssl.SSLCertVerificationError as exc:
        return f"the robot there holds a certificate from another CA than this robot's ({exc.verify_message})"
    except ssl.SSLError as exc:
        text = str(exc).lower()
        if creds is None:
            return "tls" if "alert" in text else "not tls"
        if "alert" in text:
            return f"the robot there refused this robot's certificate ({exc.reason or exc})"
        return f"the TLS handshake failed ({exc.reason or exc}); is it a secured ramps node?"
    except OSError as exc:
        if creds is None:
            return "not tls"
        return f"the TLS handshake failed ({exc}); is it a secured ramps node?"
    finally:
        raw.close()


def _await_acceptance(s: ssl.SSLSocket, timeout: float) -> str:
    """TLS 1.3 finishes the client's handshake before the server has checked
    the client's certificate: a refusal arrives as an alert afterwards, an
    acceptance as a session ticket (rustls sends them). Wait for either."""
    import time

    s.setblocking(False)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            if not s.recv(1):
                return "the peer closed the connection after the TLS handshake"
        except ssl.SSLWantReadError:
            pass
        if s.session is not None and s.session.has_ticket:
            return ""
        time.sleep(0.005)
    return ""  # no alert in time: taken as admitted
