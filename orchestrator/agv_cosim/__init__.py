"""agv_cosim: the orchestrator that runs agv-cosim FMUs from experiment manifests."""

__version__ = "0.1.0"
