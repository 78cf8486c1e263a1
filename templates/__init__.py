"""jinja2 templates of the deployment artifacts, shipped as package data."""
