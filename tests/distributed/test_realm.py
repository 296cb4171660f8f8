"""``trackflow realm init`` (files, access rules) and the agents' refusal of insecure links."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from trackflow.distributed import load_agent
from trackflow.distributed.config import link_security
from trackflow.distributed.realm import Member, realm_acl, realm_members
from trackflow.errors import ConfigError

TRACKFLOW = [sys.executable, "-m", "trackflow.cli.main"]
AGENT = """agent: {{name: {name}, realm: lab{extra}}}
frames: [W, {target}]
sensors:
  - {{name: {sensor}, source: W, target: {target}, rate_hz: 100, sigma_pos_mm: 1,
     sigma_ori_deg: 0.2, motion: {{n_dp: 1, n_do: 1, noise: [1.0, 1.0]}}}}
queries: [{{name: q_{name}, source: W, target: {target}, mode: push, rate_hz: 30}}]
"""


def _agent(tmp_path, name, sensor, target="X", extra=""):
    path = tmp_path / f"{name}.yaml"
    path.write_text(AGENT.format(name=name, sensor=sensor, target=target, extra=extra))
    return path


def test_members_own_their_sensors_and_queries(tmp_path):
    agents = [load_agent(_agent(tmp_path, "a", "art")), load_agent(_agent(tmp_path, "b", "nn"))]
    realm, members = realm_members(agents, {"b": "10.0.0.2:7447"})
    assert realm == "lab"
    assert members == [
        Member("a", "localhost:7447", ("art",), ("q_a",)),
        Member("b", "10.0.0.2:7447", ("nn",), ("q_b",)),
    ]
    with pytest.raises(ConfigError, match="sensor 'art' is in agents 'a' and 'c'"):
        realm_members(agents + [load_agent(_agent(tmp_path, "c", "art"))], {})
    with pytest.raises(ConfigError, match=r"endpoint for \['z'\]"):
        realm_members(agents, {"z": "h:1"})


def test_the_access_rules_give_each_identity_its_own_keys():
    acl = realm_acl("lab", [Member("a", "h:1", ("art",), ("qa",))], ["obs"])
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["publish_a"]["key_exprs"] == [
        "trackflow/lab/states/a", "trackflow/lab/thin/art/**", "trackflow/lab/result/a/**",
        "trackflow/lab/event/a",
    ]  # fmt: skip
    assert rules["publish_a"]["flows"] == ["ingress"]
    assert "trackflow/lab/query/qa" in rules["answer_a"]["key_exprs"]
    assert rules["tokens_a"]["key_exprs"][0] == "trackflow/lab/alive/a/**"
    assert "put" not in rules["read"]["messages"]  # reading is everyone's, writing is not
    by_subject = {p["subjects"][0]: p["rules"] for p in acl["policies"] if len(p["subjects"]) == 1}
    assert by_subject == {"id_a": ["publish_a", "answer_a", "tokens_a", "admin_a"]}
    assert {s["id"]: s["cert_common_names"] for s in acl["subjects"]} == {
        "id_a": ["a"], "id_obs": ["obs"]
    }  # fmt: skip


def test_realm_init_writes_certificates_and_configs(tmp_path):
    if shutil.which("openssl") is None:
        pytest.skip("openssl is not installed (make test installs it: apt-get install openssl)")
    paths = [_agent(tmp_path, "a", "art"), _agent(tmp_path, "b", "nn", "Y")]
    out = tmp_path / "realm"
    done = subprocess.run(
        [*TRACKFLOW, "realm", "init", *map(str, paths), "--out", str(out),
         "--endpoint", "a=192.168.10.11:7447", "--observer", "obs"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["ca.pem", "ca.key"]
        + [f"{n}.{x}" for n in ("a", "b", "obs") for x in ("pem", "key", "json5")]
    )
    assert (out / "a.key").stat().st_mode & 0o077 == 0  # keys readable by their owner only
    subject = subprocess.run(
        ["openssl", "x509", "-in", str(out / "a.pem"), "-noout", "-subject", "-ext",
         "subjectAltName"], capture_output=True, text=True, check=True,
    ).stdout  # fmt: skip
    assert "CN = a" in subject and "IP Address:192.168.10.11" in subject
    verify = subprocess.run(["openssl", "verify", "-CAfile", str(out / "ca.pem"),
                             str(out / "b.pem")], capture_output=True, text=True)  # fmt: skip
    assert verify.returncode == 0, verify.stdout + verify.stderr
    a = json.loads((out / "a.json5").read_text())
    b = json.loads((out / "b.json5").read_text())
    assert a["listen"]["endpoints"] == ["tls/192.168.10.11:7447"]
    assert b["connect"]["endpoints"] == ["tls/192.168.10.11:7447"]  # each link made once
    assert a["transport"]["link"]["tls"]["enable_mtls"] is True
    assert a["transport"]["shared_memory"] == {"enabled": False}  # (zenohconf.NO_SHARED_MEMORY)
    assert a["access_control"] == b["access_control"]
    kind = link_security(a["listen"]["endpoints"], a["connect"]["endpoints"], True, True)
    assert kind == ("tls+acl", [])
    again = subprocess.run([*TRACKFLOW, "realm", "init", *map(str, paths), "--out", str(out)],
                           capture_output=True, text=True, timeout=120)  # fmt: skip
    assert again.returncode == 1 and "already holds a realm" in again.stderr


@pytest.mark.parametrize(
    "listen, connect, mtls, acl, kind",
    [
        (["tcp/127.0.0.1:0"], [], None, False, "loopback"),
        (["tcp/localhost:7447"], ["tcp/[::1]:7448"], None, False, "loopback"),
        (["tcp/192.168.1.5:7447"], [], None, False, "insecure"),
        ([], {"peer": ["tcp/10.0.0.3:7447"]}, None, False, "insecure"),
        (["tls/192.168.1.5:7447"], [], True, False, "insecure"),  # no access control
        (["tls/192.168.1.5:7447"], [], False, True, "insecure"),  # no client certificates
        (["tls/192.168.1.5:7447"], ["tls/lab-b:7447"], True, True, "tls+acl"),
    ],
)
def test_link_security(listen, connect, mtls, acl, kind):
    assert link_security(listen, connect, mtls, acl)[0] == kind


def test_an_agent_refuses_plain_links_off_this_machine(tmp_path):
    pytest.importorskip("zenoh", reason="eclipse-zenoh is not installed")
    from trackflow.distributed.config import security, zenoh_config

    extra = ", zenoh: {listen: {endpoints: ['tcp/192.168.1.5:7447']}}"
    cfg = load_agent(_agent(tmp_path, "a", "art", extra=extra))
    with pytest.raises(ConfigError, match=r"a.yaml: agent: zenoh: links off this machine "
                       r"\(tcp/192.168.1.5:7447\) without TLS"):  # fmt: skip
        zenoh_config(cfg)
    cfg = load_agent(_agent(tmp_path, "a", "art", extra=extra + ", insecure: true"))
    assert security(zenoh_config(cfg)) == ("insecure", ["tcp/192.168.1.5:7447"])


def test_plan_on_a_realms_agent_files(tmp_path, capsys):
    """``trackflow plan`` on agent files plans on their union, as the agents would: the
    example realm's query runs through the tracker's and the camera's sensors."""
    from trackflow.cli.main import main

    ex = Path(__file__).resolve().parents[2] / "examples" / "distributed"
    files = [str(ex / f) for f in ("tracker.yaml", "camera.yaml", "app.yaml")]
    assert main(["plan", *files]) == 0
    out = capsys.readouterr().out
    assert out.startswith("path: P->A[projector] . A->T[art] . T->C[target_camera]")
    assert main(["plan", files[2]]) == 1  # the application alone has no path
    assert "no path" in capsys.readouterr().err


def test_a_realm_with_one_sensor_twice_is_refused(tmp_path):
    from trackflow.distributed.realm_setup import realm_setup

    a, b = _agent(tmp_path, "a", "art"), _agent(tmp_path, "b", "art", "Y")
    with pytest.raises(ConfigError, match=r"b\.yaml: edge 'art' is also in .*a\.yaml"):
        realm_setup([a, b])
