"""``python -m gcs.cli``: the ``swarm`` command."""

from gcs.cli.main import main

raise SystemExit(main())
