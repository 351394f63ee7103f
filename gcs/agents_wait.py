"""Wait until the agents of some drones are alive on the swarm's Zenoh network (their liveliness
tokens seen through the router), then exit 0; exit 1 on timeout, naming the missing drones.

``swarm up --only sim`` on a simulator host runs this in a child process of its own before it
starts the simulator (no Zenoh session in the supervisor: it forks its children afterwards): the
simulator's first tick then finds every agent already knowing the others, as on one host, instead
of agents that joined the lockstep barrier before their Zenoh sessions had met and took off as
separate swarms.

    python -m gcs.agents_wait ENDPOINT SWARM_ID LO HI TIMEOUT_S [SECRETS_DIR]
"""

from __future__ import annotations

import sys
import threading
import time


def wait_alive(
    endpoint: str, swarm_id: str, drones: range, timeout_s: float, secrets_dir: str | None
) -> set[int]:
    """The drones of ``drones`` still missing after waiting up to ``timeout_s`` seconds."""
    from drone_agent.zenoh_config import role_secrets
    from drone_agent.zenoh_transport import open_client
    from protocols.keys import SwarmKeys

    keys = SwarmKeys(swarm_id, 1.0)
    alive: set[int] = set()
    changed = threading.Event()

    def on_change(key: str, up: bool) -> None:
        drone = keys.drone_of(key)
        if drone is not None:
            (alive.add if up else alive.discard)(drone)
            changed.set()

    with open_client(endpoint, role_secrets(secrets_dir, "sim", swarm_id)) as bus:
        watch = bus.watch_liveliness(keys.alive_all(), on_change)
        end = time.monotonic() + timeout_s
        while set(drones) - alive and time.monotonic() < end:
            changed.wait(0.2)
            changed.clear()
        watch.close()
    return set(drones) - alive


def main(argv: list[str]) -> int:
    endpoint, swarm_id, lo, hi, timeout = argv[:5]
    secrets_dir = argv[5] if len(argv) > 5 else None
    try:
        missing = wait_alive(
            endpoint, swarm_id, range(int(lo), int(hi) + 1), float(timeout), secrets_dir
        )
    except (ValueError, ConnectionError) as exc:
        print(f"swarm up: cannot watch the agents: {exc}", file=sys.stderr)
        return 2
    if missing:
        print(
            f"swarm up: the agents of drones {sorted(missing)} did not join within {timeout} s",
            file=sys.stderr,
        )
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
