"""Explaining a plan (``catanc explain``, PLAN.md) and listing a spec's chains and allocations."""
