"""The runtime decisions shared by the enforcer and the simulator: the runtime schedule and runs in flight."""
