"""The planar RRR+P arm: its Denavit–Hartenberg model, MJCF scene and scenarios."""
