"""The spec language: its pydantic models, YAML with source positions, and loading text into a Spec."""
