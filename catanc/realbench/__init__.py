"""``catanc bench``: catanc's plan against the hand-tuned baselines on the real kernel.

The same comparison as ``catanc simulate`` (:mod:`catanc.sim`), measured
instead of simulated: synthetic worker processes (:mod:`catanc.runtime.worker`)
burn CPU as the spec's workload model says, once under the real enforcer
(:mod:`catanc.runtime.enforcer.run`) and once per baseline under a small trigger
driver; every run's timestamps are then replayed through the simulator's
dataflow and metrics, so both commands report the same figures.

- :mod:`catanc.control.timers`: the baselines' trigger rules (pure);
- :mod:`catanc.realbench.driver`: the baselines' side of the protocol (I/O);
- :mod:`catanc.realbench.replay`: records -> :class:`~catanc.sim.metrics.PolicyResult` (pure);
- :mod:`catanc.realbench.bench`: one run per policy: workers, enforcer or driver, clean-up.
"""
