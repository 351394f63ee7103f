"""The ``swarm`` command line (:mod:`gcs.cli.main`), one module per command.

``swarm`` is ``gcs.cli:main``; ``python -m gcs.cli`` runs it too.
"""

from __future__ import annotations


def main(argv: list[str] | None = None) -> int:
    """``swarm ARGS``: see :func:`gcs.cli.main.main`."""
    from gcs.cli.main import main as run

    return run(argv)
