"""HMI: pops up an alert box for the driver when collision avoidance raises an alert.

Data flow:  Alerts::DriverAlerts on AlertTopic (transient local: a late HMI shows the last state)  -->  alert box

A WaitSet, not a listener, delivers the alerts: acknowledging an alert may take the driver a while, and that must not
block DDS's receive thread. The alert box is a window (SDL2 through pygame) or a clearly marked box on the console
(--ui console|window|auto). ``--ui window`` without a usable display (automotive.bus.display) is bad input (one line,
exit code 2, before the HMI joins the bus): SDL's offscreen and dummy drivers, which it falls back to silently, show
no window and never pass for one. ``--ui auto`` then takes the console and says why.

The box never shows "all clear" on silence. It tells apart:

- no alert source: no alert writer has matched yet (grey);
- no alert state yet: a live writer matched but has said nothing (grey);
- all clear (green) or DRIVER ALERT (red): what a live, matched writer said last (a transient-local late join counts);
- alert source lost: no live writer any more, its liveliness lost or the writer gone (amber, with the last alert).

When the source comes back, what it said before the loss is shown again only if the very writer that said it is
alive again; a new writer has to speak first. The window's title names the state (``HMI - all clear`` ...).

Redundant mode (config.redundant=true): the alerts come from the stronger live of two collision_avoidance instances;
each change of owner is reported in one line, the source is lost only when no writer is alive, and an alert state is
shown once however many writers repeat it.
"""

from __future__ import annotations

import argparse
import enum
import logging
import sys
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

from cyclonedds.core import GuardCondition

from automotive.bus import console
from automotive.bus.alerts import alert_texts
from automotive.bus.app import Application, build_parser, run
from automotive.bus.cli import EXIT_BAD_INPUT
from automotive.bus.diagnostics import ERROR, OK, Problem
from automotive.bus.display import NoWindow, open_pygame_display, open_window
from automotive.bus.ownership import OwnerTracker
from automotive.bus.properties import PropertyKeys
from automotive.bus.status import policy_name
from automotive.types.Alerts import DriverAlerts

# The property keys it reads beyond the runtime's (automotive.bus.app.RUNTIME_KEYS): any other is refused at start.
PROPERTY_KEYS = PropertyKeys.of(roles=["Alerts"])

NAME = "hmi"


class Shown(enum.Enum):
    """What the alert box shows; the value is the window title's state."""

    NO_SOURCE = "no alert source"
    NO_STATE = "no alert state yet"
    LOST = "alert source lost"
    CLEAR = "all clear"
    ALERT = "DRIVER ALERT"

    @property
    def window_title(self) -> str:
        return f"HMI - {self.value}"


WINDOW_TITLE_NO_SOURCE = Shown.NO_SOURCE.window_title
WINDOW_TITLE_LOST = Shown.LOST.window_title
WINDOW_TITLE_CLEAR = Shown.CLEAR.window_title
WINDOW_TITLE_ALERT = Shown.ALERT.window_title


@dataclass(frozen=True)
class AlertView:
    shown: Shown
    texts: tuple[str, ...] = ()  # ALERT: the alerts; LOST: the alerts the source said last
    mismatch: str = ""  # NO_SOURCE: the QoS policy of an alert writer that was seen but does not match


SOURCE_LINES = {
    Shown.NO_SOURCE: "Collision avoidance not seen: no alert can be shown",
    Shown.NO_STATE: "Collision avoidance live, has said nothing yet",
    Shown.LOST: "Collision avoidance not alive: alerts may be missing",
}


def box_lines(view: AlertView) -> list[str]:
    """The lines under the box's title."""
    if view.shown is Shown.ALERT:
        return list(view.texts)
    if view.shown is Shown.CLEAR:
        return ["No alert"]
    if view.shown is Shown.NO_SOURCE and view.mismatch:  # seen, not matched: the QoS, not the network
        return [f"Collision avoidance seen, QoS does not match ({view.mismatch}): no alert can be shown"]
    return [SOURCE_LINES[view.shown], *(f"Last alert: {text}" for text in view.texts)]


