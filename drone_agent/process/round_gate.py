"""Lockstep rounds: an agent computes tick ``k`` only with every live drone's round ``k - 1``.

In lockstep the simulator steps once every agent has answered the tick, so every live agent has
*sent* its round ``k - 1`` consensus message before any agent sees tick ``k``; the message may
still be on its way. Each agent process therefore publishes a round-done marker after its agents
finish a round (protocols/wire/round_done.py; it follows their consensus messages on the same Zenoh
session, in the same send batch as far as it goes (Congestion.QUEUED), so whoever has the marker
has those messages, unless Zenoh's DROP congestion control lost one because every batch of the
send queue was still waiting for the wire for 1 s (a machine too loaded to run Zenoh's threads:
lockstep sessions queue 16 batches, not 2)), and an agent starts tick ``k`` once it
holds the round ``k - 1`` marker of every drone of its roster (:class:`RoundGate`). Liveliness
says who will never send it: a drone whose token is gone is dropped from the roster at once (after
``dead_grace_s``, for a marker still in flight), never waited for; a drone never seen alive is
given ``join_grace_s`` of wall time. The first tick waits (up to ``first_grace_s``) until every
drone of the roster is alive, that is listening: a message or marker sent before its receiver
subscribed would be lost (Zenoh keeps nothing for late subscribers). A process re-sends its newest
markers while one of its agents waits long (:meth:`RoundBook.repeat`): one lost marker must not
stall the swarm. The roster is also the agent's membership view,
so what the estimator sees depends on the scenario and its faults alone, not on when messages,
tokens or markers happen to arrive.

:class:`RoundBook` is the process's side (one per agent process, shared by the agents it hosts):
the marker subscription and publisher and the liveliness watch. :class:`RoundGate` is one agent's
decision, pure apart from the book it reads and the wall time passed in.
"""

from __future__ import annotations

import itertools
from collections import deque
from collections.abc import Iterable, Sequence

from drone_agent.process.membership_views import Views
from protocols.bus.interface import Bus, Closeable, ClosesOnExit, Congestion
from protocols.wire.format import WireError
from protocols.wire.keys import SwarmKeys
from protocols.wire.round_done import RoundDone, decode_round_done, encode_round_done

_NOT_YET = itertools.repeat(-1)  # done.get's default: no round finished
#: Markers kept between two polls (oldest dropped beyond: a newer marker says more).
MARKER_CAPACITY = 1024


