"""Run kinds: the registry (config class, params, field and renderer of each kind), run folders and per-kind view rendering."""