class SourceChange(enum.Enum):
    FOUND = "found"
    LOST = "lost"
    BACK = "back"


class AlertSource:
    """What the HMI knows of its alert source (the alert writers) and what the source last said.

    Fed, in the main thread, with the reader's match and liveliness events (their counts and the writer they name)
    and with the alerts taken; :meth:`view` is what the driver is shown.
    """

    def __init__(self) -> None:
        self.matched = 0
        self.alive = 0
        self.alive_writers: set[int] = set()
        self.seen = False  # a live writer was there once: from then on its absence is a loss, not "no source"
        self.live = False
        self.texts: list[str] | None = None  # what the source last said; None: nothing a live writer stands for
        self.said_by: int | None = None
        self.lost_reason = ""
        self.mismatch = ""  # the QoS policy of the last alert writer seen that does not match

    def incompatible(self, policy: str) -> bool:
        """An alert writer was seen whose QoS does not match; whether the box changes."""
        changed = not self.seen and policy != self.mismatch
        self.mismatch = policy
        return changed

    def matched_changed(self, current_count: int) -> SourceChange | None:
        self.matched = current_count
        return self._judge("no alert writer is matched any more")

    def liveliness_changed(self, writer: int, alive_count: int, alive_change: int,
                           not_alive_change: int) -> SourceChange | None:
        if alive_change > 0:  # matched alive, or alive again
            self.alive_writers.add(writer)
        elif alive_change < 0:  # its liveliness lost, or it left while alive
            self.alive_writers.discard(writer)
        self.alive = alive_count
        return self._judge("the alert writer's liveliness was lost" if not_alive_change > 0
                           else "the alert writer left")

    def said(self, texts: list[str], writer: int) -> None:
        self.texts, self.said_by = texts, writer

    def _judge(self, reason: str) -> SourceChange | None:
        live = self.matched > 0 and self.alive > 0
        if live == self.live:
            return None
        self.live = live
        if not live:
            self.lost_reason = reason
            return SourceChange.LOST
        if not self.seen:
            self.seen = True
            return SourceChange.FOUND
        if self.said_by not in self.alive_writers:  # a new writer: what the lost one said is not its word
            self.texts = None
        return SourceChange.BACK

    def view(self) -> AlertView:
        if not self.seen:
            return AlertView(Shown.NO_SOURCE, mismatch=self.mismatch)
        if not self.live:
            return AlertView(Shown.LOST, tuple(self.texts or ()))
        if self.texts is None:
            return AlertView(Shown.NO_STATE)
        return AlertView(Shown.ALERT, tuple(self.texts)) if self.texts else AlertView(Shown.CLEAR)


class AlertUI(Protocol):
    def render(self, view: AlertView) -> None: ...
    def pump(self) -> None: ...
    def close(self) -> None: ...


class ConsoleUI:
    """A boxed, unmistakable alert on standard output: a box on a terminal; its title bar and its lines on one line
    where the output goes to a pipe or a file (the launcher's console, a log), so that it stands out there as one line
    among the others instead of three."""

    WIDTH = 56
    TITLES = {Shown.NO_SOURCE: "no alert source", Shown.NO_STATE: "no alert state yet",
              Shown.LOST: "ALERT SOURCE LOST", Shown.CLEAR: "all clear", Shown.ALERT: "!!! DRIVER ALERT !!!"}

    def __init__(self, boxed: bool | None = None) -> None:
        self.boxed = sys.stdout.isatty() if boxed is None else boxed

    def render(self, view: AlertView) -> None:
        inner = self.WIDTH - 2
        title = "+" + f" {self.TITLES[view.shown]} ".center(inner, "=") + "+"
        # One write for the whole (console.write_line): another thread's log record cannot land inside a line.
        if not self.boxed:
            console.write_line(f"{title} {' | '.join(box_lines(view))}")
            return
        lines = [title, *("| " + line.ljust(inner - 2) + " |" for line in box_lines(view)), "+" + "=" * inner + "+"]
        console.write_line("\n".join(lines))

    def pump(self) -> None:
        pass

    def close(self) -> None:
        pass


