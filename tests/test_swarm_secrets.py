"""A secured swarm network: ``swarm keys init``, the router's TLS, authentication and access
control, and what an operator sees when something is refused.

Against a real router (``swarm router --secrets``) on loopback: a client without credentials, a
certificate of another CA, a wrong password and an expired certificate cannot connect (the last
says it expired), nor can another swarm's operator write into this one; an agent's credential cannot
send ``land``, publish a plan or put a fault (the sessions that would receive them never do, even
when the CLI's own check is bypassed); a password presented with another role's certificate gets no
right at all; the operator's can. A secured ``swarm up`` flies, and ``swarm status`` says the
network is secured.
"""

from __future__ import annotations

import json
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from agent_harness import write_scenario
from sitl_client import ENV, ROOT, free_port_block, free_udp_port, swarm_command

from protocols.bus.interface import Congestion
from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, free_loopback_endpoint
from protocols.bus.zenoh_config import role_secrets
from protocols.secrets.swarm_secrets import ROLES, access_control, init_secrets, load_role, may

SWARM_ID = "locked"


def _swarm(*args: str, timeout: float = 30) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        swarm_command(*args), capture_output=True, text=True, env=ENV, cwd=ROOT, timeout=timeout
    )


@pytest.fixture(scope="module")
def secrets(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("s") / "secrets"
    out = _swarm("keys", "init", str(folder), "--swarm-id", SWARM_ID)
    assert out.returncode == 0, out.stderr
    for name in ("agent.password", "operator.password", "gcs.password", "mavlink.key"):
        assert (folder / name).read_text().strip() not in out.stdout + out.stderr
    return folder


@pytest.fixture(scope="module")
def router(secrets: Path) -> Iterator[str]:
    """``swarm router --secrets`` on a free loopback port; its tls/ endpoint."""
    endpoint = free_loopback_endpoint().replace("tcp/", "tls/")
    proc = subprocess.Popen(
        swarm_command("router", "--listen", endpoint, "--secrets", str(secrets)),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=ENV, cwd=ROOT,
    )  # fmt: skip
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline().decode()
        assert "listening on " + endpoint in line and "secured" in line, line
        yield endpoint
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(15)


def _session(secrets: Path, role: str, endpoint: str) -> ZenohBus:
    return ZenohBus.open(
        ZenohSettings(
            mode="client", listen=(), connect=(endpoint,), secrets=role_secrets(secrets, role)
        )
    )


def _serve_commands(gcs: ZenohBus, commands: list[bytes]) -> None:
    """A ground station's command queryable on ``gcs`` that answers "ok" and notes each query
    that reached it in ``commands``."""

    def answer(query: object) -> None:
        commands.append(b"q")
        query.reply(f"swarm/{SWARM_ID}/command", b"ok")  # type: ignore[attr-defined]

    gcs.session.declare_queryable(f"swarm/{SWARM_ID}/command", answer)


def _one_line_error(out: subprocess.CompletedProcess[str], *words: str) -> None:
    assert out.returncode == 2, out.stdout + out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("swarm: error: "), out.stderr
    assert "Traceback" not in out.stderr
    for w in words:
        assert w in lines[0], lines[0]


def test_keys_init_writes_private_files(secrets: Path) -> None:
    assert secrets.stat().st_mode & 0o777 == 0o700
    files = list(secrets.iterdir())
    assert len(files) >= 17
    assert all(f.stat().st_mode & 0o777 == 0o600 for f in files)
    for role in ROLES:
        assert load_role(secrets, role).role == role
    again = _swarm("keys", "init", str(secrets))
    _one_line_error(again, "already holds swarm secrets")


def test_access_rules() -> None:
    assert may("agent", "put", "consensus/1/2/-1/7") and may("agent", "put", "status/3")
    assert may("agent", "liveliness_token", "alive/3")
    assert may("agent", "declare_subscriber", "plan") and may("agent", "query", "plan")
    assert not may("agent", "put", "plan") and not may("agent", "query", "command")
    assert not may("agent", "put", "fault") and not may("agent", "put", "status/3/x")
    assert may("operator", "query", "command") and may("operator", "put", "fault")
    assert not may("operator", "put", "plan")
    assert may("gcs", "put", "plan") and not may("gcs", "query", "command")
    acl = access_control(SWARM_ID)
    assert acl["default_permission"] == "deny"
    keys = {k for rule in acl["rules"] for k in rule["key_exprs"]}  # type: ignore[attr-defined]
    assert all(k.startswith(f"swarm/{SWARM_ID}/") for k in keys)


def test_the_router_enforces_the_rights(secrets: Path, router: str) -> None:
    """Sessions of each role, straight on the router (no CLI check in between)."""
    commands: list[bytes] = []
    plans: list[bytes] = []
    consensus: list[bytes] = []
    got = threading.Event()
    with (
        _session(secrets, "gcs", router) as gcs,
        _session(secrets, "agent", router) as agent,
        _session(secrets, "agent", router) as other_agent,
        _session(secrets, "operator", router) as operator,
    ):
        _serve_commands(gcs, commands)
        gcs.subscribe_callback(f"swarm/{SWARM_ID}/plan", lambda _k, p: plans.append(p))
        other_agent.subscribe_callback(
            f"swarm/{SWARM_ID}/consensus/**", lambda _k, p: (consensus.append(p), got.set())
        )
        agent_plans: list[bytes] = []
        other_agent.subscribe_callback(
            f"swarm/{SWARM_ID}/plan", lambda _k, p: agent_plans.append(p)
        )
        time.sleep(1.0)
        # an agent's credential: no land, no plan
        replies = list(agent.session.get(f"swarm/{SWARM_ID}/command", payload=b"land", timeout=1.5))
        assert [r for r in replies if r.ok is not None] == []
        agent.publisher(f"swarm/{SWARM_ID}/plan", Congestion.BLOCK).put(b"evil plan")
        # what an agent may do still goes through
        agent.publisher(f"swarm/{SWARM_ID}/consensus/0/0/0/3", Congestion.BLOCK).put(b"c")
        assert got.wait(5.0)
        # the operator's credential may send commands
        replies = list(operator.session.get(f"swarm/{SWARM_ID}/command", timeout=3.0))
        assert [r.ok.payload.to_bytes() for r in replies if r.ok is not None] == [b"ok"]
        time.sleep(0.5)
        assert plans == []  # the agent's plan never reached the ground station
        # the ground station's plan reaches the agents
        gcs.publisher(f"swarm/{SWARM_ID}/plan", Congestion.BLOCK).put(b"plan")
        time.sleep(1.0)
    assert commands == [b"q"]  # the operator's only: the agent's land never reached the station
    assert agent_plans == [b"plan"]
    assert consensus == [b"c"]


def test_clients_without_the_right_credentials_cannot_connect(
    secrets: Path, router: str, tmp_path: Path
) -> None:
    port = router.rsplit(":", 1)[1]
    # no credentials at all: plain TCP to the TLS port, TLS without a certificate
    plain = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", f"tcp/127.0.0.1:{port}")
    _one_line_error(plain, "refused", "--secrets")
    bare = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", router)
    _one_line_error(bare, "refused", "--secrets")
    # a certificate of another swarm's CA (same role names, same swarm id)
    stranger = tmp_path / "stranger"
    init_secrets(stranger, SWARM_ID)
    wrong_ca = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
                      "--secrets", str(stranger))  # fmt: skip
    _one_line_error(wrong_ca, "refused the 'operator' credential", "certificate")
    # the right certificate with a wrong password
    forged = tmp_path / "forged"
    forged.mkdir(mode=0o700)
    for f in secrets.iterdir():
        (forged / f.name).write_bytes(f.read_bytes())
    (forged / "operator.password").write_text("not-the-password\n")
    bad_password = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
                          "--secrets", str(forged))  # fmt: skip
    _one_line_error(bad_password, "refused the 'operator' credential", "password")
    # long-running processes too, at once (they wait for a router only while none answers)
    started = time.monotonic()
    agent = _swarm(
        "agent", "--drone-id", "0", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
        "--secrets", str(stranger), "--base-port", str(free_port_block(1)),
    )  # fmt: skip
    _one_line_error(agent, "refused the 'agent' credential")
    assert time.monotonic() - started < 20.0
    # nothing listening at all says so
    nobody = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect",
                    free_loopback_endpoint(), "--secrets", str(secrets))  # fmt: skip
    _one_line_error(nobody, "nothing reachable")


