"""The output folder: the runtime table, the deployment, the emitted files, and writing or checking them."""
