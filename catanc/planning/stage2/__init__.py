"""Stage II: rates and per-core time fractions (docs/explanation/model.md section 4).

:mod:`catanc.planning.stage2.relaxed` is the relaxed geometric program over all shared
cores (cvxpy, DPP), with a twin that minimises the bound scale;
:mod:`catanc.planning.stage2.integer` restores whole runs ``1/f`` exactly by branch and
bound on it. :mod:`catanc.planning.planner` puts Stage I and Stage II together.
"""
