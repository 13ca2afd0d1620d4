"""How soon the monitor's page shows what runs, in a real browser (Debian's headless Chromium through Selenium).

    automotive bench monitor-page                   the running system's page, then a crowd of 100 participants
    automotive bench monitor-page --crowd 0         the system's page only
    automotive bench monitor-page --tries 5         each figure the median of five openings of the page

Two phases, each timing only the page: what it takes to open it and draw it, once the monitor already knows what
runs (discovery is automotive bench discovery's).

- system: the system as `automotive launch` starts it, all but the camera (background mode, --quiet), and beside it
  `automotive monitor` on the same domain. Once the monitor's /snapshot.json lists every program and the six flows
  moving, the browser opens the page (a fresh tab each try): the figure is the time from opening it until the page
  shows the six flows with a rate above zero, every program's health and live updates. Goal: 10 s.
- crowd: one process of --crowd Cyclone participants on --crowd-domain (the next one unless given) and a monitor on
  it; once its snapshot lists them all, the browser opens the page: the time until the graph and the participants'
  table hold them all. Goal: 2 s.

A test cannot judge these timings on a machine that runs other work (tests/test_monitor_page.py checks what the page
shows, within loose bounds): this program measures them, with the load average beside each figure. Each try prints a
progress line, each phase a JSON line of its figures. The processes' output goes to a temporary work folder,
removed at the end (also on an error, Ctrl-C or SIGTERM), or to --log-dir DIR, kept. Needs chromium and
chromedriver (Debian's chromium, chromium-driver) and selenium: scripts/setup installs them.

The last line is monitor_page_s=<the system phase's median seconds>.

Exit codes: 0 measured, 1 the system or the page did not come up (its output's tail said), 2 bad options or no
browser.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
import urllib.request
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from automotive.bus.cli import (
    ArgumentParser,
    add_domain_option,
    add_log_dir_option,
    domain_id,
    output_folder_problem,
)
from automotive.bus.ports import MAX_DOMAIN_ID
from automotive.tools.launch.display import RUNNING_LINE
from automotive.tools.support.children import Child, keep_outputs, program_command, stop_all, work_folder

PROG = "automotive bench monitor-page"
SIX_FLOWS = ("VisionTopic", "rt/LidarTopic", "SensorObjects", "PlatformStatus", "PlatformControl", "AlertTopic")
PROGRAMS = ("vision", "lidar", "sensor_fusion", "vehicle_platform", "collision_avoidance", "hmi", "monitor")
GOALS_S = {"system": 10.0, "crowd": 2.0}
START_TIMEOUT_S = 180.0  # the system and the monitor starting on a busy 2-core machine
PAGE_TIMEOUT_S = 120.0  # one opening of the page: a figure above this is reported as not shown
# Chromium's singleton socket, TMPDIR/org.chromium.Chromium.XXXXXX/SingletonSocket, must fit a socket path (107 bytes)
SOCKET_FOLDER_MAX = 107 - len("/org.chromium.Chromium.XXXXXX/SingletonSocket")
URL_MARK = "the page is on "
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run", "--window-size=1600,1300")
# Many lightweight participants in one process (they share its domain and participant index), each named.
CROWD_SCRIPT = r'''
import sys
from cyclonedds.domain import DomainParticipant
from cyclonedds.qos import Policy, Qos
domain, count = int(sys.argv[1]), int(sys.argv[2])
crowd = [DomainParticipant(domain, qos=Qos(Policy.EntityName(f"crowd-{i:03d}"))) for i in range(count)]
print(f"crowd of {len(crowd)} participants", flush=True)
sys.stdin.read()
'''
# What the page shows: the flows' rates, each program's health, whether updates are live, the graph's nodes and the
# participants' rows (the page's own data attributes, as tests/test_monitor_page.py reads them).
PAGE_STATE_JS = """
const graph = document.getElementById('graph');
return {status: document.getElementById('status').dataset.state,
        flows: [...document.querySelectorAll('#flows tbody tr[data-topic]')]
            .map((row) => [row.dataset.topic, Number(row.dataset.rate)]),
        programs: [...document.querySelectorAll('#programs tbody tr[data-program]')].map((row) => row.dataset.program),
        nodes: Number(graph.dataset.nodes),
        participants: document.querySelectorAll('#participants tbody tr[data-name]').length};
