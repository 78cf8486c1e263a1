"""Measuring from runs: ``catanc profile`` (compute profiles and hops from a log) and ``catanc calibrate`` (the
enforcer's costs)."""
