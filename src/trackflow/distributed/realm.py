"""A secure realm on Zenoh's own TLS and access control, and the check agents make of theirs.

:func:`init_realm` turns a realm's agent files into what its hosts need: one certificate
authority, a key and certificate per agent (the agent's name as its common name) and per
agent a complete Zenoh configuration:

* **TLS with mutual authentication.** Every link is ``tls/``, both ends show a certificate
  of the realm's CA, and a connecting agent checks the name of the host it reaches. A process
  without such a certificate cannot join.
* **Access control by identity.** Every agent's Zenoh runtime lets each peer (known by its
  certificate's common name) publish only the states of its own sensors (``states/<agent>``,
  ``thin/<edge>/...``), its own results (``result/<agent>/...``) and re-plan events
  (``event/<agent>``), declare only its own
  liveliness tokens (``alive/<agent>/...``, ``agent/<agent>``, its demands) and answer only
  its own queryables (its fragment, clock and status, ``get/`` of its sensors, ``query/`` of
  its queries). Everyone in the realm may subscribe and ask. An observer identity
  (``observers``) may only subscribe and ask. Anything else is denied (``default_permission:
  deny``); a peer holding another agent's certificate still cannot speak for a third.

The ownership comes from the agent files: an agent owns the sensors and queries its file
declares. Certificates are made with the ``openssl`` command (installed by ``make test``; on
Debian ``apt install openssl``); the CA key stays in the output folder, to be kept offline.

What an agent checks of its own configuration before it opens its session is
:func:`trackflow.distributed.config.link_security`.
"""

from __future__ import annotations

import ipaddress
import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from ..errors import ConfigError, StateError
from ..zenohconf import NO_SHARED_MEMORY
from .config import AgentConfig

__all__ = ["Member", "RealmFiles", "init_realm", "realm_acl", "realm_members"]

#: every message kind Zenoh's access control knows
_MESSAGES = ["put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
             "liveliness_token", "liveliness_query", "declare_liveliness_subscriber"]  # fmt: skip
_READ = ["declare_subscriber", "query", "liveliness_query", "declare_liveliness_subscriber"]


@dataclass(frozen=True)
class Member:
    """One identity of a realm: an agent (its sensors and queries) or an observer."""

    name: str
    endpoint: str | None  # "host:port" it listens on (None: it only connects)
    edges: tuple[str, ...] = ()
    queries: tuple[str, ...] = ()


@dataclass(frozen=True)
class RealmFiles:
    """What :func:`init_realm` wrote: the CA and, per identity, its certificate, key and
    Zenoh configuration (``zenoh_config:`` of its agent file)."""

    folder: Path
    ca: Path
    configs: dict[str, Path]


def realm_members(
    agents: list[AgentConfig], endpoints: dict[str, str], base_port: int = 7447
) -> tuple[str, list[Member]]:
    """The realm and its members from the agents' files: each owns its sensors and queries
    and listens on ``endpoints[name]`` (default ``localhost:<base_port + k>``).

    Raises
    ------
    ConfigError
        Agents of several realms, one name twice, one sensor in two agents, or an endpoint
        for an agent not given.
    """
    realms = sorted({a.realm for a in agents})
    if len(realms) != 1:
        raise ConfigError(f"the agents belong to several realms: {realms}")
    names = [a.name for a in agents]
    unknown = sorted(set(endpoints) - set(names))
    if unknown:
        raise ConfigError(f"endpoint for {unknown}: no such agent among {names}")
    owner: dict[str, str] = {}
    members = []
    for k, a in enumerate(agents):
        edges = tuple(e.name for e in a.setup.graph.edges if e.kind == "measured")
        for e in edges:
            if e in owner:
                raise ConfigError(f"sensor {e!r} is in agents {owner[e]!r} and {a.name!r}")
            owner[e] = a.name
        endpoint = endpoints.get(a.name, f"localhost:{base_port + k}")
        members.append(Member(a.name, endpoint, edges, tuple(a.setup.queries)))
    if len(set(names)) != len(names):
        raise ConfigError(f"an agent name twice: {names}")
    return realms[0], members


def realm_acl(realm: str, members: list[Member], observers: list[str] = ()) -> dict:
    """Zenoh's ``access_control`` section for a realm (module docstring)."""
    r = f"trackflow/{realm}"
    rules = [
        {"id": "egress", "permission": "allow", "flows": ["egress"], "messages": _MESSAGES,
         "key_exprs": [f"{r}/**", "@/**"]},
        {"id": "read", "permission": "allow", "flows": ["ingress"], "messages": _READ,
         "key_exprs": [f"{r}/**", "@/**"]},
    ]  # fmt: skip
    subjects = [{"id": f"id_{m.name}", "cert_common_names": [m.name]} for m in members]
    subjects += [{"id": f"id_{o}", "cert_common_names": [o]} for o in observers]
    everyone = [s["id"] for s in subjects]
    policies = [{"rules": ["egress", "read"], "subjects": everyone}]
    for m in members:
        own = [f"{r}/states/{m.name}"] + [f"{r}/thin/{e}/**" for e in m.edges]
        own += [f"{r}/result/{m.name}/**", f"{r}/event/{m.name}"]
        answers = [f"{r}/{k}/{m.name}" for k in ("fragment", "clock", "status")]
        answers += [f"{r}/get/{e}" for e in m.edges] + [f"{r}/query/{q}" for q in m.queries]
        tokens = [f"{r}/alive/{m.name}/**", f"{r}/agent/{m.name}", f"{r}/demand/*/{m.name}/**"]
        rules += [
            {"id": f"publish_{m.name}", "permission": "allow", "flows": ["ingress"],
             "messages": ["put", "delete"], "key_exprs": own},
            {"id": f"answer_{m.name}", "permission": "allow", "flows": ["ingress"],
             "messages": ["declare_queryable", "reply"], "key_exprs": answers},
            {"id": f"tokens_{m.name}", "permission": "allow", "flows": ["ingress"],
             "messages": ["liveliness_token"], "key_exprs": tokens},
            {"id": f"admin_{m.name}", "permission": "allow", "flows": ["ingress"],
             "messages": _MESSAGES, "key_exprs": ["@/**"]},
        ]  # fmt: skip
        policies.append(
            {
                "rules": [f"{k}_{m.name}" for k in ("publish", "answer", "tokens", "admin")],
                "subjects": [f"id_{m.name}"],
            }  # fmt: skip
        )
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}  # fmt: skip


