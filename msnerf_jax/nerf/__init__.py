"""NeRF primitives: cameras, rays, encodings, sampling, occupancy grids, volume rendering, regularizers and the one renderer of every field."""
