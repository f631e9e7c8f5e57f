"""Team credentials and the secure-mode settings, without a team: the CA and
robot certificates (``ramps.runtime.security``), ``ramps team init/add``,
settings validation, the Zenoh configuration of a secured team, and the TLS
admission probe against one in-process Zenoh peer on loopback."""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import logging
import os
import stat
import time
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ramps.cli import app
from ramps.errors import ConfigError, CredentialsError, NotAdmitted, NoTeam
from ramps.runtime import security as sec
from ramps.runtime.localteam import free_port
from ramps.runtime.settings import NodeSettings, load_settings
from ramps.runtime.zenoh_configs import zenoh_config

runner = CliRunner()
UTC = dt.UTC


def mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def bundle(d, name):
    return d / name / sec.BUNDLE_CA, d / name / sec.BUNDLE_CERT, d / name / sec.BUNDLE_KEY


@pytest.fixture
def team(tmp_path):
    """A team CA 'warehouse' with robots r1 and r2, and a rogue CA (same team
    name, so same CA subject) with robot r9."""
    d, rogue = tmp_path / "ca", tmp_path / "rogue"
    sec.create_ca(d, "warehouse")
    sec.issue(d, "r1")
    sec.issue(d, "r2")
    sec.create_ca(rogue, "warehouse")
    sec.issue(rogue, "r9")
    return d, rogue


# ====================================================================== CA and certificates
def test_ca_and_robot_bundle_files_and_modes(team):
    d, _ = team
    assert mode(d / sec.CA_KEY) == 0o600
    assert mode(d / "r1") == 0o700 and mode(d / "r1" / sec.BUNDLE_KEY) == 0o600
    ca_cert, _, name = sec.load_ca(d)
    assert name == "warehouse" and "warehouse" in ca_cert.subject.rfc4514_string()
    creds = sec.check_credentials(*bundle(d, "r1"), robot="r1", team="warehouse")
    assert (creds.robot, creds.team) == ("r1", "warehouse")
    assert creds.not_after > dt.datetime.now(UTC) + dt.timedelta(days=700)


def test_robot_certificate_is_fit_for_mutual_tls_on_loopback(team):
    from cryptography import x509
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    d, _ = team
    cert = x509.load_pem_x509_certificate((d / "r1" / sec.BUNDLE_CERT).read_bytes())
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "r1"
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "r1" in san.get_values_for_type(x509.DNSName) and "localhost" in san.get_values_for_type(x509.DNSName)
    assert {str(ip) for ip in san.get_values_for_type(x509.IPAddress)} >= {"127.0.0.1", "::1"}
    eku = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert ExtendedKeyUsageOID.SERVER_AUTH in eku and ExtendedKeyUsageOID.CLIENT_AUTH in eku
    assert cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca is False


def test_extra_hosts_become_subject_alternative_names(tmp_path):
    from cryptography import x509

    sec.create_ca(tmp_path, "lab")
    out = sec.issue(tmp_path, "r3", hosts=["192.168.1.13", "r3.local"])
    san = x509.load_pem_x509_certificate((out / sec.BUNDLE_CERT).read_bytes()).extensions.get_extension_for_class(
        x509.SubjectAlternativeName).value
    assert "r3.local" in san.get_values_for_type(x509.DNSName)
    assert "192.168.1.13" in {str(ip) for ip in san.get_values_for_type(x509.IPAddress)}


def test_never_overwrites_a_ca_or_robot_credentials_without_force(team):
    d, _ = team
    before = (d / sec.CA_KEY).read_bytes()
    with pytest.raises(CredentialsError, match="already holds a team CA; pass --force"):
        sec.create_ca(d, "warehouse")
    with pytest.raises(CredentialsError, match="already holds credentials for r1; pass --force"):
        sec.issue(d, "r1")
    assert (d / sec.CA_KEY).read_bytes() == before
    sec.create_ca(d, "warehouse", force=True)
    assert (d / sec.CA_KEY).read_bytes() != before
    # the old robot certificates no longer belong to this CA
    with pytest.raises(CredentialsError, match="not issued by this team's CA"):
        sec.check_credentials(d / sec.CA_CERT, d / "r1" / sec.BUNDLE_CERT, d / "r1" / sec.BUNDLE_KEY)