class RoundBook(ClosesOnExit):
    """What one agent process knows of the swarm's rounds: the newest round each drone has
    finished (its markers), which drones are alive and which have ever been (liveliness), and
    the markers of its own agents to publish (:meth:`finished`, :meth:`flush`)."""

    def __init__(self, bus: Bus, keys: SwarmKeys, hosted: Sequence[int]) -> None:
        self._keys = keys
        self.done: dict[int, int] = {}
        self.alive: set[int] = set()
        self.seen: set[int] = set()
        #: drones whose token went away, with the wall time we noticed (set by poll's caller)
        self.gone: set[int] = set()
        self._changes: deque[tuple[int, bool]] = deque()
        self._to_send: dict[int, list[int]] = {}
        self._newest: dict[int, int] = {}  # hosted drone -> newest round finished
        self.rejected = 0
        #: one tuple per distinct roster of the process's gates (:meth:`roster_of`)
        self._rosters: dict[tuple[int, ...], tuple[int, ...]] = {}
        #: the process's one frozenset per membership view (its gates' members())
        self.views = Views()
        #: by roster (its tuple's id): the roster, version, round and :meth:`lows`' answer
        self._lows: dict[int, tuple[tuple[int, ...], int, int, tuple[int, int, int, bool]]] = {}
        #: moves whenever :meth:`poll` took in a marker or a liveliness change
        self.version = 0
        self._declared: list[Closeable] = []
        # DROP, express: never blocking the agent's thread (BLOCK stalled whole lockstep swarms
        # on a loaded machine), and it flushes the pass's QUEUED consensus messages ahead of it
        # in one send batch (Congestion); a lost marker is made up for by :meth:`repeat`
        self._publisher = bus.publisher(keys.round_done(min(hosted)), Congestion.DROP)
        self._declared.append(self._publisher)
        # pulled (no Python on Zenoh's threads), drained by :meth:`poll`
        self._inbox = bus.subscribe(keys.round_done_all(), MARKER_CAPACITY)
        self._declared.append(self._inbox)
        self._declared.append(bus.watch_liveliness(keys.alive_all(), self._on_liveliness))

    def _on_liveliness(self, key: str, alive: bool) -> None:
        drone = self._keys.drone_of(key)
        if drone is not None:
            self._changes.append((drone, alive))

    def poll(self) -> bool:
        """Take in the markers and liveliness changes that arrived (on the caller's thread);
        whether there were any."""
        news = bool(self._changes)
        while self._changes:
            drone, alive = self._changes.popleft()
            if alive:
                self.alive.add(drone)
                self.seen.add(drone)
                self.gone.discard(drone)
            else:
                self.alive.discard(drone)
                self.gone.add(drone)
        for _key, payload in self._inbox.drain():
            news = True
            try:
                marker = decode_round_done(payload, self._keys.swarm_id)
            except WireError:
                self.rejected += 1
                continue
            done = self.done
            for drone in marker.drones:
                if marker.round > done.get(drone, -1):
                    done[drone] = marker.round
                self.seen.add(drone)
        if news:
            self.version += 1
        return news

    def roster_of(self, drones: Iterable[int]) -> tuple[int, ...]:
        """``drones`` sorted, as the one tuple of the process for that roster (the gates of its
        agents share :meth:`lows` through it)."""
        key = tuple(sorted(drones))
        if len(self._rosters) > 256:  # rosters of long ago (drop-outs, returns)
            self._rosters.clear()
            self._lows.clear()
        return self._rosters.setdefault(key, key)

    def lows(self, roster: tuple[int, ...], need: int) -> tuple[int, int, int, bool]:
        """Over ``roster`` (a :meth:`roster_of` tuple), as of the last :meth:`poll`: the lowest
        round finished (-1: none), the first drone with it, the lowest of the others, and
        whether a drone outside the roster has finished round ``need`` and is alive (a
        newcomer). Worked out once per roster and poll for all the gates of the process."""
        got = self._lows.get(id(roster))
        if got is not None and got[0] is roster and got[1] == self.version and got[2] == need:
            return got[3]
        done = self.done
        values = list(map(done.get, roster, _NOT_YET))
        low = min(values, default=need)
        at = values.index(low) if values else -1
        rest = min(itertools.chain(values[:at], values[at + 1 :]), default=need) if values else need
        members = set(roster)
        joining = any(done[j] >= need and j in self.alive for j in done.keys() - members)
        answer = (low, roster[at] if values else -1, rest, joining)
        self._lows[id(roster)] = (roster, self.version, need, answer)
        return answer

    def finished(self, drone: int, round_: int) -> None:
        """Hosted ``drone`` has finished ``round_`` (its consensus message, if any, is sent)."""
        self._to_send.setdefault(round_, []).append(drone)
        self._newest[drone] = round_

    def flush(self) -> None:
        """Publish the markers of the rounds finished since the last flush."""
        if not self._to_send:
            return
        rounds, self._to_send = self._to_send, {}
        self._publish(rounds)

    def _publish(self, rounds: dict[int, list[int]]) -> None:
        sid = self._keys.swarm_id
        for round_, drones in sorted(rounds.items()):
            self._publisher.put(encode_round_done(RoundDone(round_, tuple(sorted(drones))), sid))

    def repeat(self) -> None:
        """Publish the newest round of each hosted drone again (a marker means "this round and
        every earlier one": a repeat is harmless, and makes up for one that was lost)."""
        rounds: dict[int, list[int]] = {}
        for drone, round_ in self._newest.items():
            rounds.setdefault(round_, []).append(drone)
        self._publish(rounds)

    def close(self) -> None:
        """Undeclare the publisher, subscription and watch."""
        for thing in reversed(self._declared):
            thing.close()
        self._declared.clear()


