"""One clock for vehicles that each keep their own: a vehicle's ``time_boot_ms`` on the swarm's.

The project's own simulator gives every vehicle the same simulated time, so its ``time_boot_ms``
*is* the swarm's clock. Autopilots started one by one (ArduCopter SITL instances, real vehicles)
each count from their own boot. Their agents and the ground station then agree on the swarm's
clock as milliseconds since a shared epoch (``--swarm-epoch``, Unix seconds; ``swarm up`` picks
it and passes it to every process), and map each vehicle's stamps onto it:
``swarm_ms = time_boot_ms + offset``, where the offset is the smallest ``receipt - time_boot_ms``
of the vehicle's last :data:`WINDOW` messages (the least delayed one: the stamps keep the
vehicle's own spacing, and a vehicle whose clock runs slow or fast is followed within a window).
A vehicle that reboots starts a new window at once (its stamps went back by more than a second).
"""

from __future__ import annotations

import argparse
import math
import time
from collections import deque
from collections.abc import Callable

#: Messages over which the least delayed one sets the offset (2 s of a 50 Hz stream).
WINDOW = 100
#: A stamp this far (ms) behind the last one is a reboot.
REBOOT_MS = 1000


class VehicleClock:
    """Maps one vehicle's ``time_boot_ms`` onto the swarm's clock (ms since ``epoch_s``)."""

    def __init__(self, epoch_s: float, wall: Callable[[], float] = time.time) -> None:
        self.epoch_s = epoch_s
        self.wall = wall
        self._lags: deque[tuple[int, float]] = deque()  # (sequence, lag), lags increasing
        self._seq = 0
        self._last_boot_ms = -1

    def swarm_ms(self, boot_ms: int) -> int:
        """The swarm time (ms) of a message stamped ``boot_ms`` that arrived just now."""
        if boot_ms < self._last_boot_ms - REBOOT_MS:
            self._lags.clear()
        self._last_boot_ms = boot_ms
        lag = (self.wall() - self.epoch_s) * 1000.0 - boot_ms
        lags = self._lags
        while lags and lags[-1][1] >= lag:
            lags.pop()
        lags.append((self._seq, lag))
        while lags[0][0] <= self._seq - WINDOW:
            lags.popleft()
        self._seq += 1
        return round(boot_ms + lags[0][1])


#: ``--swarm-epoch``'s help, for every role that takes it (agents, ground station).
EPOCH_HELP = (
    "vehicles that each count time from their own boot (ArduCopter SITL instances): the swarm's "
    "clock is seconds since this Unix time, the same for every agent and the ground station "
    "(swarm up passes it); without it the vehicles' time_boot_ms is the swarm's clock (one "
    "simulator)"
)


def epoch_arg(text: str) -> float:
    """``--swarm-epoch``'s value: a finite, positive Unix time (s); otherwise the one-line error
    argparse prints."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"must be a Unix time in seconds, got {text!r}")
    return value


def swarm_now_ms(epoch_s: float, wall: Callable[[], float] = time.time) -> int:
    """The swarm's clock now (ms since ``epoch_s``)."""
    return round((wall() - epoch_s) * 1000.0)
