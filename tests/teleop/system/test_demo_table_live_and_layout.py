"""``teleop demo``'s live status line (before, during and after a grasp; on a terminal or not) and the
closing table's layout: the bound marks, the alignment of its columns, its rule, its felt time."""

from __future__ import annotations

import io

from support.outcomes import outcome

from teleop.bus.messages import EstimateBody
from teleop.system.demo_table import LiveView, closing_table

RANGE_PA = (5e3, 6.75e6)
HEAD = f"[1/3] {'duck':<26}"


class _Terminal(io.StringIO):
    """An output that says it is a terminal."""

    def isatty(self) -> bool:
        return True


def _estimate(e_pa: float, state: str, *, provisional: bool) -> EstimateBody:
    return EstimateBody(grasp_id="g", method="auto", E_pa=e_pa, interval_pa=[None, None], state=state, reason="",
                        provisional=provisional, latency_s=0.0)


def test_the_live_line_says_simulating_then_grasping_before_the_first_estimate():
    waiting = outcome("duck", 1e6, None, None, None)
    view = LiveView(io.StringIO(), 3)
    assert view.line(1, waiting) == f"{HEAD} simulating"
    waiting.started = True
    assert view.line(1, waiting) == f"{HEAD} grasping"


def test_the_live_line_counts_the_estimates_and_names_the_newest_ones_kind_and_bound():
    going = outcome("duck", 1e6, None, None, None)
    going.started, going.estimates = True, 5
    going.latest = _estimate(1.2e6, "ok", provisional=True)
    view = LiveView(io.StringIO(), 3)
    assert view.line(1, going) == f"{HEAD}   5 estimates, provisional 1.2e+06 Pa (ok)"
    going.estimates, going.latest = 12, _estimate(2e9, "lower_bound", provisional=False)
    assert view.line(1, going) == f"{HEAD}  12 estimates, final >=2e+09 Pa (lower_bound)"
    going.latest = _estimate(1e3, "upper_bound", provisional=True)
    assert view.line(1, going) == f"{HEAD}  12 estimates, provisional <=1e+03 Pa (upper_bound)"


def test_the_done_line_gives_the_true_modulus_then_the_estimate():
    done = outcome("duck", 1e6, {"E_pa": 3e6, "state": "ok"}, 0.1, 150.0)
    done.robot_ended = done.estimator_ended = True
    line = LiveView(io.StringIO(), 3).line(1, done)
    assert line.startswith(f"{HEAD} E 1e+06 Pa -> 3e+06 Pa (ok), display -, felt - dec, ")


def test_an_upper_bound_shows_its_mark_in_the_table():
    soft = outcome("foam", 5e3, {"E_pa": 1e3, "state": "upper_bound"}, 0.1, 150.0)
    row = closing_table([soft]).splitlines()[2].split()
    assert row[:5] == ["foam", "script", "5e+03", "<=1e+03", "upper_bound"]


def test_on_a_terminal_the_line_is_rewritten_in_place_and_ends_with_a_newline():
    out = _Terminal()
    view = LiveView(out, 3)
    waiting = outcome("duck", 1e6, None, None, None)
    view.update(1, waiting)
    assert out.getvalue() == f"\r\033[K{HEAD} simulating"
    waiting.started = True
    view.update(1, waiting)
    view.finish(1, waiting)
    assert out.getvalue() == f"\r\033[K{HEAD} simulating\r\033[K{HEAD} grasping\r\033[K{HEAD} grasping\n"


def test_off_a_terminal_only_the_finished_line_is_printed():
    out = io.StringIO()
    view = LiveView(out, 3)
    waiting = outcome("duck", 1e6, None, None, None)
    view.update(1, waiting)
    assert out.getvalue() == ""
    view.finish(1, waiting)
    assert out.getvalue() == f"{HEAD} simulating\n"


def test_a_disabled_view_writes_nothing_even_on_a_terminal():
    for out in (_Terminal(), io.StringIO()):
        view = LiveView(out, 3, enabled=False)
        waiting = outcome("duck", 1e6, None, None, None)
        view.update(1, waiting)
        view.finish(1, waiting)
        assert out.getvalue() == "" and not view.tty


def _columns(rule: str) -> list[tuple[int, int]]:
    """The (start, end) of each column, from the rule under the header."""
    spans, start = [], 0
    for dashes in rule.split("  "):
        spans.append((start, start + len(dashes)))
        start += len(dashes) + 2
    return spans


def test_the_table_left_aligns_the_object_and_right_aligns_the_rest_under_a_rule_per_column():
    long_name = outcome("memory_foam_block", 2e4, {"E_pa": 3e4, "state": "ok"}, 0.1234, 15.0)
    short = outcome("oak", 1e10, {"E_pa": 2e9, "state": "lower_bound"}, 0.05, 1234.0)
    table = closing_table([long_name, short]).splitlines()
    header, rule, rows = table[0], table[1], table[2:4]
    assert set(rule) == {"-", " "} and "   " not in rule  # dashes per column, two spaces apart
    spans = _columns(rule)
    assert len(spans) == 10 and all(len(line) == len(rule) for line in (header, *rows))
    cells = [[line[a:b] for a, b in spans] for line in (header, *rows)]
    assert [row[0] for row in cells] == ["object".ljust(17), "memory_foam_block", "oak".ljust(17)]
    assert [row[1] for row in cells] == [" style", "script", "script"]
    assert [row[3] for row in cells] == ["final (Pa)", "     3e+04", "   >=2e+09"]
    assert [row[7] for row in cells] == ["first est. (ms)", "            123", "             50"]
    assert [row[9] for row in cells] == ["latency (ms)", "          15", "        1234"]
    assert all(line[b:b + 2] == "  " for line in (header, *rows) for _, b in spans[:-1])


def test_the_tables_felt_time_has_two_places():
    duck = outcome("duck", 1e6, {"E_pa": 1e6, "state": "ok"}, 0.1, 150.0, display_range=RANGE_PA)
    duck.t_contact_s, duck.display_track = 1.0, [(1.25, 9e5)]
    assert duck.t_felt_within_2x_s == 0.25
    header, rule, row = closing_table([duck]).splitlines()[:3]
    spans = _columns(rule)[-2:]
    assert [header[a:b] for a, b in spans] == ["felt 2x (s)", "latency (ms)"]
    assert [row[a:b].strip() for a, b in spans] == ["0.25", "150"]
