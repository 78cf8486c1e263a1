"""The planning problem a spec states, and the analytic model over it (docs/explanation/model.md sections 1, 2, 4)."""
