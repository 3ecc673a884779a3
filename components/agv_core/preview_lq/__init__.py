"""Seed-004 preview + LQ path-tracking controller: core preview_lq.py, FMU AgvPreviewLq."""
