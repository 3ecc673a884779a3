"""Test FMU: variables named as FMI allows and CSV and dotted references do not expect.

Outputs ``body.frame_a.r_0[1]`` (Modelica style: dots and brackets), ``a,b`` (a comma),
``say "hi"`` (quotes) and ``x'[2,3]`` (a quote, brackets, a comma), each k times its own
factor after k steps; a parameter ``gain.k`` (a dot in a parameter name) scales them all; the
input ``in.u[1]`` is echoed on ``echo.y``. A parameter ``inf_ok`` with max = INF and one
``nan_ok`` whose start value is NaN declare those values legal.
"""

import math

from agv_boot import load_core

core = load_core("fmi.fmi_slave")

NAMES = {"body.frame_a.r_0[1]": 1.0, "a,b": 2.0, 'say "hi"': 3.0, "x'[2,3]": 4.0}


class AgvTestNames(core.fmi.fmi_slave.AgvSlave):
    """Counter outputs under odd names."""

    description = "Test FMU with variable names holding dots, brackets, commas, quotes"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.parameter("gain.k", 1.0, "1", "Scale of every output")
        self.parameter("inf_ok", 0.0, "1", "A parameter whose max is INF")
        self.parameter("nan_ok", math.nan, "1", "A parameter whose start value is NaN")
        self.input("in.u[1]", 0.0, "1", "Input echoed on echo.y")
        for name in NAMES:
            self.output(name, "1", f"k times {NAMES[name]!r}")
        self.output("echo.y", "1", "Copy of in.u[1]", depends_on=("in.u[1]",))

    def _variable(self, kind, name, causality, variability, description, unit):
        # plain attributes named as the variables (pythonfmu would read "a.b" as self.a.b)
        variable = super()._variable(kind, name, causality, variability, description, unit)
        variable.getter = lambda: getattr(self, name)
        variable.setter = lambda value: setattr(self, name, value)
        return variable

    def make_core(self):
        return {"k": 0}

    def advance(self, t, h):
        self.core["k"] += 1

    def publish(self):
        scale = getattr(self, "gain.k")
        for name, factor in NAMES.items():
            setattr(self, name, scale * factor * (self.core["k"] if self.core else 0))
        setattr(self, "echo.y", getattr(self, "in.u[1]"))

    def to_xml(self, model_options=None):
        root = super().to_xml(model_options)
        root.set("variableNamingConvention", "flat")  # any name is legal
        for scalar in root.iter("ScalarVariable"):
            if scalar.get("name") == "inf_ok":
                scalar[0].set("max", "INF")
            elif scalar.get("name") == "nan_ok":
                scalar[0].set("start", "NaN")  # XML Schema's spelling
        return root
