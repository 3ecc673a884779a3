"""Test FMU: one output of each FMI 2.0 type that changes every step, and typed echoes.

Outputs after k steps: ``r`` = 0.5 k (Real), ``i`` = 3 k - 7 (Integer), ``b`` = k odd
(Boolean), ``s`` = 'step k, "q"' (String: a comma and quotes, to test CSV quoting).
Inputs ``ri``, ``ii``, ``bi``, ``si`` are echoed (feedthrough) on ``ro``, ``io``, ``bo``,
``so``.
"""

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


class CounterCore:
    """Step counter; JSON-safe state."""

    def __init__(self):
        self.k = 0

    def get_state(self):
        return {"k": self.k}

    def set_state(self, state):
        self.k = int(state["k"])


class AgvTestTypes(core.fmi.fmi_slave.AgvSlave):
    """Typed source and echo for orchestrator tests."""

    description = "Test source of every FMI 2.0 type, and typed echoes"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        fs = core.fmi.fmi_slave
        self.input("ri", 0.0, "1", "Real input")
        self.input("ii", 0, None, "Integer input", kind=fs.Integer)
        self.input("bi", False, None, "Boolean input", kind=fs.Boolean)
        self.input("si", "", None, "String input", kind=fs.String)
        self.output("r", "1", "0.5 k")
        self.output("i", None, "3 k - 7", kind=fs.Integer, start=-7)
        self.output("b", None, "k is odd", kind=fs.Boolean, start=False)
        self.output("s", None, "step k, \"q\"", kind=fs.String, start='step 0, "q"')
        self.output("ro", "1", "echo of ri", depends_on=("ri",))
        self.output("io", None, "echo of ii", depends_on=("ii",), kind=fs.Integer, start=0)
        self.output("bo", None, "echo of bi", depends_on=("bi",), kind=fs.Boolean,
                    start=False)
        self.output("so", None, "echo of si", depends_on=("si",), kind=fs.String, start="")

    def make_core(self):
        return CounterCore()

    def advance(self, t, h):
        self.core.k += 1

    def publish(self):
        k = self.core.k
        self.r, self.i, self.b, self.s = 0.5 * k, 3 * k - 7, k % 2 == 1, f'step {k}, "q"'
        self.ro, self.io, self.bo, self.so = float(self.ri), int(self.ii), bool(self.bi), \
            str(self.si)
