"""The mid-level task: the discrete action table, the feasibility filter, goals and rewards."""
