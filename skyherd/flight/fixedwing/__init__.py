"""Fixed-wing airframe: JSBSim physics (`jsbsim_model`) and its own autopilot (`autopilot`)."""
