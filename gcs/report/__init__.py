"""A flight's report: flight.tlog, events.jsonl, metrics.json, plots and the printed summaries,
whether the flight was in one process or distributed."""