def test_an_agent_credential_is_refused_in_one_line(secrets: Path, router: str) -> None:
    land = _swarm("land", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
                  "--secrets", str(secrets), "--role", "agent")  # fmt: skip
    _one_line_error(land, "'agent' credential has no right to send operator commands")
    drill = _swarm("drill", "link-cut", "0", "1", "--swarm-id", SWARM_ID, "--zenoh-connect",
                   router, "--secrets", str(secrets), "--role", "agent")  # fmt: skip
    _one_line_error(drill, "'agent' credential has no right to send drills")
    other = _swarm("status", "--swarm-id", "other", "--zenoh-connect", router,
                   "--secrets", str(secrets))  # fmt: skip
    _one_line_error(other, "swarm 'locked'", "not 'other'")


def test_secured_swarm_up_flies_and_status_says_secured(secrets: Path, tmp_path: Path) -> None:
    scenario = write_scenario(
        tmp_path / "hover.toml",
        [(0.0, 0.0, 0.0), (0.0, 3.0, 0.0), (4.0, 0.0, 0.0), (4.0, 3.0, 0.0)],
        centre=(2.0, 1.5, -2.0), spread=(2.0, 1.5, 0.0), duration_s=40.0, settle_s=8.0,
    )  # fmt: skip
    report = tmp_path / "report"
    router = free_loopback_endpoint()
    proc = subprocess.Popen(
        swarm_command(
            "up", str(scenario), "--report", str(report), "--no-plots", "--no-recording",
            "--base-port", str(free_port_block(4)),
            "--gcs-port", str(free_udp_port()), "--swarm-id", SWARM_ID, "--clock", "realtime",
            "--secrets", str(secrets), "--router", router, "--only", "router,gcs,sim,agents",
            "--duration-s", "18",
        ),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=ENV, cwd=ROOT,
    )  # fmt: skip
    secured = router.replace("tcp/", "tls/")
    try:
        status = None
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            status = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
                            "--secrets", str(secrets))  # fmt: skip
            if status.returncode == 0 and status.stdout.count("FLYING") == 4:
                break
            time.sleep(1.0)
        assert status is not None and status.stdout.count("FLYING") == 4, status
        assert "network: secured (TLS with client certificates" in status.stdout
        refused = _swarm("land", "--swarm-id", SWARM_ID, "--zenoh-connect", secured,
                         "--secrets", str(secrets), "--role", "agent")  # fmt: skip
        _one_line_error(refused, "no right")
        out, _ = proc.communicate(timeout=90)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.communicate(timeout=60)
    text = out.decode(errors="replace")
    assert proc.returncode == 0 and "swarm up: finished" in text, text
    metrics = json.loads((report / "metrics.json").read_text())
    assert metrics["tracking_steady"]["centroid_m"]["rms"] < 0.05
    events = [json.loads(line) for line in (report / "events.jsonl").read_text().splitlines()]
    assert not any(e.get("kind") == "command" and "land" in str(e) for e in events)
    assert "signed" in (report / "logs" / "sim.log").read_text()
    logged = "".join(p.read_text(errors="replace") for p in (report / "logs").glob("*.log"))
    for name in ("agent.password", "gcs.password", "mavlink.key"):
        assert (secrets / name).read_text().strip() not in logged + text


