"""The Gauss-Seidel schedule of a system: the components in topological order of the
direct-feedthrough graph (:mod:`graphlib`); an algebraic loop is refused, its cycle named."""

import graphlib
import heapq
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..errors import ManifestError
from ..manifest import Connection
from .model import ModelInfo

__all__ = ["feedthrough_order"]


def feedthrough_order(models: dict[str, ModelInfo], connections: Sequence[Connection],
                      manifest_path: str | Path = "manifest",
                      algorithm: str = "gauss-seidel") -> list[str]:
    """Gauss-Seidel order of the components, or raise on an algebraic loop.

    Parameters
    ----------
    models : dict
        Instance name -> :class:`~agv_cosim.model.ModelInfo`.
    connections : list of Connection
    manifest_path : path
        For the messages.
    algorithm : {"gauss-seidel", "jacobi"}
        Jacobi needs no order: components that feed each other without a variable loop
        are then accepted (in manifest order); an algebraic loop is refused for both.

    Returns
    -------
    list of str
        Instance names in topological order of the direct-feedthrough graph: an edge
        A -> B exists when a connection runs from an output of A that depends directly
        on an input of A to an input of B. Ties keep the manifest's order.
    """
    # variable-level graph: input -> feedthrough output (inside an FMU), output -> input;
    # graphlib takes each node with its predecessors, so a reported cycle runs forwards
    variables: graphlib.TopologicalSorter[tuple[str, str]] = graphlib.TopologicalSorter()
    for cname, info in models.items():
        for out, deps in info.dependencies.items():
            for inp in deps:
                variables.add((cname, out), (cname, inp))
    for conn in connections:
        variables.add(conn.target, conn.source)
    try:
        variables.prepare()
    except graphlib.CycleError as error:
        loop = " -> ".join(".".join(v) for v in _rotated(error.args[1]))
        raise ManifestError(manifest_path, "connections",
                            f"algebraic loop (a cycle of direct feedthrough): {loop}") from None
    names = list(models)
    components: graphlib.TopologicalSorter[str] = graphlib.TopologicalSorter(
        {n: set() for n in names})
    for conn in connections:
        src, dst = conn.source[0], conn.target[0]
        if models[src].dependencies.get(conn.source[1]) and src != dst:
            components.add(dst, src)
    try:
        components.prepare()
    except graphlib.CycleError as error:
        if algorithm == "jacobi":  # Jacobi needs no order: every FMU reads, then sets
            return names
        cycle = " -> ".join(_rotated(error.args[1], key=names.index))
        raise ManifestError(manifest_path, "connections",
                            f"components {cycle} feed each other through feedthrough "
                            "outputs (no algebraic loop between variables, but a single "
                            "Gauss-Seidel pass cannot order them); use algorithm = 'jacobi'"
                            ) from None
    # ties keep the manifest's order: always take the first ready component (a heap of
    # manifest positions: linear-logarithmic in the number of components)
    position = {name: i for i, name in enumerate(names)}
    order: list[str] = []
    ready: list[int] = []
    while components.is_active():
        for node in components.get_ready():
            heapq.heappush(ready, position[node])
        node = names[heapq.heappop(ready)]
        order.append(node)
        components.done(node)
    return order


def _rotated(cycle: Sequence[Any], key: Callable[[Any], Any] | None = None) -> list[Any]:
    """A cycle ``[a, b, ..., a]`` started at its smallest node (a stable message)."""
    ring = list(cycle[:-1])
    first = ring.index(min(ring, key=key) if key is not None else min(ring))
    ring = ring[first:] + ring[:first]
    return ring + ring[:1]
