"""Training loops: shared machinery and one module per task."""
