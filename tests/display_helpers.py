"""Programs with a window, run where there is no display (the HMI, the LiDAR view): the tests of their one line."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from automotive.tools.support.children import program_command

DISPLAY_VARIABLES = ("DISPLAY", "WAYLAND_DISPLAY", "SDL_VIDEODRIVER")


def free_x_display() -> str:
    """A display number no X server serves here."""
    number = next(n for n in range(900, 1000)
                  if not Path(f"/tmp/.X11-unix/X{n}").exists() and not Path(f"/tmp/.X{n}-lock").exists())
    return f":{number}"


def run_without_display(program: str, ui: str, domain_id: int, **environment: str) -> subprocess.CompletedProcess[str]:
    """``program --ui ui`` with no display variable but ``environment``'s, run to its end (bounded)."""
    env = {key: value for key, value in os.environ.items() if key not in DISPLAY_VARIABLES}
    return subprocess.run(program_command(program, "--ui", ui, "--domain", str(domain_id)), env={**env, **environment},
                          capture_output=True, text=True, timeout=60)
