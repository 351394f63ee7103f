"""The simulator's sockets: one UDP endpoint per vehicle for its agent, one for the ground station.

Vehicle ``i`` listens on ``bind_host`` at its port (protocols/mavlink_conventions.vehicle_port).
The GCS endpoint is bound to an ephemeral port (of ``bind_host``, or of every interface when the
ground station is on another host) and sends to the ``--gcs`` address (MAVProxy and
QGroundControl answer the port telemetry comes from). Opening refuses clashes with one line naming
the port and the vehicle; closing is idempotent. Use as a context manager.
"""

from __future__ import annotations

import errno
import socket
from collections.abc import Sequence
from types import TracebackType

from protocols.mavlink.conventions import vehicle_port
from sitl_sim.mavlink_edge.channel import Channel, Endpoint, new_codec, report_unreachable
from sitl_sim.sim_config import NetConfig, SimConfigError

_GCS_BUFFER_BYTES = 1 << 21
_GCS_RX_SYSID = 0


def bind_udp(host: str, port: int, what: str, buffer_bytes: int = 0) -> socket.socket:
    """A UDP socket bound to ``host:port``; SimConfigError naming ``what`` when that fails."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        if buffer_bytes:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, buffer_bytes)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, buffer_bytes)
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        if exc.errno == errno.EADDRINUSE:
            raise SimConfigError(f"UDP port {port} ({what}) is in use") from None
        reason = exc.strerror or str(exc)
        raise SimConfigError(f"cannot bind UDP {host}:{port} ({what}): {reason}") from None
    return sock


def _gcs_bind_host(config: NetConfig) -> str:
    """Where the GCS socket binds: the vehicles' address, unless that is loopback and the
    ground station is not (a loopback socket cannot reach another host)."""
    gcs = config.gcs
    if gcs is not None and config.bind_host.startswith("127.") and not gcs[0].startswith("127."):
        return "0.0.0.0"
    return config.bind_host


class Network:
    """Endpoints and channels of every vehicle; ``outbox`` holds endpoints with frames to send."""

    def __init__(self, config: NetConfig, sysids: Sequence[int]) -> None:
        self.config = config
        self.sysids = list(sysids)
        self.outbox: set[Endpoint] = set()
        self.agent_endpoints: list[Endpoint] = []
        self.gcs_endpoint: Endpoint | None = None
        self.agent_channels: list[Channel] = []
        self.gcs_channels: list[Channel] = []

    def __enter__(self) -> Network:
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def open(self) -> None:
        """Bind every socket; on a clash close those already bound and raise SimConfigError."""
        cfg, key = self.config, self.config.signing_key
        try:
            for i, sysid in enumerate(self.sysids):
                port = vehicle_port(cfg.first_drone + i, cfg.base_port)
                sock = bind_udp(cfg.bind_host, port, f"vehicle {i}, system id {sysid}")
                report_unreachable(sock)  # an agent whose process died is noticed at once
                endpoint = Endpoint(sock, new_codec(sysid, 1, key), None, self.outbox)
                self.agent_endpoints.append(endpoint)
                self.agent_channels.append(Channel(endpoint, sysid, key))
            gcs_sock = bind_udp(_gcs_bind_host(cfg), 0, "ground station link", _GCS_BUFFER_BYTES)
            self.gcs_endpoint = Endpoint(
                gcs_sock, new_codec(_GCS_RX_SYSID, 1, key), cfg.gcs, self.outbox
            )
            self.gcs_channels = [Channel(self.gcs_endpoint, s, key) for s in self.sysids]
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        """Close every socket (idempotent)."""
        for endpoint in self.agent_endpoints:
            endpoint.close()
        if self.gcs_endpoint is not None:
            self.gcs_endpoint.close()
        self.outbox.clear()

    def flush(self) -> None:
        """Send every queued frame."""
        outbox = self.outbox
        while outbox:
            outbox.pop().flush()
