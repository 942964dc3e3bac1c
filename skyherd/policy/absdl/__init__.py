"""ABS-DL: Apprenticeship Bootstrapping via deep learning with a safety net (report ref [15]).

Continuous velocity actions in the GroundAir task (env), a scripted PD demonstrator with
human-like noise, delay and error (demonstrator), demonstrations with optional DAgger rounds
(demos), the flown SafetyNet certifying every training action (shield), one torch MLP per
sub-task fused into the composite policy by relevance gating plus a composite-demonstration
baseline (mlp, policy, train), evaluation and the run folder's report (evaluate, report).
Flying needs only numpy: policy.load_policy reads the `.npz` (format skyherd-absdl-policy/1).
"""
