"""``catanc run``'s enforcer: its loop, the app's nodes and processes, the shared cores' walk in Python, runs in
flight, re-plans."""