def _forged(secrets: Path, folder: Path) -> Path:
    """A copy of the swarm's secrets folder, to tamper with."""
    folder.mkdir(mode=0o700)
    for f in secrets.iterdir():
        (folder / f.name).write_bytes(f.read_bytes())
        (folder / f.name).chmod(0o600)
    return folder


def test_the_router_refuses_faults_and_borrowed_passwords(
    secrets: Path, router: str, tmp_path: Path
) -> None:
    """At the router, with nothing of the CLI in between: an agent's credential putting a fault
    (the drills' key) reaches no agent, though the operator's does; a session presenting the
    agent's certificate with the operator's user name and password (a password without its
    certificate) gets no right at all: its commands go unanswered and its faults nowhere."""
    borrowed = _forged(secrets, tmp_path / "borrowed")
    (borrowed / "operator.pem").write_bytes((secrets / "agent.pem").read_bytes())
    (borrowed / "operator.key").write_bytes((secrets / "agent.key").read_bytes())
    faults: list[bytes] = []
    commands: list[bytes] = []
    with (
        _session(secrets, "gcs", router) as gcs,
        _session(secrets, "agent", router) as listener,
        _session(secrets, "agent", router) as agent,
        _session(secrets, "operator", router) as operator,
        _session(borrowed, "operator", router) as impostor,
    ):
        _serve_commands(gcs, commands)
        listener.subscribe_callback(f"swarm/{SWARM_ID}/fault", lambda _k, p: faults.append(p))
        time.sleep(1.0)
        agent.publisher(f"swarm/{SWARM_ID}/fault", Congestion.BLOCK).put(b"agent fault")
        impostor.publisher(f"swarm/{SWARM_ID}/fault", Congestion.BLOCK).put(b"impostor fault")
        replies = list(impostor.session.get(f"swarm/{SWARM_ID}/command", timeout=1.5))
        assert [r for r in replies if r.ok is not None] == []
        operator.publisher(f"swarm/{SWARM_ID}/fault", Congestion.BLOCK).put(b"drill")
        deadline = time.monotonic() + 5.0
        while not faults and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
    assert faults == [b"drill"]  # the operator's only
    assert commands == []  # the impostor's command never reached the ground station


