"""The enforcer's compiled loop: the shared cores' walk in numba, its arrays, its build, and loading it."""
