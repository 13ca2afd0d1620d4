"""Where a program can show a window: a usable display for SDL2 (pygame), or why there is none, in one line.

Both programs with windows (the HMI's alert box, the LiDAR view) open their display here, before they join the bus:
``--ui window`` without a usable display is then bad input (one line, exit code 2, no participant), and an automatic
choice falls back to what the program can do without a window and says why.

SDL falls back silently to its ``offscreen`` or ``dummy`` video driver when it cannot open the display (or is told
to by ``SDL_VIDEODRIVER``): a window there draws into memory and is seen by nobody, so neither passes for a window.
pygame is imported only when a display is wanted: a program that never opens a window does not load it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

# SDL's video drivers that draw into memory: a "window" there is seen by nobody.
NO_WINDOW_DRIVERS = ("offscreen", "dummy")


class NoWindow(Exception):
    """Why no window can be shown, in one line."""


@contextmanager
def stderr_silenced() -> Iterator[None]:
    """File descriptor 2 to /dev/null: SDL prints its probing of video drivers there (``XDG_RUNTIME_DIR is invalid``),
    which is noise beside the one line the program says about the display."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, 2)
        os.close(null)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def display_named() -> str:
    """The display the environment names (``DISPLAY=':0'``, and/or ``WAYLAND_DISPLAY=...``), or "" if none."""
    names = [f"{variable}={os.environ[variable]!r}" for variable in ("DISPLAY", "WAYLAND_DISPLAY")
             if os.environ.get(variable)]
    return " and ".join(names)


def open_pygame_display() -> Any:
    """pygame with its display initialised on a video driver that shows windows; raises NoWindow saying why not."""
    display = display_named()
    if not display:
        raise NoWindow("no display: neither DISPLAY nor WAYLAND_DISPLAY is set")
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import pygame
    except ImportError as error:
        raise NoWindow(f"pygame is not installed ({error})") from None
    try:
        with stderr_silenced():
            pygame.display.init()
    except pygame.error as error:
        raise NoWindow(f"SDL cannot open the display {display}: {error}") from None
    driver = pygame.display.get_driver()
    if driver in NO_WINDOW_DRIVERS:
        pygame.display.quit()
        requested = os.environ.get("SDL_VIDEODRIVER")
        why = (f"SDL_VIDEODRIVER={requested} chose" if requested
               else f"SDL cannot open the display {display} and fell back to")
        raise NoWindow(f"{why} SDL's '{driver}' video driver, which shows no window")
    return pygame


def open_window(pygame: Any, size: tuple[int, int]) -> Any:
    """The window's surface (``pygame.display.set_mode``) on a display :func:`open_pygame_display` opened; raises
    NoWindow, the display closed, if SDL cannot open a window there."""
    try:
        return pygame.display.set_mode(size)
    except pygame.error as error:
        pygame.display.quit()
        raise NoWindow(f"SDL cannot open a window on {display_named()}: {error}") from None
