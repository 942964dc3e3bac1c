"""The multirotor controller's flat arrays, by index: the setpoints sp, the controller's
constants c and memory cs (control.py's kernels), and the packed work array w and constant
array k the autopilot hands to one compiled step. Plain numbers, no numba: the autopilot
(multirotor.autopilot) fills these arrays without importing the kernels, which it may run
compiled ahead of time (multirotor.compiled)."""

from __future__ import annotations

from skyherd.flight.quadrotor import N_AUX, N_P, N_X

# ---- setpoint array sp (written by the mode logic each control step)
SP_POS = 0  # (3,) [m] NED
SP_VEL = 3  # (3,) [m/s] velocity setpoint (velocity axes) or feed-forward (position axes)
SP_YAW = 6  # [rad]
SP_YAWRATE = 7  # [rad/s] feed-forward
SP_XY_MODE = 8  # XY_POS | XY_VEL | XY_ATT
SP_Z_MODE = 9  # Z_POS | Z_VEL | Z_THRUST
SP_ROLL = 10  # [rad] for XY_ATT
SP_PITCH = 11  # [rad] for XY_ATT
SP_THRUST = 12  # [N] collective for Z_THRUST
SP_ARMED = 13  # 1.0 armed, 0.0 motors off
SP_VXY_MAX = 14  # [m/s] horizontal speed limit of this mode
SP_VZ_UP = 15  # [m/s] climb limit (positive)
SP_VZ_DN = 16  # [m/s] descent limit (positive)
N_SP = 17
XY_POS, XY_VEL, XY_ATT = 0.0, 1.0, 2.0
Z_POS, Z_VEL, Z_THRUST = 0.0, 1.0, 2.0

# ---- controller constants c (built from the parameters)
C_KP_XY, C_KP_Z, C_KV_XY, C_KI_XY, C_KV_Z, C_KI_Z = 0, 1, 2, 3, 4, 5
C_TILT_MAX = 6  # [rad]
C_VINT_MAX = 7  # [m/s^2] velocity integrator limit
C_KATT = 8  # (3,) [1/s]
C_RATE_MAX = 11  # (3,) [rad/s]
C_KRP = 14  # (3,) [1/s]
C_KRI = 17  # (3,) [1/s^2]
C_KRD = 20  # (3,) [-]
C_RINT_MAX = 23  # [rad/s^2] rate integrator limit
C_T_MIN = 24  # [N] minimum collective in flight
C_T_MAX = 25  # [N] maximum collective
C_T_IDLE = 26  # [N] per-rotor thrust at idle (armed)
C_T_ROTOR_MAX = 27  # [N] per-rotor thrust at command 1
C_MASS = 28  # [kg] mass the controller assumes
C_MIX = 29  # (16,) allocation inverse, row-major
C_VINT_ERR = 45  # [m/s] velocity error the integrators see is clipped to this
C_DRAG_LIN = 46  # (2,) [N s/m] horizontal, vertical drag estimate (× MPC_DRAG_FF)
C_DRAG_QUAD = 48  # (2,) [N s^2/m^2]
C_WDRAG_LIN = 50  # (2,) [N s/m] body x, y drag the wind estimator inverts (airframe's)
C_WDRAG_QUAD = 52  # (2,) [N s^2/m^2]
C_WIND_TAU = 54  # [s] wind estimate low-pass time constant
C_WIND_FF_MIN = 55  # [m/s] wind estimate below this is not fed forward
N_C = 56

# ---- controller memory cs
CS_VINT = 0  # (3,) [m/s^2]
CS_RINT = 3  # (3,) [rad/s^2]
CS_PREV_OMEGA = 6  # (3,)
CS_F = 9  # (3,) thrust vector setpoint [N], NED
CS_QSP = 12  # (4,) attitude setpoint
CS_RATE_SP = 16  # (3,)
CS_U = 19  # (4,) last motor commands
CS_SAT = 23  # last mixer flags
CS_T = 24  # last collective [N]
CS_TAU = 25  # (3,) last torque setpoint [N m], body FRD
CS_WORK = 28  # (12,) mixer scratch
CS_WIND = 40  # (2,) [m/s] the wind estimate ŵ (north, east)
N_CS = 42

# ---- packed form: one work array w and one constant array k (fewer arguments per call)
W_X = 0
W_AUX = W_X + N_X
W_CS = W_AUX + N_AUX
W_SP = W_CS + N_CS
W_U = W_SP + N_SP
N_W = W_U + 4
K_P = 0
K_C = N_P
N_K = N_P + N_C
