"""Per-robot revocation for a secured team: shut one robot out without a new team CA.

How this works: ``ramps team revoke r3`` (on the machine holding the team CA
key) adds r3 to the team's revocation list, a small document signed with
the CA key: the team, a sequence number that only grows, when it was
issued and the revoked robot names. It is written as ``revoked.json`` into
the CA directory and into every robot bundle there (so a robot set up or
re-copied later carries it), and, with ``--connect``, published to the
running team on ``ramps/<team>/revoked``.

Every secured node checks the list signature against the team CA it already
holds (``ca.pem``), keeps the newest one (highest sequence number), saves it
beside its credentials (so it survives a restart), and republishes it every
REPUBLISH_PERIOD seconds, so a node that was away learns it from any
teammate. A node that learns a teammate is revoked drops everything that
teammate sends (load reports, offload requests, results, liveliness),
writes off the programs it hosted and never places one there again, and
stops the programs it hosts for it. A node that learns that it is revoked
itself hands its programs back and leaves the team, and a revoked robot's
node refuses to start (``NotAdmitted``).

What this cannot do: Zenoh's TLS and access control are configured when a
session opens and cannot drop an established link, and they do not tell the
application which certificate sent a message. A revoked robot that keeps
its Zenoh links and lies about its name is therefore not stopped by the
list alone. At the transport, a node's ``members`` setting (config file or
``RAMPS_MEMBERS``: the certificate names it admits) refuses a certificate
from the session's start, whatever name it claims; a deny rule for the
revoked names alone does not (with ``default_permission: deny``, Zenoh
1.10 lets the team's allow rule win: measured on loopback). So for a robot
that is compromised, not just retired or lost: list the others in
``members`` and restart the nodes, or replace the team CA. Only a secured team has revocation (an open team has no
CA to sign a list with).

Wire and file format: msgpack on the wire, JSON in the file, both the
``RevocationList`` schema with its limits; the signature is ECDSA-SHA256
(the CA's key) over the msgpack encoding of the list with an empty
signature.
"""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import msgspec

from ramps.errors import CredentialsError
from ramps.runtime import keys

if TYPE_CHECKING:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec

REVOKED_FILE = "revoked.json"
#: the most robots one list may name
MAX_REVOKED = 4096
#: seconds between two republications of a node's list
REPUBLISH_PERIOD = 5.0
#: largest list accepted from the network, bytes
MAX_LIST_BYTES = MAX_REVOKED * 80 + 1024

_Name = Annotated[str, msgspec.Meta(pattern=r"^[A-Za-z0-9_.-]{1,64}$")]