class RoundGate:
    """Drone ``me``'s lockstep wait: :meth:`ready` says whether tick ``k`` may be computed, and
    :meth:`members` is then the roster, the agent's membership view of the tick."""

    def __init__(
        self,
        me: int,
        roster: Iterable[int],
        book: RoundBook,
        join_grace_s: float = 5.0,
        dead_grace_s: float = 0.05,
        first_grace_s: float = 60.0,
    ) -> None:
        self.me = me
        self.first_grace_s = first_grace_s
        self.roster = set(roster) | {me}
        self.book = book
        self.join_grace_s = join_grace_s
        self.dead_grace_s = dead_grace_s
        self._first_tick: int | None = None
        self._since: dict[int, float] = {}  # drone -> wall time we began waiting on its death
        self._tick = -1
        self._tick_since = 0.0
        self._members = self.book.views.of(self.roster)
        #: the roster, the book's tuple of it (None: to be made again after a change)
        self._shared: tuple[int, ...] | None = None

    def ready(self, tick: int, now: float) -> bool:
        """Whether every drone of the roster has finished round ``tick - 1`` or is dead (dropped
        from the roster); a drone that is alive is waited for as long as it is."""
        if tick != self._tick:
            self._tick, self._tick_since = tick, now
        if self._first_tick is None:
            # the first tick: every drone of the roster listens (its token, declared after its
            # subscriptions, is here), so that none misses a message or marker of round 0
            self.book.poll()
            alive = self.book.alive
            # a late joiner (a restarted agent: rounds before this one are done) waits for nobody
            running = any(r < tick for j, r in self.book.done.items() if j != self.me)
            waiting = any(j not in alive and j not in self.book.gone for j in self.roster)
            if not running and waiting and now - self._tick_since < self.first_grace_s:
                return False
            self._first_tick = tick
            self.roster = {j for j in self.roster if j in alive} | {self.me}
            self._members = self.book.views.of(self.roster)
            self._shared = None
        if tick > self._first_tick:
            book = self.book
            book.poll()
            need = tick - 1
            done, alive = book.done, book.alive
            if self._shared is None:
                self._shared = book.roster_of(self.roster)
            # the usual case, worked out once for the process's gates: every other drone of
            # the roster has sent its round and nobody joins (the loops below change nothing)
            low, low_drone, rest, joining = book.lows(self._shared, need)
            if (rest if low_drone == self.me else low) >= need and not joining:
                return True
            if not joining and self.roster <= alive:
                # someone of the roster has not finished its round and every one is alive: the
                # loop below would stop at the first of them and change nothing before it
                return False
            newcomers = done.keys() - self.roster
            changed = False
            for j in sorted(self.roster):
                if j == self.me or done.get(j, -1) >= need:
                    continue
                if j in alive:
                    return False  # alive: it will send its round
                if j in book.gone:  # its token went away: dead (a marker may be in flight)
                    since = self._since.setdefault(j, now)
                    if now - since < self.dead_grace_s:
                        return False
                elif now - self._tick_since < self.join_grace_s:  # never seen alive yet
                    return False
                self.roster.discard(j)
                self._since.pop(j, None)
                changed = True
            for j in sorted(newcomers):  # newcomers (a restarted agent): from their next round
                if done[j] >= need and j in alive:
                    self.roster.add(j)
                    changed = True
            if changed:
                self._members = self.book.views.of(self.roster)
                self._shared = None
        return True

    def members(self) -> frozenset[int]:
        """The roster (this agent included), one object while it does not change."""
        return self._members