class WindowUI:
    """An SDL2 window (pygame): grey without a source or state, amber when the source is lost, red with one line per
    alert, green when clear. Made by :meth:`open`, which refuses any driver that shows no window."""

    SIZE = (640, 260)
    BOX_COLOURS = {Shown.NO_SOURCE: (110, 110, 110), Shown.NO_STATE: (110, 110, 110), Shown.LOST: (230, 140, 0),
                   Shown.CLEAR: (0, 140, 0), Shown.ALERT: (200, 0, 0)}
    TITLES = {Shown.NO_SOURCE: "No alert source", Shown.NO_STATE: "No alert state yet",
              Shown.LOST: "Alert source lost", Shown.CLEAR: "All clear", Shown.ALERT: "DRIVER ALERT"}
    MAX_LINES = 5  # what the box holds under its title

    def __init__(self, pygame: Any) -> None:
        self.pygame = pygame
        pygame.font.init()
        self.screen = open_window(pygame, self.SIZE)
        self.title_font = pygame.font.Font(None, 48)
        self.text_font = pygame.font.Font(None, 32)
        self.render(AlertView(Shown.NO_SOURCE))

    @classmethod
    def open(cls) -> WindowUI:
        return cls(open_pygame_display())

    def render(self, view: AlertView) -> None:
        pygame = self.pygame
        pygame.display.set_caption(view.shown.window_title)
        self.screen.fill((30, 30, 30))
        box = pygame.Rect(20, 20, self.SIZE[0] - 40, self.SIZE[1] - 40)
        pygame.draw.rect(self.screen, self.BOX_COLOURS[view.shown], box, border_radius=12)
        self.screen.blit(self.title_font.render(self.TITLES[view.shown], True, (255, 255, 255)),
                         (box.x + 20, box.y + 16))
        # Alerts in yellow on red; the source's state in white, readable on grey and amber.
        colour = (255, 255, 0) if view.shown is Shown.ALERT else (255, 255, 255)
        for index, line in enumerate(box_lines(view)[:self.MAX_LINES]):
            self.screen.blit(self.text_font.render(line, True, colour), (box.x + 20, box.y + 70 + index * 30))
        pygame.display.flip()

    def pump(self) -> None:
        for event in self.pygame.event.get():
            if event.type == self.pygame.QUIT:
                raise KeyboardInterrupt
        self.pygame.display.flip()

    def close(self) -> None:
        self.pygame.display.quit()


def open_ui(choice: str) -> tuple[AlertUI, str]:
    """The alert box for ``--ui``, and why it is the console when a window was possible (auto), else "".

    Raises NoWindow for ``--ui window`` without a window to show.
    """
    if choice == "console":
        return ConsoleUI(), ""
    try:
        return WindowUI.open(), ""
    except NoWindow as reason:
        if choice == "window":
            raise
        return ConsoleUI(), str(reason)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ui", choices=["auto", "console", "window"], default="auto",
                        help="alert box in a window (SDL2), on the console, or a window when a display can be "
                             "opened (auto)")


