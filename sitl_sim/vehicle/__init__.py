"""Each simulated vehicle's autopilot, pure: modes, arming, guidance, failsafe, setpoint
checks, battery, tunables, the ArduCopter flight core, and the world of N vehicles."""