def test_wrong_ca_is_detected(team):
    d, rogue = team
    with pytest.raises(CredentialsError, match=r"certificate for r2 .* was not issued by this team's CA"):
        sec.check_credentials(rogue / sec.CA_CERT, d / "r2" / sec.BUNDLE_CERT, d / "r2" / sec.BUNDLE_KEY)
    with pytest.raises(CredentialsError, match=r"certificate for r9 .* was not issued by this team's CA"):
        sec.check_credentials(d / sec.CA_CERT, rogue / "r9" / sec.BUNDLE_CERT, rogue / "r9" / sec.BUNDLE_KEY)


def test_expired_and_not_yet_valid_certificates(tmp_path):
    long_ago = dt.datetime(2020, 1, 1, tzinfo=UTC)
    sec.create_ca(tmp_path, "lab", now=long_ago)  # valid 10 years: until 2029
    sec.issue(tmp_path, "old", days=30, now=long_ago)
    with pytest.raises(CredentialsError, match=r"expired on 2020-01-3.*ramps team add old --force"):
        sec.check_credentials(*bundle(tmp_path, "old"))
    sec.issue(tmp_path, "new")
    with pytest.raises(CredentialsError, match="is not valid before .*clock"):
        sec.check_credentials(*bundle(tmp_path, "new"), now=long_ago)
    with pytest.raises(CredentialsError, match=r"ca.pem .* expired.*ramps team init --force"):
        sec.check_credentials(*bundle(tmp_path, "new"), now=dt.datetime(2031, 1, 1, tzinfo=UTC))


def test_missing_files_and_a_missing_ca_say_which_file(tmp_path, team):
    d, _ = team
    with pytest.raises(CredentialsError, match=r"missing certificate: .*nope.pem does not exist"):
        sec.check_credentials(d / "r1" / sec.BUNDLE_CA, tmp_path / "nope.pem", d / "r1" / sec.BUNDLE_KEY)
    with pytest.raises(CredentialsError, match=r"missing private key: .*gone.key does not exist"):
        sec.check_credentials(d / "r1" / sec.BUNDLE_CA, d / "r1" / sec.BUNDLE_CERT, tmp_path / "gone.key")
    with pytest.raises(CredentialsError, match=r"missing team CA certificate"):
        sec.check_credentials(tmp_path / "ca.pem", d / "r1" / sec.BUNDLE_CERT, d / "r1" / sec.BUNDLE_KEY)
    with pytest.raises(CredentialsError, match=r"no team CA in .*ramps team init"):
        sec.issue(tmp_path / "empty", "r1")
    (tmp_path / "junk.pem").write_text("not a certificate")
    with pytest.raises(CredentialsError, match="is not a PEM certificate"):
        sec.check_credentials(tmp_path / "junk.pem", d / "r1" / sec.BUNDLE_CERT, d / "r1" / sec.BUNDLE_KEY)
    with pytest.raises(CredentialsError, match="is not a team CA certificate"):
        sec.check_credentials(d / "r1" / sec.BUNDLE_CERT, d / "r1" / sec.BUNDLE_CERT, d / "r1" / sec.BUNDLE_KEY)


def test_key_of_another_robot_and_a_readable_key_are_refused(team):
    d, _ = team
    with pytest.raises(CredentialsError, match="is not the private key of"):
        sec.check_credentials(d / sec.CA_CERT, d / "r1" / sec.BUNDLE_CERT, d / "r2" / sec.BUNDLE_KEY)
    os.chmod(d / "r1" / sec.BUNDLE_KEY, 0o644)
    with pytest.raises(CredentialsError, match=r"readable by other users \(mode 0644\); run: chmod 600"):
        sec.check_credentials(*bundle(d, "r1"))


def test_robot_and_team_must_match_the_certificate(team):
    d, _ = team
    with pytest.raises(CredentialsError, match=r"is for robot 'r1', not 'r2'.*--robot r1"):
        sec.check_credentials(*bundle(d, "r1"), robot="r2")
    with pytest.raises(CredentialsError, match=r"are for team 'warehouse', not 'lab'; pass --team warehouse"):
        sec.check_credentials(*bundle(d, "r1"), team="lab")


def test_bad_names_are_refused(tmp_path):
    with pytest.raises(ValueError, match="team name"):
        sec.create_ca(tmp_path, "two words")
    sec.create_ca(tmp_path, "lab")
    with pytest.raises(ValueError, match="robot name"):
        sec.issue(tmp_path, "r1/../x")


