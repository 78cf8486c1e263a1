"""Stage II: rates and per-core time fractions (catan-model.md section 4).

Work in progress (issue 4): :mod:`catanc.stage2.relaxed` is the relaxed
geometric program over all shared cores; the integer restoration of ``1/f``,
the planner and ``catanc explain`` build on it.
"""
