"""Aerial shepherding (the report's ref [16]): a UAV herds a UGV flock (groundsim.flock) into a
goal region. `rules`: Strömbom's collect and drive sub-skills; `selector`: the high-level choice
between them, hand-written (Strömbom's rule) or learned from the rule's demonstrations;
`episode`: one herding episode with a point shepherd; `study`: success rate and time to goal
over many seeds (`python -m skyherd.policy.shepherd.study`). docs/shepherding.md."""