def test_swarm_a_cannot_write_into_swarm_b(secrets: Path, router: str, tmp_path: Path) -> None:
    """Swarm A's operator (``swarm keys init`` of its own: its CA, its swarm id) against swarm
    B's router: the router refuses its session at TLS, so its drill and its ``land`` reach
    nobody of swarm B (B's agent subscribed to the fault key and B's ground station serving
    commands hear nothing, while B's own operator still gets through), and the user reads one
    line naming the refused credential, or the swarm it belongs to."""
    import zenoh

    swarm_a = tmp_path / "swarm-a"
    init_secrets(swarm_a, "swarm-a")
    faults: list[bytes] = []
    commands: list[bytes] = []
    with (
        _session(secrets, "gcs", router) as gcs,
        _session(secrets, "agent", router) as listener,
        _session(secrets, "operator", router) as operator,
    ):
        _serve_commands(gcs, commands)
        listener.subscribe_callback(f"swarm/{SWARM_ID}/fault", lambda _k, p: faults.append(p))
        time.sleep(1.0)
        with pytest.raises(zenoh.ZError):  # at the router: no session for A's certificate
            _session(swarm_a, "operator", router).close()
        land = _swarm("land", "--swarm-id", "swarm-a", "--zenoh-connect", router,
                      "--secrets", str(swarm_a))  # fmt: skip
        _one_line_error(land, "refused the 'operator' credential", "certificate")
        drill = _swarm("drill", "link-cut", "0", "1", "--swarm-id", SWARM_ID,
                       "--zenoh-connect", router, "--secrets", str(swarm_a))  # fmt: skip
        _one_line_error(drill, "belong to swarm 'swarm-a'", f"not '{SWARM_ID}'")
        # B's operator, on the same router meanwhile: its drill arrives
        operator.publisher(f"swarm/{SWARM_ID}/fault", Congestion.BLOCK).put(b"b drill")
        deadline = time.monotonic() + 5.0
        while not faults and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
    assert faults == [b"b drill"]
    assert commands == []


def test_an_expired_certificate_is_refused_in_one_line(
    secrets: Path, router: str, tmp_path: Path
) -> None:
    """The operator's certificate, signed by the swarm's own CA but expired yesterday."""
    import datetime

    from cryptography import x509
    from cryptography.hazmat.primitives import serialization

    from protocols.secrets.swarm_secrets import _cert_pem, _issue, _key_pem

    expired = _forged(secrets, tmp_path / "expired")
    ca_key = serialization.load_pem_private_key((secrets / "ca.key").read_bytes(), None)
    ca_cert = x509.load_pem_x509_certificate((secrets / "ca.pem").read_bytes())
    now = datetime.datetime.now(datetime.UTC)
    valid = (now - datetime.timedelta(days=30), now - datetime.timedelta(days=1))
    key, cert = _issue(ca_key, ca_cert, "operator", [], valid)
    (expired / "operator.pem").write_bytes(_cert_pem(cert))
    (expired / "operator.key").write_bytes(_key_pem(key))
    out = _swarm("status", "--swarm-id", SWARM_ID, "--zenoh-connect", router,
                 "--secrets", str(expired))  # fmt: skip
    _one_line_error(out, "refused the 'operator' credential", "certificate expired on", "keys init")
