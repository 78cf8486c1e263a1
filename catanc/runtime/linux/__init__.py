"""Linux calls for the enforcer: scheduling policies, levels and CPUs, thread clocks, the watchdog."""
