"""Team credentials on disk: a team certificate authority, robot keys and
certificates, made and checked (``ramps team init/add``, ``--secure``).

How this works: ``ramps team init`` makes one certificate authority (CA) per
team; its subject carries the team name. ``ramps team add r1`` issues robot
r1 a key and a certificate signed by that CA, with the robot name as the
common name (CN) and the team name as the organisational unit, into a bundle
directory ``<ca dir>/r1/`` of three files, which is all a robot needs:

    ca.pem      the team CA's certificate (public)
    cert.pem    this robot's certificate
    key.pem     this robot's private key (mode 0600)

The CA key (``ca.key``) never leaves the machine that ran ``team init``.

A secured node or client loads and checks its bundle before it opens Zenoh
(``check_credentials``: files present, key matches certificate, certificate
issued by the CA, valid now, for this team and robot) and fails with a
``CredentialsError`` naming the file and the fix. Who may then join the team
(TLS, access control, probing the teammates) is ``ramps.runtime.admission``.

Rules: plain functions of files and ``now``; no network. Nothing here is
imported by ``ramps.core``.
"""

from __future__ import annotations

import datetime as _dt
import ipaddress
import os
import stat
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

from ramps.errors import CredentialsError
from ramps.runtime import keys

if TYPE_CHECKING:
    from cryptography import x509
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.hazmat.primitives.asymmetric.types import PrivateKeyTypes, PublicKeyTypes

CA_CERT = "ca.pem"
CA_KEY = "ca.key"
BUNDLE_CA = "ca.pem"
BUNDLE_CERT = "cert.pem"
BUNDLE_KEY = "key.pem"
DEFAULT_DIR = "ramps-team"
CA_DAYS = 3650
ROBOT_DAYS = 730


@dataclass(frozen=True)
class Credentials:
    """A checked bundle: paths for Zenoh, and what the certificate says."""

    ca: Path
    cert: Path
    key: Path
    robot: str  # the certificate's common name
    team: str
    not_after: _dt.datetime


# ====================================================================== creating
def _now(now: _dt.datetime | None) -> _dt.datetime:
    return now or _dt.datetime.now(_dt.UTC)


def _write(path: Path, data: bytes, *, private: bool, force: bool) -> None:
    """Write ``data`` to ``path`` (0600 when private), refusing to replace a
    file unless ``force``; written to a temporary name first, then renamed."""
    if path.exists() and not force:
        raise CredentialsError(f"{path} already exists; pass --force to replace it")
    tmp = path.with_name(f".{path.name}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600 if private else 0o644)
    try:
        os.fchmod(fd, 0o600 if private else 0o644)  # whatever the umask says
        os.write(fd, data)
    finally:
        os.close(fd)
    os.replace(tmp, path)


def _name(cn: str, team: str) -> x509.Name:
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ramps"),
                      x509.NameAttribute(NameOID.ORGANIZATIONAL_UNIT_NAME, team)])


def _key_pem(key: PrivateKeyTypes) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert: x509.Certificate) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)