# ====================================================================== ramps team
def test_cli_team_init_add_show(tmp_path):
    d = tmp_path / "ramps-team"
    res = runner.invoke(app, ["team", "init", "--dir", str(d), "--team", "warehouse"])
    assert res.exit_code == 0, res.output
    assert mode(d / sec.CA_KEY) == 0o600 and "ramps team add" in res.output
    res = runner.invoke(app, ["team", "init", "--dir", str(d), "--team", "warehouse"])
    assert res.exit_code == 2 and "--force" in res.output
    res = runner.invoke(app, ["team", "add", "r1", "--dir", str(d), "--host", "10.0.0.1"])
    assert res.exit_code == 0, res.output
    out = " ".join(res.output.split())
    for f in (sec.BUNDLE_CA, sec.BUNDLE_CERT, sec.BUNDLE_KEY):
        assert str(d / "r1" / f) in out
    assert "ca.key" not in out.replace("ca.key here", "")  # the CA key is never to be copied
    assert "--secure" in out and "--team warehouse" in out
    sec.check_credentials(*bundle(d, "r1"), robot="r1", team="warehouse")
    res = runner.invoke(app, ["team", "add", "r1", "--dir", str(d)])
    assert res.exit_code == 2 and "--force" in res.output
    res = runner.invoke(app, ["team", "add", "r2", "--dir", str(tmp_path / "nowhere")])
    assert res.exit_code == 2 and "ramps team init" in res.output
    res = runner.invoke(app, ["team", "show", "--dir", str(d)])
    assert res.exit_code == 0 and "r1" in res.output and "warehouse" in res.output


# ====================================================================== settings
def test_settings_secure_from_env_and_flags(tmp_path):
    s = load_settings(environ={"RAMPS_SECURE": "1", "RAMPS_CREDENTIALS": str(tmp_path), "RAMPS_MEMBERS": "r1,r2"},
                      default_robot=False)
    assert s.secure and s.credentials == str(tmp_path) and s.members == ["r1", "r2"]
    assert s.listen_endpoints() == ["tls/0.0.0.0:0"]  # the default listen becomes TLS
    assert load_settings(environ={}, default_robot=False).listen_endpoints() == ["tcp/0.0.0.0:0"]
    s = load_settings(environ={}, default_robot=False, flags={"secure": True, "credentials": "c",
                                                               "connect": ["tls/10.0.0.2:7447"]})
    assert s.connect == ["tls/10.0.0.2:7447"]


@pytest.mark.parametrize("flags, message", [
    ({"secure": True, "credentials": "c", "connect": ["tcp/10.0.0.2:7447"]}, "write tls/10.0.0.2:7447 instead"),
    ({"secure": True, "credentials": "c", "listen": ["tcp/0.0.0.0:7447"]}, "TLS links only"),
    ({"connect": ["tls/10.0.0.2:7447"]}, "TLS links need secure mode"),
    ({"secure": True}, "needs this robot's credentials: --credentials DIR"),
    ({"secure": True, "credentials": "c", "members": ["r 1"]}, "member name"),
])
def test_settings_validation(flags, message):
    with pytest.raises(ConfigError, match=message):
        load_settings(environ={}, default_robot=False, flags=flags)


def test_bad_secure_env_value_is_a_config_error():
    with pytest.raises(ConfigError, match="RAMPS_SECURE"):
        load_settings(environ={"RAMPS_SECURE": "maybe"}, default_robot=False)


def test_zenoh_config_of_a_secured_team(team):
    d, _ = team
    creds = sec.check_credentials(*bundle(d, "r1"))
    s = NodeSettings(robot="r1", team="warehouse", secure=True, credentials=str(d / "r1"),
                     connect=["tls/127.0.0.1:7447"], members=["r2", "r1"])
    c = zenoh_config(s, credentials=creds, exit_on_failure=True)
    get = lambda key: json.loads(c.get_json(key))
    assert get("listen/endpoints") == ["tls/0.0.0.0:0"]
    assert get("transport/link/protocols") == ["tls"]
    tls = get("transport/link/tls")
    assert tls["enable_mtls"] is True and tls["root_ca_certificate"] == str(creds.ca)
    assert tls["listen_certificate"] == tls["connect_certificate"] == str(creds.cert)
    acl = get("access_control")
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert acl["rules"][0]["key_exprs"] == ["ramps/warehouse/**"] and acl["rules"][0]["permission"] == "allow"
    assert acl["subjects"][0]["cert_common_names"] == ["r1", "r2"]
    assert get("connect/exit_on_failure") is True and get("connect/timeout_ms") == 3000
    with pytest.raises(ValueError, match="needs the checked credentials"):
        zenoh_config(s)
    # without members any team certificate is admitted; insecure configs are unchanged
    assert "cert_common_names" not in sec.secure_zenoh_json("warehouse", creds)["access_control"]["subjects"][0]
    plain = zenoh_config(NodeSettings(robot="r1"))
    assert json.loads(plain.get_json("connect/exit_on_failure")) is not True
    # secured or not, of two robots that scout each other only one dials (zenoh#2806);
    # an application that listens nowhere cannot be dialled, so it dials everyone
    app = zenoh_config(NodeSettings(robot="r1", connect=["tcp/127.0.0.1:7447"]), listen=[])
    for cfg, want in ((c, "greater-zid"), (plain, "greater-zid"), (app, "always")):
        for how in ("multicast", "gossip"):
            strategy = json.loads(cfg.get_json(f"scouting/{how}/autoconnect_strategy"))
            assert strategy["peer"]["to_peer"] == want, (how, strategy)


