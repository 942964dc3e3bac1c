"""The ground-air task that the world simulates, the companion flies and the learners train on:
its parameters (params: the UAV's limits, the camera, the team), the UGV team's scenarios
(scenarios), φ's fast geometric path (fastphi) and the policy's observation (observation).

Layer 1: numpy only, no learner and no gymnasium, so `skyherd sim` and `skyherd companion`
import it without importing a learner.
"""