def body(app: Application, ui: AlertUI, why_console: str) -> None:
    # The reader's match and liveliness events, queued by the listener thread, judged by the main loop.
    events: deque[tuple[str, int, int, int, int]] = deque()
    wake = GuardCondition(app.bus.participant)  # a source event wakes the loop at once, not at its next timeout

    def on_status(event: str, topic: str, status: Any) -> None:
        if event == "subscription_matched":
            events.append((event, status.last_publication_handle, status.current_count, 0, 0))
        elif event == "liveliness_changed":
            events.append((event, status.last_publication_handle, status.alive_count, status.alive_count_change,
                           status.not_alive_count_change))
        elif event == "requested_incompatible_qos":
            events.append((event, status.last_policy_id, 0, 0, 0))
        else:
            return
        wake.set(True)

    alerts = app.reader("Alerts", DriverAlerts, "AlertTopic", hook=on_status)
    topic = alerts.topic.get_name()
    owner = OwnerTracker(alerts, app.log, app.stats)
    window = isinstance(ui, WindowUI)
    source = AlertSource()
    view = source.view()
    ui.render(view)

    def health() -> Problem:
        """For /diagnostics: what the box shows; an error when the alert source is lost."""
        now = source.view()
        if now.shown is Shown.LOST:
            return Problem(ERROR, f"alert source LOST: {source.lost_reason}")
        return Problem(OK, "; ".join((now.shown.value, *now.texts)))

    app.health_check = health
    app.log.info("HMI: %s alert box%s, waiting for alerts; %s", "window" if window else "console",
                 f" (no window: {why_console})" if why_console else "", view.shown.value)
    waitset = app.waitset(alerts)
    waitset.attach(wake)

    shown: list[str] | None = None
    # With the console box, the box is what shows a change; its log line is a duplicate, for -v and the log files.
    shown_level = logging.INFO if window else logging.DEBUG
    for _ in app.wake_ups(waitset, timeout_s=0.05 if window else 1.0):
        ui.pump()
        wake.set(False)  # before draining: an event queued from now on sets it again
        while events:
            event, writer, count, alive_change, not_alive_change = events.popleft()
            if event == "subscription_matched":
                change = source.matched_changed(count)
            elif event == "requested_incompatible_qos":
                source.incompatible(policy_name(writer))  # said once by the reader's line; the box shows it
                change = None
            else:
                change = source.liveliness_changed(writer, count, alive_change, not_alive_change)
            if change is SourceChange.FOUND:
                app.log.log(shown_level, "alert source found: a live alert writer matched")  # the box says it too
            elif change is SourceChange.LOST:
                # what the driver is told: lost (why: a writer that left cleanly, at a shutdown, counts too), or back;
                # recorded before it is said, so that whoever reads the line finds the record
                app.stats.record("source", alive=False, reason=source.lost_reason)
                app.log.warning("alert source LOST: %s", source.lost_reason)
            elif change is SourceChange.BACK:
                app.stats.record("source", alive=True)
                app.log.info("alert source back: the alert writer's liveliness was regained%s",
                             "" if source.texts is not None else " (a new writer: no alert state from it yet)")
        taken = alerts.take(N=100)
        taken_ns = time.time_ns()
        for alert in taken:
            if not isinstance(alert, DriverAlerts):
                continue
            info: Any = alert.sample_info  # type: ignore[attr-defined]
            app.stats.record("take", topic=topic, src=info.source_timestamp, at=taken_ns,
                             attention=alert.driverAttention)
            owner.follow(alert)
            texts = alert_texts(alert)
            source.said(texts, info.publication_handle)
            if texts != shown:  # the writer repeats an active alert; the driver sees each change once
                if texts:
                    app.log.log(shown_level, "DRIVER ALERT: %s", "; ".join(texts))
                    app.stats.record("shown", state="alert", texts=texts)
                else:
                    app.log.log(shown_level, "all clear")
                    app.stats.record("shown", state="clear", texts=[])
                shown = texts
            app.tick()
        if source.view() != view:
            view = source.view()
            ui.render(view)


def main(argv: list[str] | None = None) -> int:
    description = __doc__ or ""
    # The alert box is opened before the application exists: a window that cannot be shown is bad input, refused
    # before the HMI creates its DDS participant. (The command line is parsed again by run: the same parser.)
    parser = build_parser(NAME, description, add_arguments)
    args = parser.parse_args(argv)
    try:
        ui, why_console = open_ui(args.ui)
    except NoWindow as reason:
        print(f"{parser.prog}: --ui window: {reason}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        return run(NAME, description, lambda app: body(app, ui, why_console), argv, add_arguments, keys=PROPERTY_KEYS)
    finally:
        ui.close()


if __name__ == "__main__":
    sys.exit(main())
