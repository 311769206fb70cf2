"""Infrastructure under every layer: errors, atomic files, configs, checkpoints, run locks, progress, devices and processes."""
