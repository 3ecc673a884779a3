"""Seed-000 state-feedback steering controller: core state_feedback.py, FMU AgvStateFeedback."""
