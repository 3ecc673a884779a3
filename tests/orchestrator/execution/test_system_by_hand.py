"""The execution stage on its own: Systems built by hand from the test FMUs' model
descriptions (no manifest, no plan, no command line), run by
``agv_cosim.execution.simulate``.

The loop is an integrator x' = u (no direct feedthrough; exact for an input held over a
step: x_{n+1} = x_n + h u_n) and a gain y = k u (direct feedthrough), wired
integ.y -> gain.u -> gain.y -> integ.u, so that the integrator is fed k times its own
past output:

- Gauss-Seidel (gain first, the integrator's output read at the start of each pass):
  u_n = k x_n, so x_n = (1 + h k)^n x_0 and the recorded gain.y is k x_n;
- Jacobi (every output read, then every input set): the gain's output seen by the
  integrator at t_n was computed from x_{n-1}, so x_{n+1} = x_n + h k x_{n-1} for n >= 1,
  and x_1 = (1 + h k) x_0 (the exchanges in initialisation mode give the gain x_0 before
  the first step). Its closed form is x_n = A r1^n + B r2^n with r1, r2 the roots of
  r^2 = r + h k and A, B from x_0 and x_1; the recorded gain.y is k x_{n-1} (k x_0 at t_0).

With h = 0.1, k = -2, x_0 = 1 the two differ from the second step on (0.64 against 0.6).
Both are checked on the reference loops and on the fast path (``fast=True``: generated or
compiled step functions, the same calls), as are the observers (what each is given) and
events written as :class:`~agv_cosim.system.Event` values.
"""

import math

import pytest

from agv_cosim.execution import Observer, simulate
from agv_cosim.manifest import Connection
from agv_cosim.system import Event, System, feedthrough_order, read_model

H, K, X0, STEPS = 0.1, -2.0, 1.0, 10


def loop_system(fmus, algorithm, record_every=1):
    """The integrator-gain loop as a System, written out field by field."""
    models = {"gain": read_model(fmus["agv_test_gain"]),
              "integ": read_model(fmus["agv_test_integrator"])}
    connections = [Connection(("integ", "y"), ("gain", "u"), "connections[0]"),
                   Connection(("gain", "y"), ("integ", "u"), "connections[1]")]
    return System(models=models, parameters={"gain": {"k": K}, "integ": {"y0": X0}},
                  connections=connections,
                  order=["gain", "integ"],  # gain.y depends directly on gain.u
                  record=["integ.y", "gain.y"], start=0.0, stop=STEPS * H, step=H,
                  algorithm=algorithm, record_every=record_every, steps=STEPS)


def gauss_seidel_x(n):
    return (1 + H * K) ** n * X0


def jacobi_x(n):
    """x_n of x_{n+1} = x_n + h k x_{n-1}, x_1 = (1 + h k) x_0, in closed form."""
    root = math.sqrt(1 + 4 * H * K)
    r1, r2 = (1 + root) / 2, (1 - root) / 2
    x1 = (1 + H * K) * X0
    a = (x1 - r2 * X0) / (r1 - r2)
    return a * r1 ** n + (X0 - a) * r2 ** n


class Recording(Observer):
    """Keeps a copy of every row it is given, the row objects themselves, and every
    progress count."""

    def __init__(self):
        self.rows, self.objects, self.counts = [], [], []

    def row(self, row):
        self.rows.append(list(row))
        self.objects.append(row)

    def steps(self, count):
        self.counts.append(count)


def test_the_hand_written_order_is_the_systems(fmus):
    """The premise of ``loop_system``'s order: the feedthrough order puts the gain first
    (listed second here, so that the order is not just the listing's)."""
    system = loop_system(fmus, "gauss-seidel")
    models = {"integ": system.models["integ"], "gain": system.models["gain"]}
    assert feedthrough_order(models, system.connections) == system.order == ["gain", "integ"]


@pytest.mark.parametrize("fast", [False, True])
def test_gauss_seidel_follows_the_loops_recurrence(fmus, fast):
    seen = Recording()
    outcome = simulate(loop_system(fmus, "gauss-seidel"), [seen], fast=fast)
    assert outcome.rows == STEPS + 1 and outcome.ended_by is None
    assert [r[0] for r in seen.rows] == [n / 10 for n in range(STEPS + 1)]
    for n, (_, x, y) in enumerate(seen.rows):
        assert x == pytest.approx(gauss_seidel_x(n), rel=1e-13), n
        assert y == pytest.approx(K * gauss_seidel_x(n), rel=1e-13), n


