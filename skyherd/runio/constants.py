"""skyherd's shared numbers, one home each: ports and their offsets, MAVLink identities, rates,
latencies and the autopilot limits the safety net certifies against. Everything reads them from
here (runio.ports adds the per-instance arithmetic; the parameter tables, the net and the
command line's defaults and help read the rest).
"""

from __future__ import annotations

# -- ports (CONVENTIONS.md "MAVLink endpoints": the PX4 SITL layout, a contract) ---------------
MAX_INSTANCE = 200  # the highest vehicle instance N (ports, system id 1+N <= 201)
API_BIND_BASE = 14580  # UDP, the vehicle's API / offboard link binds 14580+N
API_REMOTE_BASE = 14540  # UDP, ... and sends to the companion (MAVSDK) on 14540+N
GCS_BIND_BASE = 18570  # UDP, the vehicle's ground-station link binds 18570+N
GCS_REMOTE_PORT = 14550  # UDP, ... and sends to QGroundControl / MAVProxy on 14550 (any N)
PX4_SIM_BASE = 4560  # TCP, PX4 `-i N` connects its simulator_mavlink to 4560+N
JSON_BASE = 9002  # UDP, ArduPilot `-I N --model JSON` sends its servos to 9002+10N
JSON_STRIDE = 10  # ArduPilot's -I N moves every port by 10 N
ZENOH_BASE = 7447  # TCP, the simulator's Zenoh peer listens on 127.0.0.1:7447+N
MISSION_DRILL_INSTANCE = 85  # `skyherd drill --through mission`: the first vehicle instance
LOOPBACK = "127.0.0.1"  # every socket skyherd opens binds here unless a flag says otherwise
READY_FD_ENV = "SKYHERD_READY_FD"  # the fd a child of `fly` says "I take signals" on

# -- MAVLink identities (CONVENTIONS.md) -------------------------------------------------------
AUTOPILOT_COMPONENT = 1  # MAV_COMP_ID_AUTOPILOT1; the vehicle of instance N is system 1+N
COMPANION_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER: skyherd's companion beside an autopilot

# -- rates and latencies (simulation time) -----------------------------------------------------
CAMERA_HZ = 10.0  # camera frames per simulated second: the companion's tick
LOCKSTEP_LATENCY_S = 0.02  # the companion's declared compute latency L in lockstep [s]
PACE_S = 0.02  # a paced simulator sleeps once per this much simulation time [s]

# -- the autopilot limits the net certifies against --------------------------------------------
POS_SPEED_MAX_MPS = 12.0  # PX4 MPC_XY_VEL_MAX's default: the position-mode horizontal speed [m/s]

# -- Zenoh key expressions (CONVENTIONS.md "Zenoh") -----------------------------------------------
CLOCK_KEY = "skyherd/sim/clock"  # the simulation clock, one sample per camera instant

# -- safety evidence ----------------------------------------------------------------------------
TARGET_BOUND = 1e-3  # the breach probability a drill campaign is bounded against at 95 % [-]
