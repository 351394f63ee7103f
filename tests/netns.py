"""Linux network namespaces as separate hosts for tests: one namespace per host, each with its own
address on a bridge (in a namespace of its own, so nothing of the machine's network changes),
joined by veth pairs. Needs root (``ip netns``); :func:`unavailable` says why they cannot be made.
"""

from __future__ import annotations

import contextlib
import os
import random
import shutil
import subprocess
from collections.abc import Iterator, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Host:
    """A namespace ``ns`` with address ``ip`` (a /24 shared with the other hosts)."""

    name: str
    ns: str
    ip: str

    def argv(self, *command: str, env: dict[str, str] | None = None) -> list[str]:
        """``command`` run inside this host, with ``env`` (ip netns exec keeps no environment
        of its own choosing: pass what the command needs)."""
        pairs = [f"{k}={v}" for k, v in (env or {}).items()]
        return ["ip", "netns", "exec", self.ns, "env", *pairs, *command]


def _ip(*args: str, ns: str | None = None) -> None:
    cmd = ["ip", *args] if ns is None else ["ip", "netns", "exec", ns, "ip", *args]
    subprocess.run(cmd, check=True, capture_output=True, text=True, timeout=20)


def unavailable() -> str | None:
    """Why namespaces cannot be created here (None: they can)."""
    if shutil.which("ip") is None:
        return "the ip command (iproute2) is not installed"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    probe = f"qsprobe{os.getpid()}"
    try:
        _ip("netns", "add", probe)
    except (subprocess.CalledProcessError, OSError) as exc:
        err = getattr(exc, "stderr", "") or str(exc)
        return f"cannot create a network namespace: {err.strip()}"
    finally:
        subprocess.run(["ip", "netns", "del", probe], capture_output=True, timeout=20)
    return None


@contextlib.contextmanager
def hosts(names: Sequence[str]) -> Iterator[dict[str, Host]]:
    """Namespaces ``names`` on one bridged /24 (10.231.S.1, .2, ... in order); all removed on
    exit (their processes must have ended)."""
    tag = f"qs{os.getpid() % 100000}"
    subnet = random.randrange(1, 250)
    switch = f"{tag}sw"
    made: list[str] = []
    try:
        _ip("netns", "add", switch)
        made.append(switch)
        _ip("link", "add", "br0", "type", "bridge", ns=switch)
        _ip("link", "set", "br0", "up", ns=switch)
        out: dict[str, Host] = {}
        for i, name in enumerate(names):
            ns = f"{tag}{name}"
            ip = f"10.231.{subnet}.{i + 1}"
            _ip("netns", "add", ns)
            made.append(ns)
            port = f"p{i}"
            _ip(
                "link",
                "add",
                port,
                "netns",
                switch,
                "type",
                "veth",
                "peer",
                "name",
                "eth0",
                "netns",
                ns,
            )
            _ip("link", "set", port, "master", "br0", ns=switch)
            _ip("link", "set", port, "up", ns=switch)
            _ip("addr", "add", f"{ip}/24", "dev", "eth0", ns=ns)
            _ip("link", "set", "eth0", "up", ns=ns)
            _ip("link", "set", "lo", "up", ns=ns)
            out[name] = Host(name, ns, ip)
        yield out
    finally:
        for ns in reversed(made):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True, timeout=20)