def create_ca(directory: str | os.PathLike, team: str, *, days: int = CA_DAYS, force: bool = False,
              now: _dt.datetime | None = None) -> Path:
    """Make a team CA in ``directory``: ``ca.key`` (0600) and a self-signed
    ``ca.pem``. Refuses to replace an existing CA unless ``force``."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec

    keys.check_name("team", team)
    d = Path(directory)
    if not force and ((d / CA_KEY).exists() or (d / CA_CERT).exists()):
        raise CredentialsError(f"{d} already holds a team CA; pass --force to replace it "
                               "(every robot certificate it issued then stops working)")
    d.mkdir(parents=True, exist_ok=True)
    key = ec.generate_private_key(ec.SECP256R1())
    start = _now(now) - _dt.timedelta(minutes=5)  # tolerate clocks a little behind
    name = _name(f"ramps team {team} CA", team)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(start + _dt.timedelta(days=days))
            .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=True,
                                         crl_sign=True, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .sign(key, hashes.SHA256()))
    _write(d / CA_KEY, _key_pem(key), private=True, force=True)
    _write(d / CA_CERT, _cert_pem(cert), private=False, force=True)
    return d


def load_ca(directory: str | os.PathLike[str]) -> tuple[x509.Certificate, ec.EllipticCurvePrivateKey, str]:
    """The CA certificate, its key and the team name stored in ``directory``."""
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ec

    d = Path(directory)
    for f in (d / CA_CERT, d / CA_KEY):
        if not f.exists():
            raise CredentialsError(f"no team CA in {d} (missing {f.name}); create one with `ramps team init --dir {d}`")
    cert = _load_cert(d / CA_CERT, "CA certificate")
    try:
        key = serialization.load_pem_private_key((d / CA_KEY).read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise CredentialsError(f"{d / CA_KEY} is not a readable private key: {exc}") from None
    if _spki(key.public_key()) != _spki(cert.public_key()):
        raise CredentialsError(f"{d / CA_KEY} is not the key of {d / CA_CERT}")
    if not isinstance(key, ec.EllipticCurvePrivateKey):  # what create_ca makes, and what signs revocation lists
        raise CredentialsError(f"{d / CA_KEY} is not an elliptic-curve key; make the CA with `ramps team init`")
    return cert, key, _team_of(cert)


def issue(directory: str | os.PathLike, robot: str, *, days: int = ROBOT_DAYS, hosts: list[str] | tuple = (),
          force: bool = False, now: _dt.datetime | None = None) -> Path:
    """Issue ``robot`` a key and certificate signed by the CA in ``directory``;
    returns the robot's bundle directory ``<directory>/<robot>/``.

    The certificate's CN is the robot name; its subject alternative names
    are the robot name, ``localhost``, 127.0.0.1, ::1 and ``hosts`` (names
    or IP addresses), so TLS name checks can pass on loopback and on the
    robot's own addresses."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID

    keys.check_name("robot", robot)
    ca_cert, ca_key, team = load_ca(directory)
    out = Path(directory) / robot
    if not force and (out / BUNDLE_KEY).exists():
        raise CredentialsError(f"{out} already holds credentials for {robot}; pass --force to issue new ones")
    out.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(out, 0o700)
    key = ec.generate_private_key(ec.SECP256R1())
    start = _now(now) - _dt.timedelta(minutes=5)
    end = min(start + _dt.timedelta(days=days), ca_cert.not_valid_after_utc)
    sans: list[x509.GeneralName] = []
    for h in [robot, "localhost", "127.0.0.1", "::1", *hosts]:
        entry: x509.GeneralName
        try:
            entry = x509.IPAddress(ipaddress.ip_address(h))
        except ValueError:
            entry = x509.DNSName(h)
        if entry not in sans:
            sans.append(entry)
    cert = (x509.CertificateBuilder().subject_name(_name(robot, team)).issuer_name(ca_cert.subject)
            .public_key(key.public_key()).serial_number(x509.random_serial_number())
            .not_valid_before(start).not_valid_after(end)
            .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False, key_encipherment=False,
                                         data_encipherment=False, key_agreement=False, key_cert_sign=False,
                                         crl_sign=False, encipher_only=False, decipher_only=False), critical=True)
            .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                           critical=False)
            .add_extension(x509.SubjectAlternativeName(sans), critical=False)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False)
            .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256()))
    _write(out / BUNDLE_KEY, _key_pem(key), private=True, force=True)
    _write(out / BUNDLE_CERT, _cert_pem(cert), private=False, force=True)
    _write(out / BUNDLE_CA, _cert_pem(ca_cert), private=False, force=True)
    return out


# ====================================================================== checking
def _spki(public_key: PublicKeyTypes) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return public_key.public_bytes(serialization.Encoding.DER, serialization.PublicFormat.SubjectPublicKeyInfo)


