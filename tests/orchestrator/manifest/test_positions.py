"""agv_cosim.manifest.load.key_lines / line_of: the line of a dotted key in a TOML text."""

from agv_cosim.manifest.load import key_lines, line_of

TEXT = """\
name = "m"            # 1
# a comment           # 2
[simulation]          # 3
stop = 1.0            # 4
"step" = 0.1          # 5

[components.veh]      # 7
fmu = "v.fmu"
parameters = { wheelbase = 2.0 }
[[connections]]       # 10
from = "a.x"
to = "b.u"
[[connections]]       # 13
from = "a.y"
to = "b.v"            # 15
[sweep]
"veh.wheelbase" = [1.0, 2.0]
[ montecarlo . parameters ]   # 18
"veh.v0" = { distribution = "normal", mean = 1.0, std = 0.1 }
record.interval = 0.2  # 20: a dotted key inside [montecarlo.parameters]
"""


def test_headers_and_keys_are_found_by_their_dotted_key():
    lines = key_lines(TEXT)
    assert lines["name"] == 1
    assert lines["simulation"] == 3 and lines["simulation.stop"] == 4
    assert lines["simulation.step"] == 5
    assert lines["components.veh"] == 7 and lines["components.veh.parameters"] == 9
    assert lines["connections[0]"] == 10 and lines["connections[0].to"] == 12
    assert lines["connections[1]"] == 13 and lines["connections[1].to"] == 15
    assert lines["sweep.veh.wheelbase"] == 17
    assert lines["montecarlo.parameters"] == 18
    assert lines["montecarlo.parameters.veh.v0"] == 19
    assert lines["montecarlo.parameters.record.interval"] == 20
    assert "# a comment" not in "".join(lines)


def test_a_key_not_written_is_placed_at_its_closest_enclosing_key():
    lines = key_lines(TEXT)
    assert line_of(lines, "simulation.algorithm") == 3  # missing: its table's header
    assert line_of(lines, "components.veh.parameters.wheelbas") == 9  # in an inline table
    assert line_of(lines, "connections[1].from") == 14
    assert line_of(lines, "connections") == 10  # a whole array of tables: its first
    assert line_of(lines, "montecarlo") == 18  # a table written only by its sub-tables
    assert line_of(lines, "record.variables") is None
    assert line_of(lines, "--set") is None
