"""``catanc bench``: catanc's plan against the hand-tuned baselines on the real kernel.

The same comparison as ``catanc simulate`` (:mod:`catanc.simulate`), measured
instead of simulated: synthetic worker processes (:mod:`catanc.runtime.worker`)
burn CPU as the spec's workload model says, once under the real enforcer
(:mod:`catanc.runtime.enforcer`) and once per baseline under a small trigger
driver; every run's timestamps are then replayed through the simulator's
dataflow and metrics, so both commands report the same figures.

- :mod:`catanc.bench.triggers`: the baselines' trigger rules (pure);
- :mod:`catanc.bench.driver`: the baselines' side of the protocol (I/O);
- :mod:`catanc.bench.replay`: records -> :class:`~catanc.simulate.metrics.PolicyResult` (pure);
- :mod:`catanc.bench.run`: one run per policy: workers, enforcer or driver, clean-up.
"""
