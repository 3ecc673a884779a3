"""The FMI side: the slave adapters (FMI 2.0 and 3.0), the pythonfmu work-arounds, the boot loader.

Only this package and the slave scripts may import pythonfmu / pythonfmu3; the component cores
and numerics never import it (tests/test_components.py reads the imports).
"""
