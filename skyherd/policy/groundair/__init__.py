"""The GroundAir task: one UAV keeps a team of UGVs in its downward camera's view."""
