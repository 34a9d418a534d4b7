"""The operator console: a terminal UI (textual) over :class:`~haptics.operator_loop.OperatorLoop`.

It runs over SSH and in tmux, with the keyboard alone. The loop runs in its own thread (it
sends ``follow`` at 50 Hz and must not wait for the screen); the screen redraws from the loop's
frozen :class:`~haptics.operator_status.LoopStatus` ten times a second. Panels:

* **live system**: whether the robot node, the estimator and the display's renderer are alive
  (heard from within three heartbeat periods) and when each was last heard; WAIT for a robot node
  heard whose subscription to the console's commands has not arrived (they are refused meanwhile);
* **grasp**: its id and object, its phase (loading, loaded, ended), the robot's mode and target
  width, the force (N, with a bar up to the settings' maximum), the fingers' width, and the label
  the operator gave it;
* **estimate**: the grasp's newest estimate: E with its interval, its state (a bound reads
  ``E >= ...``), provisional or final, and the estimator's reason (cut to fit a short terminal),
  and that it is not current while the estimator is down;
* **display**: what the softness display renders: the fraction of its range and the modulus it
  stands for, rigid or unknown, the level written of its full scale, and how many decades wide the
  estimate's interval is on the display's range (its whole width, not a +/-);
* **operator**: the input device, the grip as a bar and the target width it asks for, the
  dead-man enable, the mode (follow, discrete grasp, idle), the discrete grasp's force;
* **notices**: what went wrong on this side (a send that failed) first, then the robot's last
  notice (a refused command, the watchdog), the one that ended the grasp (the watchdog's, a
  failed gripper command's) kept above a later refusal, the
  operator's last actions, newest first, and the last warning logged (a refused CURVE handshake,
  say: the log itself is held until the screen closes); cut to the panel's rows, ending in ``…``;
* the **keys**, at the bottom. The whole fits an 80x24 terminal; in a smaller one, where panels
  are cut off, a line at the top says so and shows the dead-man enable and the mode.

With the keyboard, the console turns the enable toggle off when the loop suspends the follows
(after ``next``, the robot's end of the grasp), so the screen shows the toggle as it is and one
``e`` drives again.

Keys: with ``--input keyboard`` every key goes to the keyboard input device
(:mod:`haptics.inputs.keyboard`: up/down squeeze and open, e toggles the enable, g r s n q are the
buttons). With the other inputs the device drives the grip and enable, and g r s n q still work
as the buttons from the keyboard. Always: ``+``/``-`` change the discrete grasp's force by 1 N
(up to the settings' maximum), ctrl+c and ctrl+q quit, and ``l`` labels a grasp. s r e q act
whatever has the focus, except in the open label line (textual's command palette is off: its
search box would take them as typing).

Labelling: ``l`` opens a line under the panels, in place of the keys' legend, for the grasp shown
(after ``n``, the last one): type the object's catalogue name (the right arrow takes the
suggestion), or a name with a Shore reading (``blue gel shore 00 60``, ``pad shore A 40``) or a
stated modulus (``cork mat 12 MPa``, ``... measured``), as :func:`teleop.labels.parse_label` reads
them; enter sends the ``label`` (the loop publishes it on ``bus.command``, where ``teleop record``
logs it), escape closes the line.
A reading out of range or an unknown name is shown on the line, which stays open. While it is
open, keys go to the line, not to the keyboard input device (ctrl+c still quits).
"""

from __future__ import annotations

import logging
import math
import textwrap
import threading
from collections.abc import Sequence
from typing import Any

from rich.text import Text
from textual import events
from textual.app import App, ComposeResult
from textual.binding import Binding
from textual.containers import Horizontal
from textual.suggester import SuggestFromList
from textual.widgets import Input, Static

from haptics.mapping import rendered_value_pa
from haptics.operator_loop import LoopStatus, OperatorLoop
from teleop.bus.messages import EstimateBody
from teleop.labels import LabelError, describe_label, parse_label
from teleop.units import format_pa

__all__ = ["CONSOLE_BUTTON_KEYS", "MIN_SIZE", "OperatorConsole", "estimate_line", "small_terminal_line"]

log = logging.getLogger(__name__)

