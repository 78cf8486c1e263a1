"""Planning: Stage I (core allocation), Stage II (rates and time slices), the planner, re-planning, the baseline."""
