"""Numerics shared by the component cores: angles, finite checks, sample-and-hold, path
geometry (FMI-free).
"""
