"""Applications: the one-command pipeline, the demo and the render videos."""
