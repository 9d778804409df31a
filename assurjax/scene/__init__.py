"""Scene files (TOML): a mechanism, its loads, initial state, solver settings and outputs."""
