"""A SITL test of your own with quadswarm's pytest plugin (``pip install quadswarm`` registers
it): the ``swarm`` fixture starts a swarm on free ports, in lockstep, and ends it with the test.

    pytest examples/test_swarm_example.py
"""

import numpy as np


def test_the_swarm_moves_two_metres_north(swarm):
    with swarm(drones=4) as s:
        s.takeoff(altitude_m=3).wait()
        start = s.descriptors().true[:3]  # the true centre, NED m
        s.move(north_m=2).wait()
        end = s.descriptors().true[:3]
    assert np.allclose(end - start, [2.0, 0.0, 0.0], atol=0.15)
    report = s.report  # flight.tlog, events and plan as arrays
    assert ((-report.positions_ned_m[:, :, 2]).max(axis=0) > 2.8).all()  # each flew at 3 m
    assert report.metrics()["collisions"]["count"] == 0