class RevocationList(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    team: _Name
    seq: Annotated[int, msgspec.Meta(ge=0, le=2**53)]
    #: when the CA key holder signed it (ISO 8601, UTC)
    issued: Annotated[str, msgspec.Meta(max_length=40)]
    robots: Annotated[list[_Name], msgspec.Meta(max_length=MAX_REVOKED)]
    sig: Annotated[bytes, msgspec.Meta(max_length=256)] = b""


_mp_dec = msgspec.msgpack.Decoder(RevocationList)
_js_dec = msgspec.json.Decoder(RevocationList)


def _signed_bytes(rl: RevocationList) -> bytes:
    return msgspec.msgpack.encode(msgspec.structs.replace(rl, sig=b""))


def sign(rl: RevocationList, ca_key: ec.EllipticCurvePrivateKey) -> RevocationList:
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec

    rl = msgspec.structs.replace(rl, robots=sorted(set(rl.robots)), sig=b"")
    return msgspec.structs.replace(rl, sig=ca_key.sign(_signed_bytes(rl), ec.ECDSA(hashes.SHA256())))


def verify(rl: RevocationList, ca_cert: x509.Certificate, team: str) -> RevocationList:
    """``rl`` if it is for ``team`` and signed by its CA, else ``CredentialsError``."""
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec

    if rl.team != team:
        raise CredentialsError(f"revocation list is for team {rl.team!r}, not {team!r}")
    ca_public = ca_cert.public_key()
    try:
        if not isinstance(ca_public, ec.EllipticCurvePublicKey):  # not a CA ramps makes: it signed nothing
            raise InvalidSignature
        ca_public.verify(rl.sig, _signed_bytes(rl), ec.ECDSA(hashes.SHA256()))
    except (InvalidSignature, TypeError, ValueError):
        raise CredentialsError(f"revocation list {rl.seq} of team {team!r} is not signed by the team CA") from None
    return rl


def decode(data: bytes, ca_cert: x509.Certificate, team: str) -> RevocationList:
    """A list received from the network: size, schema, team and signature
    checked; any failure is ``CredentialsError`` (remote bad input)."""
    if len(data) > MAX_LIST_BYTES:
        raise CredentialsError(f"revocation list of {len(data)} bytes is over the limit of {MAX_LIST_BYTES}")
    try:
        rl = _mp_dec.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:  # ValueError: bad UTF-8
        raise CredentialsError(f"not a revocation list: {exc}") from None
    return verify(rl, ca_cert, team)


def encode(rl: RevocationList) -> bytes:
    return msgspec.msgpack.encode(rl)


def load(path: str | os.PathLike[str], ca_cert: x509.Certificate, team: str) -> RevocationList | None:
    """The list in ``path`` (None if there is no such file), checked."""
    p = Path(path)
    try:
        data = p.read_bytes()
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise CredentialsError(f"cannot read the revocation list {p}: {exc.strerror or exc}") from None
    try:
        rl = _js_dec.decode(data)
    except (msgspec.DecodeError, msgspec.ValidationError, ValueError) as exc:
        raise CredentialsError(f"{p} is not a revocation list ({exc}); get it again from the team CA's "
                               f"directory, or remove it") from None
    try:
        return verify(rl, ca_cert, team)
    except CredentialsError as exc:
        raise CredentialsError(f"{p}: {exc}") from None


def save(path: str | os.PathLike, rl: RevocationList) -> None:
    """Write atomically (a reader never sees half a list)."""
    p = Path(path)
    tmp = p.with_name(p.name + f".tmp{os.getpid()}")
    tmp.write_bytes(msgspec.json.format(msgspec.json.encode(rl)) + b"\n")
    os.replace(tmp, p)


def revoke(directory: str | os.PathLike, robots: list[str], *, now: _dt.datetime | None = None
           ) -> tuple[RevocationList, list[Path]]:
    """Add ``robots`` to the team's list in the CA ``directory`` (signed with
    its key); returns the list and every file written (the CA directory's
    and each robot bundle's ``revoked.json``)."""
    from ramps.runtime.security import BUNDLE_CERT, load_ca

    ca_cert, ca_key, team = load_ca(directory)
    for r in robots:
        keys.check_name("robot", r)
    d = Path(directory)
    old = load(d / REVOKED_FILE, ca_cert, team)
    when = (now or _dt.datetime.now(_dt.UTC)).strftime("%Y-%m-%dT%H:%M:%SZ")
    names = sorted(set(old.robots if old else []) | set(robots))
    if len(names) > MAX_REVOKED:
        raise CredentialsError(f"a revocation list names at most {MAX_REVOKED} robots")
    rl = sign(RevocationList(team=team, seq=(old.seq + 1) if old else 1, issued=when, robots=names), ca_key)
    written = [d / REVOKED_FILE]
    written += [sub / REVOKED_FILE for sub in sorted(d.iterdir()) if (sub / BUNDLE_CERT).exists()]
    for path in written:
        save(path, rl)
    return rl, written


def publish(rl: RevocationList, *, team: str, connect: list[str], credentials: str, multicast: bool = False,
            wait: float = 10.0, repeat: int = 3) -> tuple[int, float]:
    """Tell a running secured team: join it with ``credentials`` (any team
    bundle), publish the list ``repeat`` times, leave. Returns how many
    teammates were linked when it was sent (0: nobody heard it) and when
    (``time.monotonic()``) it was first sent."""
    import time

    import zenoh

    from ramps.runtime.security import check_credentials, credential_paths
    from ramps.runtime.settings import NodeSettings
    from ramps.runtime.zenoh_configs import zenoh_config

    creds = check_credentials(*credential_paths(credentials), team=team)
    s = NodeSettings(robot=keys.keys_safe_id(f"revoker-{creds.robot}"), team=team, connect=list(connect),
                     multicast=multicast, secure=True, credentials=str(credentials))
    with zenoh.open(zenoh_config(s, listen=[], credentials=creds)) as session:
        deadline = time.monotonic() + wait
        while not list(session.info.peers_zid()) and time.monotonic() < deadline:
            time.sleep(0.1)
        peers = len(list(session.info.peers_zid()))
        sent_at = time.monotonic()
        if peers:
            pub = session.declare_publisher(revoked_key(team))
            for i in range(repeat):
                pub.put(encode(rl))
                time.sleep(0.2)
            pub.undeclare()
    return peers, sent_at


def revoked_key(team: str) -> str:
    return f"ramps/{team}/revoked"
