"""The runtime side of catanc: reading the runtime table, and (issue 6) the enforcer ``catanc run``."""
