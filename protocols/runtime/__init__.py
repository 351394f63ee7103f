"""How the project runs fast: numba compilation through one helper, cheap frozen dataclasses,
the garbage collector tuned for a flight."""
