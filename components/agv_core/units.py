"""The physical units used by agv-cosim, as FMI 2.0 unit definitions.

Every Real variable of every FMU names one of these. Exponents are SI base units
(kg, m, s, A) plus rad, as FMI 2.0 ``<BaseUnit>`` allows.
"""

#: unit name -> dict of FMI ``BaseUnit`` attributes (exponents, and factor where not 1)
UNITS = {
    "1": {},
    "m": {"m": 1},
    "rad": {"rad": 1},
    "s": {"s": 1},
    "m/s": {"m": 1, "s": -1},
    "m/s2": {"m": 1, "s": -2},
    "rad/s": {"rad": 1, "s": -1},
    "1/m": {"m": -1},
    "1/m2": {"m": -2},
    "1/s": {"s": -1},
    "V": {"kg": 1, "m": 2, "s": -3, "A": -1},
    "V/rad": {"kg": 1, "m": 2, "s": -3, "A": -1, "rad": -1},
    "V/m": {"kg": 1, "m": 1, "s": -3, "A": -1},
    "rad/(V.s)": {"kg": -1, "m": -2, "s": 2, "A": 1, "rad": 1},
    "rad/(V.s2)": {"kg": -1, "m": -2, "s": 1, "A": 1, "rad": 1},
    "rad/(V.s3)": {"kg": -1, "m": -2, "A": 1, "rad": 1},
    "1/s2": {"s": -2},
    "rad/s/rad": {"s": -1},
    "rad/m": {"rad": 1, "m": -1},
    "m.s": {"m": 1, "s": 1},
    "rad/(s.m)": {"rad": 1, "s": -1, "m": -1},
    "rad/(s2.m)": {"rad": 1, "s": -2, "m": -1},
    "rad.s/m": {"rad": 1, "s": 1, "m": -1},
    "kg": {"kg": 1},
    "kg.m2": {"kg": 1, "m": 2},
    "N": {"kg": 1, "m": 1, "s": -2},
    "N/rad": {"kg": 1, "m": 1, "s": -2, "rad": -1},
    "1/rad": {"rad": -1},
}


def base_unit_attributes(unit: str) -> dict[str, str]:
    """Return the FMI ``BaseUnit`` attributes of ``unit`` as strings.

    Raises
    ------
    KeyError
        If ``unit`` is not defined here.
    """
    return {key: str(value) for key, value in UNITS[unit].items()}
