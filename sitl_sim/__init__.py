"""The SITL simulator: vectorised 6-DOF quadcopter dynamics and each vehicle's inner loop."""