#: Keys that press a button from the console whatever the input device.
CONSOLE_BUTTON_KEYS = {"g": "grasp", "r": "release", "s": "stop", "n": "next", "q": "quit"}
#: Keys that stop the fingers, let them go, toggle the enable or quit: the console's before textual's
#: bindings or any focused widget could take them (the label line alone takes them, as letters, while
#: it is open).
SAFETY_KEYS = ("s", "r", "e", "q")
LABEL_KEY = "l"
LABEL_PLACEHOLDER = "object name (right arrow takes the suggestion), NAME shore A 40, NAME shore 00 60 or NAME 12 MPa"
FORCE_STEP_N = 1.0
REFRESH_S = 0.1
MIN_SIZE = (80, 24)  # the terminal the whole layout fits; under it a line at the top keeps the enable shown
MIN_KEYS_HEIGHT = 10  # rows under which the keys' legend is hidden, leaving them to that line
QUIT_GRACE_S = 1.0  # after quit, the loop thread is told to stop if it has not ended by itself
BAR_CELLS = 24
PANEL_LINES = 4  # the estimate and display panels' lines on a terminal shorter than TALL_LINES ...
TALL_LINES = 50  # ... so that the operator and notices panels stay on screen below a long reason
#: A final interval wider than this (a factor 10, a third of the display's scale) gets a hint: a
#: firmer squeeze reads surer (the model card's light-squeeze limit) ...
WIDE_INTERVAL_DECADES = 1.0
#: ... unless the grasp already reached this share of the settings' maximum force.
FULL_SQUEEZE = 0.9


def estimate_line(estimate: EstimateBody | None) -> str:
    """The estimate in one line: ``E = 3.6 MPa  [2 MPa, 6 MPa]  ok  final``, a bound as ``E >= ...``."""
    if estimate is None:
        return "no estimate yet"
    state = estimate.state
    kind = "provisional" if estimate.provisional else "final"
    low, high = estimate.interval_pa
    value = rendered_value_pa(state, estimate.E_pa, (low, high))  # what the display renders
    if value is None:
        return f"no modulus ({state.replace('_', ' ')})  {kind}"
    sign = {"lower_bound": ">=", "upper_bound": "<="}.get(state, "=")
    interval = ""
    if low is not None or high is not None:
        interval = f"  interval [{format_pa(low) if low else '-'}, {format_pa(high) if high else '-'}]"
    return f"E {sign} {format_pa(value)}{interval}  {state}  {kind}"


def squeeze_hint(estimate: EstimateBody | None, *, peak_force_n: float | None = None,
                 max_force_n: float | None = None) -> str | None:
    """A hint for a final ``ok`` estimate whose interval is wider than :data:`WIDE_INTERVAL_DECADES`,
    after a grasp that peaked at ``peak_force_n`` (N) of the ``max_force_n`` (N) allowed: none when
    it reached :data:`FULL_SQUEEZE` of that maximum, as no firmer squeeze is possible."""
    if estimate is None or estimate.provisional or estimate.state != "ok":
        return None
    low, high = estimate.interval_pa
    if not (low and high):
        return None
    width = math.log10(high / low)
    if width <= WIDE_INTERVAL_DECADES:
        return None
    if peak_force_n is None or max_force_n is None:
        return f"wide interval ({width:.1f} decades): a firmer squeeze reads surer"
    if peak_force_n >= FULL_SQUEEZE * max_force_n:
        return None
    return (f"wide interval ({width:.1f} decades) after a {peak_force_n:.0f} N squeeze: a firmer one "
            f"(up to {max_force_n:.0f} N) reads surer")


def _bar(fraction: float | None, cells: int = BAR_CELLS) -> str:
    if fraction is None:
        return "[" + " " * cells + "]"
    filled = round(min(max(fraction, 0.0), 1.0) * cells)
    return "[" + "#" * filled + "-" * (cells - filled) + "]"


def _mm(width_m: float | None) -> str:
    return "-" if width_m is None else f"{width_m * 1e3:.1f} mm"


def _ago(seconds: float | None) -> str:
    return "never heard" if seconds is None else f"heard {seconds:.1f} s ago"


def _peer_line(peer: Any) -> str:
    """UP, DOWN, WAIT for a robot node heard alive whose subscription to our commands is not open yet, or
    MANY while more than one robot node subscribes (driving refused)."""
    if peer.alive and peer.subscribed is False:
        return f"WAIT  {peer.name:<11} not subscribed yet"  # heard: its ago is not the news
    if peer.alive and (peer.nodes or 0) > 1:
        return f"MANY  {peer.nodes} robot nodes subscribe"
    return f"{'UP  ' if peer.alive else 'DOWN'}  {peer.name:<11} {_ago(peer.seen_ago_s)}"


