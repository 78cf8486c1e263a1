"""The enforcer's end of the trigger protocol: its messages, the nodes' rings, the socket (the node's end:
catanc/client.py)."""