def test_insecure_node_warns_once_per_process(monkeypatch, caplog):
    from ramps.runtime import node_team

    monkeypatch.setattr(node_team, "_insecure_warned", False)
    s = NodeSettings(robot="r1", team="lab")
    with caplog.at_level(logging.WARNING, logger="ramps.node"):
        assert node_team.join_checks(s) == (None, False)
        node_team.join_checks(s)
    warnings = [r.getMessage() for r in caplog.records if "INSECURE" in r.getMessage()]
    assert len(warnings) == 1
    assert "anyone who can reach this network" in warnings[0] and "--secure" in warnings[0]


# ====================================================================== admission, one Zenoh peer on loopback
@pytest.fixture
def tls_peer(team):
    """A secured Zenoh peer of team 'warehouse' (robot r1) listening on loopback."""
    import zenoh

    d, _ = team
    port = free_port()
    creds = sec.check_credentials(*bundle(d, "r1"))
    s = NodeSettings(robot="r1", team="warehouse", secure=True, credentials=str(d / "r1"),
                     listen=[f"tls/127.0.0.1:{port}"], multicast=False)
    session = zenoh.open(zenoh_config(s, credentials=creds))
    try:
        yield f"tls/127.0.0.1:{port}"
    finally:
        session.close()


@pytest.mark.slow
def test_admission_of_teammates_and_of_strangers(team, tls_peer):
    d, rogue = team
    r2 = sec.check_credentials(*bundle(d, "r2"))
    r9 = sec.check_credentials(*bundle(rogue, "r9"))
    dead = f"tls/127.0.0.1:{free_port()}"
    assert sec.admission([tls_peer], r2, team="warehouse") is True
    assert sec.admission([tls_peer, dead], r2, team="warehouse") is False  # some not up yet: no fail-fast
    assert sec.admission([dead], r2, team="warehouse") is False  # the first robot up
    assert sec.admission([], r2, team="warehouse") is False
    t0 = time.monotonic()
    with pytest.raises(NotAdmitted, match=r"did not admit robot 'r9'.*certificate from another CA") as info:
        sec.admission([tls_peer, dead], r9, team="warehouse")
    assert time.monotonic() - t0 < 5 and isinstance(info.value, NoTeam)
    # a stranger that trusts the team CA (ca.pem is public) but holds a foreign certificate
    mixed = dataclasses.replace(r9, ca=r2.ca)
    assert "refused this robot's certificate" in sec.probe_tls(tls_peer, mixed)
    # a client without TLS can tell that the team wants TLS
    assert sec.tls_listeners([tls_peer, dead]) == [tls_peer]
    assert sec.probe_tls(dead, r2) == "unreachable"


@pytest.mark.slow
def test_client_with_credentials_of_another_team_fails_at_once(team, tls_peer):
    import ramps

    _, rogue = team
    t0 = time.monotonic()
    with pytest.raises(NotAdmitted, match="did not admit robot 'r9'"):
        ramps.connect(team="warehouse", connect=[tls_peer], multicast=False, secure=True,
                      credentials=rogue / "r9", timeout=30)
    assert time.monotonic() - t0 < 5
    with pytest.raises(CredentialsError, match="for team 'warehouse', not 'lab'"):
        ramps.connect(team="lab", connect=[tls_peer], multicast=False, secure=True, credentials=rogue / "r9")


