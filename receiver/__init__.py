"""occloc receiver: frames in, LED IDs, distances and positions out."""

__version__ = "0.1.0"
