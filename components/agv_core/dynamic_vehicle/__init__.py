"""Dynamic single-track vehicle with tyre forces: core dynamic_vehicle.py, tyre laws
tyres.py, FMU AgvDynamicVehicle."""
