"""Seed 003's three-car train with tyre forces (planar multibody): core dynamic_train.py,
FMU AgvDynamicTrain."""
