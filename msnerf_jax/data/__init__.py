"""Scene and image loading."""
