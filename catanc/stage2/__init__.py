"""Stage II: rates and per-core time fractions (catan-model.md section 4).

Work in progress (issue 4). Done: :mod:`catanc.stage2.relaxed`, the relaxed
geometric program over all shared cores (cvxpy, DPP), and
:mod:`catanc.stage2.integer`, the exact integer restoration of ``1/f`` by
branch and bound on it. To come: the smallest bound scale for the integer
problem, the planner (Stage I's next-best allocations under Stage II), the
public API, ``catanc explain``, and a faster runtime re-solve path.
"""