def _load_cert(path: Path, what: str) -> x509.Certificate:
    from cryptography import x509

    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CredentialsError(f"missing {what}: {path} does not exist") from None
    except OSError as exc:
        raise CredentialsError(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    try:
        return x509.load_pem_x509_certificate(data)
    except ValueError:
        raise CredentialsError(f"{what} {path} is not a PEM certificate") from None


def _attr(name: x509.Name, oid: x509.ObjectIdentifier) -> str:
    found = name.get_attributes_for_oid(oid)
    return str(found[0].value) if found else ""


def _cn(cert: x509.Certificate) -> str:
    from cryptography.x509.oid import NameOID

    return _attr(cert.subject, NameOID.COMMON_NAME)


def _team_of(cert: x509.Certificate) -> str:
    from cryptography.x509.oid import NameOID

    return _attr(cert.subject, NameOID.ORGANIZATIONAL_UNIT_NAME)


def credential_paths(credentials: str | os.PathLike | None, *, ca: str | None = None, cert: str | None = None,
                     key: str | None = None) -> tuple[Path, Path, Path]:
    """(ca, cert, key): explicit paths win, the rest come from the bundle directory."""
    if not credentials and not (ca and cert and key):
        raise CredentialsError("secure mode needs credentials: --credentials DIR (a robot's bundle from "
                               "`ramps team add ROBOT`: ca.pem, cert.pem, key.pem), or env RAMPS_CREDENTIALS")
    base = Path(credentials).expanduser() if credentials else Path(".")
    return (Path(ca).expanduser() if ca else base / BUNDLE_CA, Path(cert).expanduser() if cert else base / BUNDLE_CERT,
            Path(key).expanduser() if key else base / BUNDLE_KEY)


def check_credentials(ca: str | os.PathLike, cert: str | os.PathLike, key: str | os.PathLike, *,
                      robot: str | None = None, team: str | None = None,
                      now: _dt.datetime | None = None) -> Credentials:
    """Load and check a robot's credentials; raise ``CredentialsError`` saying
    what is wrong and how to fix it. ``robot``/``team``, when given, must be
    the certificate's."""
    from cryptography import x509
    from cryptography.exceptions import InvalidSignature
    from cryptography.hazmat.primitives import serialization
    from cryptography.x509.oid import NameOID

    ca, cert, key = Path(ca), Path(cert), Path(key)
    ca_cert = _load_cert(ca, "team CA certificate")
    my_cert = _load_cert(cert, "certificate")
    who = _cn(my_cert) or "?"
    try:
        ca_cert.verify_directly_issued_by(ca_cert)
        is_ca = ca_cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    except (ValueError, TypeError, InvalidSignature, x509.ExtensionNotFound):
        is_ca = False
    if not is_ca:
        raise CredentialsError(f"{ca} is not a team CA certificate (use the ca.pem from `ramps team add`)")
    try:
        my_cert.verify_directly_issued_by(ca_cert)
    except (ValueError, InvalidSignature, TypeError):
        issuer = _attr(my_cert.issuer, NameOID.COMMON_NAME)
        raise CredentialsError(f"certificate for {who} ({cert}) was not issued by this team's CA ({ca}): "
                               f"it was issued by {issuer!r}, the CA is {_cn(ca_cert)!r}") from None
    try:
        mode = key.stat().st_mode
    except FileNotFoundError:
        raise CredentialsError(f"missing private key: {key} does not exist") from None
    if os.name == "posix" and mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise CredentialsError(f"private key {key} is readable by other users (mode {stat.S_IMODE(mode):04o}); "
                               f"run: chmod 600 {key}")
    try:
        my_key = serialization.load_pem_private_key(key.read_bytes(), password=None)
    except (ValueError, TypeError) as exc:
        raise CredentialsError(f"{key} is not a readable private key: {exc}") from None
    except OSError as exc:
        raise CredentialsError(f"cannot read private key {key}: {exc.strerror or exc}") from None
    if _spki(my_key.public_key()) != _spki(my_cert.public_key()):
        raise CredentialsError(f"{key} is not the private key of {cert} (mixed up bundles?)")
    t = _now(now)
    for c, path in ((ca_cert, ca), (my_cert, cert)):
        if t < c.not_valid_before_utc:
            raise CredentialsError(f"{path} is not valid before {c.not_valid_before_utc:%Y-%m-%d %H:%M} UTC "
                                   "(is this robot's clock right?)")
        if t > c.not_valid_after_utc:
            fix = (f"issue a new one with `ramps team add {who} --force`" if c is my_cert
                   else "make a new team CA with `ramps team init --force` and re-issue every robot")
            raise CredentialsError(f"{path} ({_cn(c)}) expired on {c.not_valid_after_utc:%Y-%m-%d} UTC; {fix}")
    my_team = _team_of(my_cert)
    if team is not None and my_team != team:
        raise CredentialsError(f"credentials in {cert.parent} are for team {my_team!r}, not {team!r}; "
                               f"pass --team {my_team} (or use team {team}'s credentials)")
    if robot is not None and who != robot:
        raise CredentialsError(f"certificate {cert} is for robot {who!r}, not {robot!r}; "
                               f"use {robot}'s credentials (`ramps team add {robot}`) or --robot {who}")
    return Credentials(ca=ca.resolve(), cert=cert.resolve(), key=key.resolve(), robot=who, team=my_team,
                       not_after=my_cert.not_valid_after_utc)



class CredentialSettings(Protocol):
    """What ``settings_credentials`` reads of a node's settings
    (``ramps.runtime.settings.NodeSettings``, which imports this module)."""

    @property
    def credentials(self) -> str: ...
    @property
    def ca(self) -> str: ...
    @property
    def cert(self) -> str: ...
    @property
    def key(self) -> str: ...
    @property
    def team(self) -> str: ...


def settings_credentials(s: CredentialSettings, *, robot: str | None = None) -> Credentials:
    """The checked credentials of a node's settings ``s`` (a node passes its
    robot name: its certificate must be for that robot)."""
    ca, cert, key = credential_paths(s.credentials or None, ca=s.ca or None, cert=s.cert or None, key=s.key or None)
    return check_credentials(ca, cert, key, robot=robot, team=s.team)