@pytest.mark.parametrize("fast", [False, True])
def test_jacobi_follows_the_loops_delayed_recurrence(fmus, fast):
    seen = Recording()
    outcome = simulate(loop_system(fmus, "jacobi"), [seen], fast=fast)
    assert outcome.rows == STEPS + 1 and outcome.ended_by is None
    assert [r[0] for r in seen.rows] == [n / 10 for n in range(STEPS + 1)]
    for n, (_, x, y) in enumerate(seen.rows):
        assert x == pytest.approx(jacobi_x(n), rel=1e-12), n
        assert y == pytest.approx(K * jacobi_x(max(n - 1, 0)), rel=1e-12), n
    # the two algorithms part at the second step: 0.64 against 0.6
    assert seen.rows[2][1] == pytest.approx(0.6, rel=1e-14)
    assert gauss_seidel_x(2) == pytest.approx(0.64, rel=1e-14)


@pytest.mark.parametrize("fast", [False, True])
def test_an_observer_is_given_each_recorded_row_and_the_progress(fmus, fast):
    """record_every 3 of 10 steps: rows at steps 0, 3, 6, 9 and the stop (10), each the
    same list object overwritten (a keeper copies it); the progress: 10 steps, told at
    the end (it is told every 1000)."""
    seen, other = Recording(), Recording()
    outcome = simulate(loop_system(fmus, "gauss-seidel", record_every=3), [seen, other],
                       fast=fast)
    kept = [0, 3, 6, 9, 10]
    assert outcome.rows == len(kept)
    assert [r[0] for r in seen.rows] == [n / 10 for n in kept]
    for n, (_, x, y) in zip(kept, seen.rows):
        assert x == pytest.approx(gauss_seidel_x(n), rel=1e-13), n
        assert y == pytest.approx(K * gauss_seidel_x(n), rel=1e-13), n
    assert other.rows == seen.rows
    assert all(row is seen.objects[0] for row in seen.objects + other.objects)
    assert seen.counts == other.counts == [STEPS]


def test_an_observer_that_fails_ends_the_run_with_its_own_error(fmus):
    """An observer's exception (a full disk, say) is the caller's, not an FMU's: it
    leaves simulate unchanged, after the rows before it."""
    full = OSError(28, "No space left on device")

    class FullDisk(Recording):
        def row(self, row):
            if len(self.rows) == 4:
                raise full
            super().row(row)

    seen = FullDisk()
    with pytest.raises(OSError) as raised:
        simulate(loop_system(fmus, "jacobi"), [seen])
    assert raised.value is full
    assert [r[0] for r in seen.rows] == [0.0, 0.1, 0.2, 0.3]


@pytest.mark.parametrize("fast", [False, True])
def test_events_by_hand_set_an_unconnected_input_at_their_points(fmus, fast):
    """The integrator alone, its input set by two events: u = 1 at t_0 and u = -3 at t_4,
    so x_n = x_0 + h n up to n = 4 and x_0 + 4 h - 3 h (n - 4) after (the recorded u shows
    each value from its own point on)."""
    events = [Event(k=0, at=0.0, name="on", sets=(("integ", "u", 1.0),)),
              Event(k=4, at=0.4, name="back", sets=(("integ", "u", -3.0),))]
    system = System(models={"integ": read_model(fmus["agv_test_integrator"])},
                    parameters={"integ": {"y0": X0}}, connections=[], order=["integ"],
                    record=["integ.y"], start=0.0, stop=STEPS * H, step=H,
                    algorithm="gauss-seidel", record_every=1, steps=STEPS, events=events)
    seen = Recording()
    simulate(system, [seen], fast=fast)
    expected = [X0 + H * n if n <= 4 else X0 + 4 * H - 3 * H * (n - 4)
                for n in range(STEPS + 1)]
    assert [r[1] for r in seen.rows] == pytest.approx(expected, rel=1e-13, abs=1e-15)
