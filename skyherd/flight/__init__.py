"""Vehicle dynamics, onboard autopilots and the vehicle's own MAVLink endpoint.

Frames: world is local NED about home, body is FRD, quaternions (w, x, y, z) body→world.
Everything is SI; degrees only at the MAVLink boundary.
"""
