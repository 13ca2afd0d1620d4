"""A command in a mount namespace of its own with a small tmpfs mounted on a folder (the namespace, and the tmpfs
with it, go when the command ends), and what a test does with that tmpfs from outside: fill it, read what the
command wrote there (through /proc/PID/root, the command's view of the files)."""

from __future__ import annotations

import re
from pathlib import Path

SIZE = "1m"


def on_small_disk(disk: Path, command: list[str], stdout_file: str | None = None) -> list[str]:
    """``command`` run with a tmpfs of SIZE mounted on ``disk`` (an existing folder), its standard output into
    ``disk/stdout_file`` when given. The process keeps the command's pid: the shell execs it."""
    redirect = ' > "$disk/$0"' if stdout_file else ""
    script = f'disk=$1 && shift && mount -t tmpfs -o size={SIZE} tmpfs "$disk" && exec "$@"{redirect}'
    return ["unshare", "--mount", "--propagation", "private", "sh", "-c", script, stdout_file or "small-disk",
            str(disk), *command]


def inside(pid: int, disk: Path) -> Path:
    """The tmpfs as process ``pid`` sees it (before its shell mounted it: the folder beneath)."""
    return Path(f"/proc/{pid}/root{disk}")


def fill(folder: Path) -> Path:
    """Fill the file system of ``folder`` to its last byte with a file of its own (returned: unlink it to make room)."""
    filler = folder / "filler"
    with open(filler, "wb", buffering=0) as stream:
        try:
            while True:
                stream.write(bytes(65536))
        except OSError as error:
            assert "No space left" in str(error), error
    return filler


def last_published_sample(path: Path) -> int:
    """The number of the vision sensor's last "published sample N" line in ``path`` (0: none, or no file yet)."""
    text = path.read_text(errors="replace") if path.exists() else ""
    found = re.findall(r"published sample (\d+):", text)
    return int(found[-1]) if found else 0