"""


class NoBrowser(Exception):
    """Chromium, chromedriver or selenium is missing: what to install."""


@contextmanager
def chromium(folder: Path) -> Iterator[Any]:
    """Debian's headless Chromium driven by Selenium, its profile, temporary files and driver log in ``folder``; quit
    at the end. Chromium's singleton socket lives in its TMPDIR, and a socket path is at most 107 bytes: where
    ``folder`` is too deep for that (a test's temporary folder), its temporary files go to a folder of its own in /tmp,
    removed after it."""
    try:
        from selenium import webdriver
        from selenium.common.exceptions import WebDriverException
        from selenium.webdriver.chrome.options import Options
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        raise NoBrowser("selenium is not installed (scripts/setup installs it with the development tools)") from None
    binary, driver = shutil.which("chromium"), shutil.which("chromedriver")
    if binary is None or driver is None:
        raise NoBrowser("chromium and chromedriver are missing: scripts/setup installs them (Debian's chromium, "
                        "chromium-driver)")
    folder.mkdir(parents=True, exist_ok=True)
    options = Options()
    options.binary_location = binary
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={folder / 'profile'}"):
        options.add_argument(flag)
    own_tmp = len(str(folder)) > SOCKET_FOLDER_MAX
    chromium_tmp = Path(tempfile.mkdtemp(prefix="chromium-", dir="/tmp")) if own_tmp else folder
    service = Service(executable_path=driver, log_output=str(folder / "chromedriver.log"),
                      env={**os.environ, "TMPDIR": str(chromium_tmp)})
    try:
        try:
            browser = webdriver.Chrome(options=options, service=service)
        except WebDriverException as error:
            first = (error.msg or str(error)).strip().splitlines()[0]
            raise NoBrowser(f"Chromium did not start: {first}") from None
        try:
            yield browser
        finally:
            browser.quit()
    finally:
        if own_tmp:
            shutil.rmtree(chromium_tmp, ignore_errors=True)


def snapshot(url: str) -> dict[str, Any]:
    """The monitor's next snapshot (one a second)."""
    base, _, query = url.partition("?")
    with urllib.request.urlopen(f"{base}snapshot.json?{'&'.join(p for p in (query, 'next=1') if p)}",
                                timeout=30) as response:
        document: dict[str, Any] = json.loads(response.read())
    return document


def wait_for_snapshot(url: str, check: Callable[[dict[str, Any]], bool], what: str, monitor: Child) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while not check(snapshot(url)):
        if monitor.poll() is not None or time.monotonic() > deadline:
            raise SystemExit(f"{PROG}: the monitor did not see {what} within {START_TIMEOUT_S:g} s:\n"
                             f"{monitor.output[-2000:]}")


def system_known(document: dict[str, Any]) -> bool:
    moving = {flow["topic"] for flow in document["flows"] if (flow.get("rate") or 0) > 0}
    return set(PROGRAMS) <= {p["name"] for p in document["programs"]} and set(SIX_FLOWS) <= moving


def time_page(browser: Any, url: str, shown: Callable[[dict[str, Any], set[str]], bool]) -> float:
    """Seconds from opening ``url`` in a fresh tab until ``shown`` holds for what the page shows (with the flows
    seen moving since it opened: the alert moves only while it is raised, and when it ends)."""
    browser.switch_to.new_window("tab")
    opened = time.monotonic()
    browser.get(url)
    moving: set[str] = set()
    while time.monotonic() - opened < PAGE_TIMEOUT_S:
        state = browser.execute_script(PAGE_STATE_JS)
        moving.update(topic for topic, rate in state["flows"] if rate > 0)
        if shown(state, moving):
            took = time.monotonic() - opened
            break
        time.sleep(0.05)
    else:
        took = float("inf")
    browser.close()
    browser.switch_to.window(browser.window_handles[0])
    return took


def system_shown(state: dict[str, Any], moving: set[str]) -> bool:
    return state["status"] == "live" and set(PROGRAMS) <= set(state["programs"]) and set(SIX_FLOWS) <= moving


def start_monitor(domain: int, env: dict[str, str]) -> tuple[Child, str]:
    monitor = Child(f"monitor-{domain}", program_command("monitor", "--domain", str(domain), "--port", "0"), env=env)
    try:
        line = monitor.wait_for(URL_MARK, timeout=START_TIMEOUT_S)
    except AssertionError:
        raise SystemExit(f"{PROG}: the monitor's page did not start:\n{monitor.output[-2000:]}") from None
    return monitor, line.split(URL_MARK, 1)[1].split()[0]


def run_phase(name: str, browser: Any, url: str, tries: int,
              shown: Callable[[dict[str, Any], set[str]], bool]) -> float:
    figures = []
    for attempt in range(1, tries + 1):
        figures.append(time_page(browser, url, shown))
        print(f"  {name}: try {attempt} of {tries}: {figures[-1]:.2f} s (load {os.getloadavg()[0]:.2f})", flush=True)
    median = statistics.median(figures)
    print(json.dumps({"phase": name, "tries": tries, "median_s": round(median, 3), "max_s": round(max(figures), 3),
                      "goal_s": GOALS_S[name], "load_1min": round(os.getloadavg()[0], 2)}), flush=True)
    verdict = "met" if median <= GOALS_S[name] else "NOT met"
    print(f"{name}: the page showed it in {median:.2f} s (median of {tries}); goal {verdict}: at most "
          f"{GOALS_S[name]:g} s", flush=True)
    return median


def measure(args: argparse.Namespace, work: Path) -> int:
    env = {**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""}  # the HMI's console box: no window on a display
    children: list[Child] = []
    try:
        with chromium(work / "chromium") as browser:
            launcher = Child("launch", program_command(
                "launch", "--mode", "background", "--quiet", "--log-dir", str(work / "logs"), "--domain",
                str(args.domain), "--except", "camera_pub,camera_sub"), env=env, keep=True)
            children.append(launcher)
            try:
                launcher.wait_for(RUNNING_LINE, timeout=START_TIMEOUT_S)
            except AssertionError:
                raise SystemExit(f"{PROG}: the launcher ended before the system ran:\n"
                                 f"{launcher.output[-2000:]}") from None
            monitor, url = start_monitor(args.domain, env)
            children.append(monitor)
            wait_for_snapshot(url, system_known, "every program and the six flows moving", monitor)
            print(f"{PROG}: the system runs and the monitor knows it; opening its page {args.tries} time(s)",
                  flush=True)
            system_s = run_phase("system", browser, url, args.tries, system_shown)
            if args.crowd > 0:
                crowd_domain = args.domain + 1 if args.crowd_domain is None else args.crowd_domain
                crowd = Child("crowd", [sys.executable, "-c", CROWD_SCRIPT, str(crowd_domain), str(args.crowd)],
                              env=env, stdin=True)
                children.append(crowd)
                try:
                    crowd.wait_for(f"crowd of {args.crowd} participants", timeout=START_TIMEOUT_S)
                except AssertionError:
                    raise SystemExit(f"{PROG}: the crowd did not start:\n{crowd.output[-2000:]}") from None
                crowd_monitor, crowd_url = start_monitor(crowd_domain, env)
                children.append(crowd_monitor)
                wait_for_snapshot(crowd_url, lambda d: sum(p["name"].startswith("crowd-") for p in d["participants"])
                                  >= args.crowd, f"the {args.crowd} participants", crowd_monitor)
                print(f"{PROG}: {args.crowd} participants known to a monitor on domain {crowd_domain}; opening its "
                      "page", flush=True)
                run_phase("crowd", browser, crowd_url, args.tries,
                          lambda state, _moving: state["nodes"] > args.crowd and state["participants"] > args.crowd)
    except NoBrowser as missing:
        print(f"{PROG}: {missing}", file=sys.stderr)
        return 2
    finally:
        stop_all(list(reversed(children)), timeout=30)
        if args.log_dir is not None:
            keep_outputs(children, args.log_dir, work / "logs")
    print(f"monitor_page_s={system_s:.2f}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--crowd", type=int, default=100,
                        help="participants of the crowd phase (default 100; 0: no crowd phase)")
    parser.add_argument("--tries", type=int, default=3, help="openings of the page per phase (default 3)")
    add_domain_option(parser, 88, "DDS domain id of the system")
    parser.add_argument("--crowd-domain", type=domain_id, metavar="ID",
                        help="DDS domain id of the crowd and its monitor (default: the system's plus one)")
    add_log_dir_option(parser, help="keep every process's output there (the launcher's log folder too)")
    args = parser.parse_args(argv)
    if args.crowd < 0 or args.tries < 1:
        parser.error(f"--crowd {args.crowd} and --tries {args.tries}: expected 0 or more and 1 or more")
    if args.crowd > 0 and args.crowd_domain is None and args.domain >= MAX_DOMAIN_ID:
        parser.error(f"--domain {args.domain}: the crowd takes the next domain, so at most {MAX_DOMAIN_ID - 1} "
                     "(or give --crowd-domain)")
    if args.crowd_domain is not None and args.crowd_domain == args.domain:
        parser.error(f"--crowd-domain {args.crowd_domain}: expected another domain than the system's")
    if args.log_dir is not None and (problem := output_folder_problem(args.log_dir, create=True)):
        parser.error(f"--log-dir {args.log_dir}: {problem}")
    # SIGTERM (a background run stopped with kill) ends the run as Ctrl-C does: the system stopped, the folder gone.
    with work_folder("bench-monitor-page-") as work:
        return measure(args, work)


if __name__ == "__main__":
    sys.exit(main())
