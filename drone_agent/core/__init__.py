"""The agent's pure, batched core: consensus, moments, the formation controller, separation,
thrust and attitude, the flight phases. No I/O, no clock; a scalar class is a one-row view."""