def _zenoh_config(folder: Path, me: str, endpoint: str | None, peers: list[str], acl) -> dict:
    tls = {
        "root_ca_certificate": str(folder / "ca.pem"),
        "listen_certificate": str(folder / f"{me}.pem"),
        "listen_private_key": str(folder / f"{me}.key"),
        "connect_certificate": str(folder / f"{me}.pem"),
        "connect_private_key": str(folder / f"{me}.key"),
        "enable_mtls": True,
        "verify_name_on_connect": True,
    }
    return {
        "mode": "peer",
        "listen": {"endpoints": [f"tls/{endpoint}"] if endpoint else []},
        "connect": {
            "endpoints": [f"tls/{p}" for p in peers],
            "retry": {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2},
        },
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {"link": {"tls": tls}, **NO_SHARED_MEMORY},
        "access_control": acl,
    }


def _openssl(*args: str, cwd: Path) -> None:
    try:
        subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True,
                       timeout=60)  # fmt: skip
    except subprocess.CalledProcessError as exc:
        why = exc.stderr.decode(errors="replace")
        raise StateError(f"openssl {args[0]} failed: {why}") from None


def _host_names(endpoint: str | None) -> str:
    """The certificate's subjectAltName: the endpoint's host (DNS name or IP) and loopback."""
    names = ["DNS:localhost", "IP:127.0.0.1"]
    if endpoint:
        host = endpoint.rsplit(":", 1)[0].strip("[]")
        try:
            ipaddress.ip_address(host)
            entry = f"IP:{host}"
        except ValueError:
            entry = f"DNS:{host}"
        if entry not in names:
            names.append(entry)
    return ",".join(names)


def _certificate(folder: Path, name: str, endpoint: str | None, days: int) -> None:
    """``<name>.key`` and ``<name>.pem`` (common name ``name``), signed by the realm's CA."""
    ext = folder / f"{name}.ext"
    ext.write_text(
        f"subjectAltName={_host_names(endpoint)}\nbasicConstraints=CA:FALSE\n"
        "keyUsage=digitalSignature,keyEncipherment\nextendedKeyUsage=serverAuth,clientAuth\n"
    )
    _openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
             "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN={name}",
             cwd=folder)  # fmt: skip
    _openssl("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
             "-CAcreateserial", "-out", f"{name}.pem", "-days", str(days), "-extfile",
             ext.name, cwd=folder)  # fmt: skip
    (folder / f"{name}.csr").unlink()
    ext.unlink()
    os.chmod(folder / f"{name}.key", 0o600)


def init_realm(
    realm: str,
    members: list[Member],
    out: Path,
    observers: list[str] = (),
    days: int = 365,
) -> RealmFiles:
    """Write a realm's CA, certificates and Zenoh configurations into ``out`` (module
    docstring). Every member listens on its endpoint and connects to every member listed
    before it (a full mesh, each link made once); observers connect to every member.

    Raises
    ------
    ConfigError
        Two identities with one name, or ``out`` already holding a CA (never overwritten).
    StateError
        ``openssl`` is missing or fails.
    """
    names = [m.name for m in members] + list(observers)
    if len(set(names)) != len(names):
        raise ConfigError(f"realm {realm!r}: an identity named twice in {names}")
    if shutil.which("openssl") is None:
        raise StateError("realm init needs the openssl command (apt install openssl)")
    out = Path(out)
    if (out / "ca.pem").exists():
        raise ConfigError(f"{out}: already holds a realm (ca.pem); choose another folder")
    out.mkdir(parents=True, exist_ok=True)
    _openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
             "-nodes", "-keyout", "ca.key", "-out", "ca.pem", "-days", str(days), "-subj",
             f"/CN=trackflow realm {realm} CA", cwd=out)  # fmt: skip
    os.chmod(out / "ca.key", 0o600)
    acl = realm_acl(realm, members, observers)
    configs = {}
    for k, m in enumerate(members):
        _certificate(out, m.name, m.endpoint, days)
        peers = [p.endpoint for p in members[:k] if p.endpoint]
        configs[m.name] = _write(out, m.name, _zenoh_config(out, m.name, m.endpoint, peers, acl))
    for o in observers:
        _certificate(out, o, None, days)
        peers = [p.endpoint for p in members if p.endpoint]
        configs[o] = _write(out, o, _zenoh_config(out, o, None, peers, acl))
    (out / "ca.srl").unlink(missing_ok=True)
    return RealmFiles(out, out / "ca.pem", configs)


def _write(folder: Path, name: str, conf: dict) -> Path:
    path = folder / f"{name}.json5"
    with tempfile.NamedTemporaryFile("w", dir=folder, delete=False, suffix=".tmp") as f:
        json.dump(conf, f, indent=2)
    Path(f.name).replace(path)
    return path
