"""The planning problem a spec states, and the analytic model over it (catan-model.md sections 1, 2, 4)."""
