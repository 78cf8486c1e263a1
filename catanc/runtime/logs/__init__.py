"""``catanc run``'s JSON-lines log, the compute samples in it, and ``catanc report``."""
