"""The quadcopter's physics: parameters, the per-vehicle rules written once (attitude
controller, mixer, rotor wrench, rigid body, ground contact) and their compiled kernel."""
