"""The default rendezvous port: a swarm that just ended leaves TIME_WAIT connections on it for a
minute; the next ``swarm up`` must still take it (else the operator's default ``swarm status``
finds nobody), and a port someone listens on is busy."""

from __future__ import annotations

import socket
import time

from protocols.bus.zenoh_bus import ZenohBus, ZenohSettings, tcp_listen_free


def _time_wait_on_a_port() -> int:
    """A port left with a server-side TIME_WAIT connection (as a closed Zenoh listener leaves)."""
    with socket.socket() as srv:
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind(("127.0.0.1", 0))
        port = int(srv.getsockname()[1])
        srv.listen()
        client = socket.create_connection(("127.0.0.1", port))
        accepted, _ = srv.accept()
        accepted.close()  # the server side closes first: TIME_WAIT stays on the server's port
        time.sleep(0.05)
        client.close()
    return port


def test_a_port_in_time_wait_is_free_for_zenoh_and_a_listening_one_is_not() -> None:
    port = _time_wait_on_a_port()
    with socket.socket() as plain:  # what the old check did: it called this port busy
        try:
            plain.bind(("127.0.0.1", port))
            plain_ok = True
        except OSError:
            plain_ok = False
    assert not plain_ok
    assert tcp_listen_free(port)
    bus = ZenohBus.open(ZenohSettings(listen=(f"tcp/127.0.0.1:{port}",)))
    try:
        assert not tcp_listen_free(port)  # a real listener is busy
    finally:
        bus.close()
