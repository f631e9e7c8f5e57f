"""Security of a team (``--secure``), one import for the rest of ramps.

How this works: two modules, one concern each, and this one re-exports both
(``from ramps.runtime import security`` keeps working everywhere):

* ``ramps.runtime.credentials``: the files. ``ramps team init`` makes a team
  certificate authority, ``ramps team add r1`` a robot's bundle (``ca.pem``,
  ``cert.pem``, ``key.pem``); ``check_credentials`` checks a bundle before
  anything opens Zenoh and raises ``CredentialsError`` naming the file and
  the fix. No network.
* ``ramps.runtime.admission``: who may join. The Zenoh configuration of a
  secured team (mutual TLS against the team CA, access control to the
  team's key expressions only), and the TLS probe of the teammates before
  Zenoh opens, so that a refusal is a ``NotAdmitted`` naming who refused
  and why instead of a silently empty team.

Nothing here is imported by ``ramps.core``.
"""

from __future__ import annotations

from ramps.runtime.admission import (
    ACL_MESSAGES,
    _await_acceptance,
    _host_port,
    admission,
    not_admitted_message,
    open_session,
    probe_all,
    probe_tls,
    reachable,
    secure_zenoh_json,
    tls_listeners,
)
from ramps.runtime.credentials import (
    BUNDLE_CA,
    BUNDLE_CERT,
    BUNDLE_KEY,
    CA_CERT,
    CA_DAYS,
    CA_KEY,
    DEFAULT_DIR,
    ROBOT_DAYS,
    Credentials,
    _load_cert,
    check_credentials,
    create_ca,
    credential_paths,
    issue,
    load_ca,
    settings_credentials,
)

__all__ = ["ACL_MESSAGES", "BUNDLE_CA", "BUNDLE_CERT", "BUNDLE_KEY", "CA_CERT", "CA_DAYS", "CA_KEY", "DEFAULT_DIR",
           "ROBOT_DAYS", "Credentials", "_await_acceptance", "_host_port", "_load_cert", "admission",
           "check_credentials", "create_ca", "credential_paths", "issue", "load_ca", "not_admitted_message",
           "open_session", "probe_all", "probe_tls", "reachable", "secure_zenoh_json", "settings_credentials",
           "tls_listeners"]
