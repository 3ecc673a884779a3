"""Parameter defaults are written once, in the core; a slave script reads them from there.

A core states its defaults (with units) in its constructor's signature or as module
constants. A slave script declares each FMU parameter with the core's value,
``d = defaults_of(core.vehicle.vehicle.Vehicle)`` then ``self.parameter("x0", d["x0"],
...)``, so the slave, the core and the modelDescription.xml cannot drift apart; each
component README's parameter table is checked against the built FMU
(tests/components/test_components.py).
"""

import inspect
from collections.abc import Callable
from typing import Any


def defaults_of(*factories: Callable[..., Any]) -> dict[str, Any]:
    """Keyword defaults of the core classes or functions ``factories``, by parameter name.

    A name defined by several factories takes the first one's default.
    """
    defaults: dict[str, Any] = {}
    for factory in reversed(factories):
        defaults.update({name: p.default
                         for name, p in inspect.signature(factory).parameters.items()
                         if p.default is not inspect.Parameter.empty})
    return defaults
