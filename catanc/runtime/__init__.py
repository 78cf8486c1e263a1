"""``catanc run`` and what measures with it: the protocol's enforcer end, Linux calls, run logs, the synthetic
worker, the enforcer, its compiled loop, and ``catanc profile``/``calibrate`` (docs/development.md, "Layout")."""
