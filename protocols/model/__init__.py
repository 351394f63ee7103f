"""The swarm's model, shared by every role: frames and rotations, the descriptor vector and
the descriptors, the trajectory and when it runs, formation fit, geodesy. Pure."""
