"""Where an operator command typed without ``--zenoh-connect`` meets the swarm
(:func:`gcs.cli.operator.session_endpoint`): the session started in this folder, when its run
file names a port that listens, else the default rendezvous. Flown end to end by
tests/test_swarm_up.py (a run moved off a taken port, ``swarm status`` typed in its folder)."""

from __future__ import annotations

import json
import socket
from pathlib import Path

from gcs.cli.operator import DEFAULT_ENDPOINT, SESSION_RUN_FILE, session_endpoint


def _run_file(folder: Path, text: str) -> None:
    path = folder / SESSION_RUN_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)


def test_a_listening_session_in_this_folder_is_found(tmp_path: Path) -> None:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        endpoint = f"tcp/127.0.0.1:{listener.getsockname()[1]}"
        _run_file(tmp_path, json.dumps({"zenoh": endpoint, "agents": {}}))
        assert session_endpoint(tmp_path) == endpoint
    # the run ended (its port closed): the default again
    assert session_endpoint(tmp_path) == DEFAULT_ENDPOINT


def test_no_or_a_broken_run_file_means_the_default(tmp_path: Path) -> None:
    assert session_endpoint(tmp_path) == DEFAULT_ENDPOINT
    for text in ("", "{", "[]", '{"agents": {}}', '{"zenoh": 7}', '{"zenoh": "udp/x:y"}'):
        _run_file(tmp_path, text)
        assert session_endpoint(tmp_path) == DEFAULT_ENDPOINT, text
