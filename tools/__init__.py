"""Offline tools: synthetic camera, recordings, hardware-in-the-loop."""