def _notice_line(notice: Any, now_s: float, at_s: float | None) -> str:
    """A robot notice in a line; its grasp's id only where the reason does not name it (room)."""
    ago = "" if at_s is None else f" ({max(0.0, now_s - at_s):.1f} s ago)"
    grasp = f" {notice.grasp_id}" if notice.grasp_id and notice.grasp_id not in notice.reason else ""
    return f"robot {notice.event} {notice.action}{grasp}{ago}: {notice.reason}"


def _fit(text: str, width: int, max_lines: int | None) -> str:
    """``text`` wrapped to ``width`` columns (none when 0: not laid out yet) and cut to ``max_lines``,
    the last line ending in an ellipsis where cut."""
    if width <= 0:
        return text
    lines = [part for line in text.splitlines() for part in (textwrap.wrap(line, width) or [""])]
    if max_lines is not None and len(lines) > max_lines:
        lines = lines[:max_lines]
        lines[-1] = lines[-1][:width - 1] + "\u2026"
    return "\n".join(lines)


class OperatorConsole(App):
    """The console's screen over a running :class:`OperatorLoop` (module docstring).

    Parameters
    ----------
    loop : OperatorLoop
        The loop to run (in a thread of this app, unless ``run_loop`` is False) and to show.
    input_name : str
        The input backend's name, for the screen.
    keyboard : object, optional
        The keyboard input device (with ``press(key) -> bool``): every key goes to it first.
    run_loop : bool
        Run ``loop`` in a thread while the app runs (False: something else steps it).
    duration_s : float, optional
        Quit after this many seconds.
    catalogue : sequence of ObjectSpec
        The objects a label may name by name alone (their names are suggested as typed).
    catalogue_name : str
        What the catalogue is called in labels and errors (its file).

    ``exit_status`` after the run: the loop's last :class:`LoopStatus`.
    """

    TITLE = "haptics operate"
    AUTO_FOCUS = None  # the keys are the console's until the label line opens
    ENABLE_COMMAND_PALETTE = False  # ctrl+p would open a search box over the status that takes s, e and q
    CSS = """
    Screen { layout: vertical; overflow-y: auto; }
    .row { height: auto; width: 100%; }
    #row3 { height: 1fr; min-height: 6; }
    .panel { border: round $primary; padding: 0 1; height: auto; width: 1fr; }
    #row3 .panel { height: 100%; overflow: hidden hidden; }
    #keys { color: $text-muted; padding: 0 1; height: auto; dock: bottom; }
    #small { dock: top; height: auto; display: none; background: $error; color: $text; text-style: bold; }
    #small.open { display: block; }
    #label { display: none; }
    #label.open { display: block; dock: bottom; height: 3; }
    """
    BINDINGS = [
        Binding("ctrl+c", "quit_console", "Quit", priority=True, show=False),
        Binding("ctrl+q", "quit_console", "Quit", priority=True, show=False),
    ]
    PANELS = (("alive", "live system"), ("grasp", "grasp"), ("estimate", "estimate"), ("display", "display"),
              ("input", "operator"), ("notice", "notices"))

    def __init__(self, loop: OperatorLoop, *, input_name: str, keyboard: Any = None, run_loop: bool = True,
                 duration_s: float | None = None, catalogue: Sequence[Any] = (),
                 catalogue_name: str = "the catalogue"):
        super().__init__()
        self.catalogue = tuple(catalogue)
        self.catalogue_name = catalogue_name
        self.labelling: str | None = None  # the grasp the open label line names
        self.duration_s = duration_s
        self.loop = loop
        self.input_name = input_name
        self.keyboard = keyboard
        self.run_loop = run_loop
        self.exit_status: LoopStatus | None = None
        self.loop_error = ""
        self.texts: dict[str, str] = {}  # each panel's text as last drawn, unwrapped (for tests and logs)
        self.drawn: dict[str, str] = {}  # each panel's text as drawn: wrapped to its width, maybe cut
        self.console_note = ""  # the console's own last note (a label sent, nothing to label) ...
        self._note_grasp: str | None = None  # ... and the grasp shown then: a new grasp's view drops it
        self.small_line = ""  # the line shown at the top of a terminal under MIN_SIZE ("" when it fits)
        self.log_note = ""  # the last warning logged while the screen holds the log (set from any thread)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ layout

    def compose(self) -> ComposeResult:
        yield Static("", id="small", markup=False)  # shown only in a terminal under MIN_SIZE
        names = [name for name, _ in self.PANELS]
        for number, row in enumerate((names[0:2], names[2:4], names[4:6]), 1):
            with Horizontal(classes="row", id=f"row{number}"):
                for name in row:
                    panel = Static("", id=name, classes="panel", markup=False)
                    panel.border_title = dict(self.PANELS)[name]
                    yield panel
        label = Input(id="label", placeholder=LABEL_PLACEHOLDER, disabled=True,
                      suggester=SuggestFromList([spec.name for spec in self.catalogue], case_sensitive=False))
        label.border_title = "label"
        yield label
        yield Static(self._legend(), id="keys", markup=False)

    def on_mount(self) -> None:
        self.sub_title = f"input {self.input_name}"
        if self.run_loop:
            self._thread = threading.Thread(target=self._run_loop, name="operator-loop", daemon=True)
            self._thread.start()
        self.redraw()
        self.set_interval(REFRESH_S, self.redraw)
        if self.duration_s is not None:
            self.set_timer(self.duration_s, self.action_quit_console)

    def _run_loop(self) -> None:
        try:
            self.loop.run(self._stop)  # the screen's timer sees the loop end (status.quit) and exits
        except Exception as exc:  # a bug: shown on the screen, which stays up until quit
            log.exception("the operator loop stopped")
            self.loop_error = f"the operator loop stopped: {type(exc).__name__}: {exc}"

    def stop_loop(self, timeout_s: float = 2.0) -> bool:
        """Stop the loop's thread (the loop lets the enable go on its way out) and wait for it;
        whether it has stopped (or never ran)."""
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=timeout_s)
        return self._thread is None or not self._thread.is_alive()

    async def on_unmount(self) -> None:
        self.stop_loop()

    # ------------------------------------------------------------------ keys

    def on_key(self, event: events.Key) -> None:
        key = event.key
        event.stop()
        if self.labelling is not None:  # the label line has the keys; escape closes it
            if key == "escape":
                self.close_label()
            else:
                self.query_one("#label", Input).focus()  # back to the line (after a tab, say)
            return
        self._press_key(key, event.character or "")

    async def on_event(self, event: events.Event) -> None:
        # A key from the terminal (not one bubbling back) reaches textual's bindings and the focused
        # widget here; even a priority binding gives way to a focused line that takes letters.
        if (isinstance(event, events.Key) and not event.is_forwarded and event.key in SAFETY_KEYS
                and self.labelling is None):
            self._press_key(event.key, event.character or "")
            return
        await super().on_event(event)

    def _press_key(self, key: str, character: str) -> None:
        """A key the console takes (not the label line's): to the keyboard input device first."""
        if key == LABEL_KEY and (self.keyboard is None or not self.keyboard.press(key)):
            self.open_label()
            return
        if key == "q":  # whatever the input, and even if the loop has stopped stepping
            self.action_quit_console()
            return
        if self.keyboard is not None and self.keyboard.press(key):
            return
        if character in ("+", "=") or key in ("plus", "equals_sign"):
            self.loop.set_force(self.loop.force_n + FORCE_STEP_N)
        elif character == "-" or key in ("minus", "hyphen"):
            self.loop.set_force(self.loop.force_n - FORCE_STEP_N)
        elif self.keyboard is None and key in CONSOLE_BUTTON_KEYS:
            self.loop.press(CONSOLE_BUTTON_KEYS[key])
        self.redraw()

    # ------------------------------------------------------------------ labels

    def open_label(self) -> bool:
        """Open the label line for the grasp a label would name now; False (and a note) if none."""
        grasp_id = self.loop.status.label_grasp_id
        line = self.query_one("#label", Input)
        if grasp_id is None:
            self._note("no grasp to label yet: grasp first, then l")
            self.redraw()
            return False
        self.labelling = grasp_id
        line.border_title = f"label grasp {grasp_id}: enter sends, escape closes"
        line.border_subtitle = ""
        line.value = ""
        line.disabled = False
        line.add_class("open")
        line.focus()
        self._show_small(self.loop.status)  # the keys' legend gives the line its rows
        return True

    def _note(self, text: str) -> None:
        self.console_note, self._note_grasp = text, self.loop.status.view.grasp_id

    def close_label(self) -> None:
        line = self.query_one("#label", Input)
        line.remove_class("open")
        line.blur()
        line.disabled = True
        self.labelling = None
        self.redraw()

    def on_input_submitted(self, event: Input.Submitted) -> None:
        event.stop()
        if self.labelling is None:
            return
        try:
            label = parse_label(event.value, self.catalogue, where=self.catalogue_name)
        except LabelError as exc:
            event.input.border_subtitle = str(exc)  # cut at the line's width: the notices hold it whole
            self._note(f"label {self.labelling} refused: {exc}")
            return
        self.loop.label(self.labelling, label)
        self._note(f"label {self.labelling}: {describe_label(label)} sent")
        self.close_label()

    def action_quit_console(self) -> None:
        self.loop.press("quit")
        self.set_timer(QUIT_GRACE_S, self._stop.set)  # in case the loop no longer steps

    # ------------------------------------------------------------------ drawing

    def _legend(self) -> str:
        # Two lines at 80 columns: the panels above must fit a 24-line terminal.
        if self.keyboard is not None:
            drive = "keys: up/k squeeze  down/j open  o open fully  e enable (dead-man)  q quit"
        else:
            drive = f"the {self.input_name} input drives grip and enable  |  keys: q quit"
        return drive + "\ng grasp  r release  s stop  n next (ends the grasp)  +/- grasp force  l label"

    def on_resize(self, event: events.Resize) -> None:
        self._show_small(self.loop.status)

    def _show_small(self, status: LoopStatus) -> None:
        """In a terminal under :data:`MIN_SIZE` the panels do not all fit (the operator panel, with the
        enable, is cut off first): a line at the top, that nothing hides, says so with the enable and
        the mode."""
        banner = self.query_one("#small", Static)
        width, height = self.size
        small = width < MIN_SIZE[0] or height < MIN_SIZE[1]
        text = small_terminal_line(status, width, height) if small else ""
        if self.small_line != text:
            banner.update(Text(text))
            self.small_line = text
        banner.set_class(small, "open")
        # Docked at the bottom, the keys' legend would take the rows of a very short terminal before the
        # line; the label line takes its place (at 80x24 both would push the typed text off the screen).
        self.query_one("#keys", Static).display = height >= MIN_KEYS_HEIGHT and self.labelling is None

    def redraw(self) -> None:
        status = self.loop.status
        self._let_go_toggle(status)
        self._show_small(status)
        texts = self.render_status(status)
        cap = None if self.size.height >= TALL_LINES else PANEL_LINES  # else row 2 would push notices off
        for name, _ in self.PANELS:
            panel = self.query_one(f"#{name}", Static)
            lines = cap if name in ("estimate", "display") else None
            if name == "notice":  # its row's height is the layout's: cut here, not clipped mid-line
                lines = panel.content_size.height or None  # 0: not laid out yet
            drawn = _fit(texts[name], panel.content_size.width, lines)
            if self.drawn.get(name) != drawn:  # wrapped here, so that a cut line ends in an ellipsis
                panel.update(Text(drawn))
                self.drawn[name] = drawn
        self.texts = texts
        ended = status.quit or self._stop.is_set()
        if ended and (self._thread is None or not self._thread.is_alive()):
            status = self.loop.status  # as the loop left it
            self.exit_status = status
            self.exit(status)

    def _let_go_toggle(self, status: LoopStatus) -> None:
        """Turn the keyboard's enable toggle off when the loop suspended the follows (after next, the
        watchdog, the robot's end): a terminal has no key release, so the toggle would stay on while
        the loop waits for it to be let go, and the next e would only let it go."""
        if self.keyboard is not None and status.suspended and status.held:
            self.keyboard.let_go()

    def render_status(self, status: LoopStatus) -> dict[str, str]:
        """Each panel's text for ``status``."""
        view = status.view
        max_force = self.loop.settings.gripper.target_force_n
        alive = "\n".join(_peer_line(p) for p in view.peers)
        robot = view.robot
        target = None if robot is None else robot.target_width_m
        grasp = [
            f"grasp  {view.grasp_id or '-'}" + (f"  ({view.object_name})" if view.object_name else ""),
            f"phase  {view.phase}",
            f"robot  {'-' if robot is None else robot.mode}"
            + (f"  target {_mm(target)}" if target is not None else ""),
            f"force  {_bar(None if view.force_n is None else view.force_n / max_force, 16)} "
            + ("-" if view.force_n is None else f"{view.force_n:.1f} N".replace("-0.0 N", "0.0 N")),  # noise at rest
            f"width  {_mm(view.width_m)}",
        ]
        given = status.labels.get(view.grasp_id) if view.grasp_id else None
        given = given or view.label
        if given is not None:
            grasp.append(f"label  {describe_label(given)}")
        elif status.label_grasp_id is not None and status.label_grasp_id in status.labels:
            grasp.append(f"label  {status.label_grasp_id}: {describe_label(status.labels[status.label_grasp_id])}")
        else:
            grasp.append(f"label  - ({LABEL_KEY} names the object)")
        estimate = view.estimate
        lines = [estimate_line(estimate)]  # in the order kept when the panel is cut to fit
        if estimate is None and view.down("estimator"):
            lines.append("the estimator is down: none will come (start `estimator serve`)")
        if estimate is not None:
            if view.down("estimator"):
                lines.insert(0, "the estimator is down: not current")
            elif view.estimate_orphaned:  # a restarted estimator does not go on with an earlier one's grasp
                lines.insert(0, "from an estimator that died since: not current, and no final will come")
            if hint := squeeze_hint(estimate, peak_force_n=view.peak_force_n, max_force_n=max_force):
                lines.append(hint)
            lines.append(f"{view.estimates} estimate(s) for this grasp, method {estimate.method}")
            lines.append(f"reason: {estimate.reason}")
        shown = view.display
        if shown is None:
            display = ["nothing rendered yet"]
            if view.down("display"):
                display.append("the renderer is down: nothing will be (start `haptics serve`)")
        else:
            level = f"  level {shown.level}/{shown.level_max}" if shown.level is not None else ""
            if shown.unknown:
                what = "unknown (the display says it cannot tell)"
            elif shown.rigid:
                what = "RIGID (at or beyond the sensor's resolution limit)"
            elif shown.phase == "idle":
                what = "free (idle)"
            elif shown.phase == "fading":  # the level falls to free: no modulus stands for it
                what = "fading to free (the grasp ended)"
            else:
                what = f"stiffness {shown.stiffness:.2f} of range = E {format_pa(shown.E_pa)}"
            display = [f"{what}{level}", f"{_bar(view.stiffness)}"]
            if shown.phase in ("active", "stale"):
                display.append(f"phase {shown.phase}  {'provisional' if shown.provisional else 'final'}  "
                               f"interval {shown.uncertainty_decades:.2f} decades wide")
            if view.down("display"):  # its last rendering is still shown below: say it is not current
                display.insert(0, "the renderer is down: its last report below is not current (start `haptics serve`)")
        felt = "-" if status.operator_force_n is None else f"{status.operator_force_n:.1f} N"
        operator = [  # short lines: half of an 80-column terminal
            f"input {self.input_name}   enable {'HELD' if status.held else 'off'}",
            f"mode {status.mode}",
            f"grip {_bar(status.grip, 8)} {status.grip:.2f} -> {_mm(status.target_width_m)}",
            f"grasp force {status.force_n:g} N (max {max_force:g})  hand {felt}",
            f"sent {status.follows_sent} follow, {status.commands_sent} command",
        ]
        # In the order kept when the panel is cut to fit: what is wrong now, then why a grasp stopped (a
        # refusal that came after it must not hide it), and the newest of the operator's actions first.
        notice_lines = []
        if self.loop_error:
            notice_lines.append(self.loop_error + " (q quits)")
        if status.problem:
            notice_lines.append(f"problem: {status.problem}")
        if view.ended_by is not None and view.ended_by != view.notice:
            notice_lines.append(_notice_line(view.ended_by, view.t_s, view.ended_by_t_s))
        if view.notice is not None:
            notice_lines.append(_notice_line(view.notice, view.t_s, view.notice_t_s))
        else:
            notice_lines.append("robot: no notice")
        if self.console_note and view.grasp_id in (None, self._note_grasp):
            notice_lines.append(self.console_note)
        if view.refused:
            notice_lines.append(f"{view.refused} bus message(s) refused (see the log)")
        notice_lines.append("last: " + ("  |  ".join(reversed(status.log[-3:])) or "-"))
        if self.log_note:  # last: a long one is cut, not the lines above
            notice_lines.append(self.log_note)
        return {"alive": alive, "grasp": "\n".join(grasp), "estimate": "\n".join(lines),
                "display": "\n".join(display), "input": "\n".join(operator), "notice": "\n".join(notice_lines)}


def small_terminal_line(status: LoopStatus, width: int, height: int) -> str:
    """The line shown at the top of a terminal under :data:`MIN_SIZE`: the enable and mode first, so
    that a narrow terminal, wrapping it, still shows them at the top."""
    grasp = f", grasp {status.grasp_id}" if status.grasp_id else ""
    return (f"enable {'HELD' if status.held else 'off'}, mode {status.mode}{grasp} | terminal {width}x{height}: "
            f"{MIN_SIZE[0]}x{MIN_SIZE[1]} needed, panels are cut off")
