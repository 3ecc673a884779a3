"""The version of agv_cosim (the one pyproject.toml declares)."""

__version__ = "0.1.0"