@pytest.mark.slow
def test_teammate_gone_between_admission_and_open_is_no_refusal(team):
    """Zenoh's connect/exit_on_failure wants every endpoint: a teammate that
    leaves between the admission check and zenoh.open must not fail the join."""
    import zenoh

    d, _ = team
    r2 = sec.check_credentials(*bundle(d, "r2"))
    gone = f"tls/127.0.0.1:{free_port()}"  # admitted a moment ago, nobody there now
    s = NodeSettings(robot="r2", team="warehouse", secure=True, credentials=str(d / "r2"), listen=[],
                     connect=[gone], multicast=False)
    t0 = time.monotonic()
    session = sec.open_session(lambda fast: zenoh_config(s, credentials=r2, exit_on_failure=fast), s.connect, r2,
                               team="warehouse", fail_fast=True)
    try:
        assert isinstance(session, zenoh.Session)
        assert time.monotonic() - t0 < 30
    finally:
        session.close()


def test_credentials_paths_expand_the_home_directory(monkeypatch, tmp_path):
    monkeypatch.setenv("HOME", str(tmp_path))
    ca, cert, key = sec.credential_paths("~/creds")
    assert ca == tmp_path / "creds" / sec.BUNDLE_CA and key == tmp_path / "creds" / sec.BUNDLE_KEY
    ca, cert, key = sec.credential_paths(None, ca="~/a.pem", cert="/c.pem", key="/k.pem")
    assert (ca, cert, key) == (tmp_path / "a.pem", Path("/c.pem"), Path("/k.pem"))
    with pytest.raises(CredentialsError, match="--credentials DIR"):
        sec.credential_paths(None, ca="/a.pem")


@pytest.mark.slow
def test_access_control_passes_team_keys_and_drops_the_rest(team):
    """Two secured peers: what one publishes under ramps/<team>/ reaches the
    other; the same under another team's prefix or any other key does not."""
    import zenoh

    d, _ = team
    port = free_port()
    got: list[str] = []

    def peer(name, **kw):
        creds = sec.check_credentials(*bundle(d, name))
        s = NodeSettings(robot=name, team="warehouse", secure=True, credentials=str(d / name), multicast=False, **kw)
        return zenoh.open(zenoh_config(s, credentials=creds))

    with peer("r1", listen=[f"tls/127.0.0.1:{port}"]) as a, peer("r2", listen=[],
                                                                  connect=[f"tls/127.0.0.1:{port}"]) as b:
        subs = [a.declare_subscriber(k, lambda smp: got.append(str(smp.key_expr)))
                for k in ("ramps/warehouse/**", "ramps/other/**", "elsewhere/**")]
        deadline = time.monotonic() + 20
        while "ramps/warehouse/x" not in got and time.monotonic() < deadline:
            for k in ("ramps/warehouse/x", "ramps/other/x", "elsewhere/x"):
                b.put(k, b"hi")
            time.sleep(0.1)
        for _ in range(5):  # a few more rounds, now that the link is up
            for k in ("ramps/other/x", "elsewhere/x"):
                b.put(k, b"hi")
            time.sleep(0.05)
        time.sleep(0.3)
        for sub in subs:
            sub.undeclare()
    assert "ramps/warehouse/x" in got
    assert set(got) == {"ramps/warehouse/x"}


@pytest.mark.slow
def test_members_admit_only_the_named_certificates(team):
    """With ``members``, a teammate whose certificate name is not listed links
    over TLS (same CA) but access control drops all it says."""
    import zenoh

    d, _ = team
    port = free_port()
    got: list[str] = []

    def peer(name, **kw):
        creds = sec.check_credentials(*bundle(d, name))
        s = NodeSettings(robot=name, team="warehouse", secure=True, credentials=str(d / name), multicast=False, **kw)
        return zenoh.open(zenoh_config(s, credentials=creds))

    with peer("r1", listen=[f"tls/127.0.0.1:{port}"], members=["r1", "r3"]) as a, \
            peer("r2", listen=[], connect=[f"tls/127.0.0.1:{port}"]) as b:
        sub = a.declare_subscriber("ramps/warehouse/**", lambda smp: got.append(str(smp.key_expr)))
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            b.put("ramps/warehouse/x", b"hi")
            time.sleep(0.1)
        linked = list(b.info.peers_zid())
        sub.undeclare()
    assert linked, "r2 should link over TLS: its certificate is from the team CA"
    assert got == []
