"""The page of ``automotive monitor`` in a real browser: Debian's headless Chromium driven by Selenium.

Why: the page is what a user opens to see "why does my tool not see the data"; only a browser runs its JavaScript,
its WebSocket and its graph library, so only a browser shows that it works. What is checked, each test saving a
screenshot (in its tmp_path):

- with the system running (``automotive launch --monitor``: the launcher starts the monitor and says its URL; the
  camera is left out to keep the 2 cores free, so the page lists the six other flows), once the page is opened it
  lists VisionTopic, rt/LidarTopic, SensorObjects, PlatformStatus, PlatformControl and AlertTopic with rates
  above zero, shows every program's health, the matched pairs in the graph and the table; the vehicle's state (speed,
  blinker, fused objects) and the alert raised and cleared as collision avoidance does (a scene whose tall truck comes
  and goes every 6 s);
- the latency panel: the alert chain's topics per reader and per pair (writer -> reader), in ms, unmarked (one
  host), and the chain's sum of its hops with what that sum is;
- an RTI Connector reader requesting RELIABLE from our best-effort vision writer appears with its reason in words,
  offered against requested, as a red edge of the graph, with RTI as its vendor;
- a domain of 100 participants (one helper process of 100 Cyclone participants) renders once the page is opened,
  once the monitor has discovered them (the bounds are loose: a timing is a benchmark's, PAGE_S);
- --bind 0.0.0.0 without --token is refused with one line and exit code 2; with --token, a request without it gets
  403 and the page with it works; bound to loopback, a request naming another host and a WebSocket from another
  origin get 403.

Chromium runs with --headless --no-sandbox --disable-gpu, no background networking, component updates or sync, and a
fresh profile in tmp_path: this machine has no internet, and the page needs none (everything is served by the
monitor). ``AUTOMOTIVE_MONITOR_SCREENSHOT=docs/monitor.png`` saves the first screen of the RTI test's page (the whole
system and one mismatch) there as well: how the user's guide's picture is made.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import pytest
from apprunner import AppRunner
from test_system import scene

from automotive.bench.monitor_page import CROWD_SCRIPT, PROGRAMS, SIX_FLOWS, NoBrowser, chromium
from automotive.tools.support.children import Child, program_command

webdriver = pytest.importorskip("selenium.webdriver")
from selenium.common.exceptions import TimeoutException  # noqa: E402
from selenium.webdriver.remote.webdriver import WebDriver  # noqa: E402
from selenium.webdriver.support.ui import WebDriverWait  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
TIMEOUT = 90.0
# The page shows the running system, and 100 participants render, within these bounds of being opened. Bounds, not
# the goals: the goals (10 s and 2 s) are timings, which a test on a busy machine cannot judge (issue 39): the
# system's page missed 10 s beside other jobs, 100 participants took 7.8 s. `automotive bench monitor-page` measures
# them.
PAGE_S = 45.0
CROWD_S = 45.0
CROWD = 100
PAGE_LINE = r"the monitor's page: (http://\S+)"
URL_LINE = r"^automotive monitor: the page is on (http://\S+)$"
SCENE_ROWS = 60  # one row every 100 ms: a 6 s cycle
TALL_ROWS = range(20, 45)  # the tall truck leads for 2.5 s of it: the alert, then all clear
REASON = "reliability: offered BEST_EFFORT, requested RELIABLE (a RELIABLE reader matches only RELIABLE writers)"
RED = "rgb(198, 40, 40)"  # the page's --error: a flow that should move and does not
T = TypeVar("T")

# One participant named "twin" that writes and reads TwinTopic: two of these processes are two participants of one
# name (as two HMIs are), each matching the other.
TWIN_SCRIPT = r'''
import os, sys
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.qos import Policy, Qos
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from automotive.types.automotive import ShapeType
participant = DomainParticipant(int(sys.argv[1]), qos=Qos(Policy.EntityName("twin")))
topic = Topic(participant, "TwinTopic", ShapeType)
writer, reader = DataWriter(participant, topic), DataReader(participant, topic)
print(f"twin {os.getpid()}", flush=True)
sys.stdin.read()
'''

# Where the graph's edge labels lie over a node, another edge's label or another edge (cytoscape's model coordinates:
# each label's box as drawn, each edge as points along its line or quadratic bezier curve).
LABELS_CLEAR_JS = """
const cy = state.cy;
const overlap = (a, b) => a.x1 < b.x2 && b.x1 < a.x2 && a.y1 < b.y2 && b.y1 < a.y2;
const inside = (p, b) => p.x > b.x1 && p.x < b.x2 && p.y > b.y1 && p.y < b.y2;
const labelBox = (e) => e.boundingBox({includeNodes: false, includeEdges: false, includeLabels: true,
  includeOverlays: false});
const path = (e) => {
  const s = e.sourceEndpoint(), t = e.targetEndpoint(), c = e.controlPoints() || [];
  const points = [];
  for (let i = 0; i <= 50; i += 1) {
    const u = i / 50;
    points.push(c.length === 1
      ? {x: (1 - u) ** 2 * s.x + 2 * (1 - u) * u * c[0].x + u * u * t.x,
         y: (1 - u) ** 2 * s.y + 2 * (1 - u) * u * c[0].y + u * u * t.y}
      : {x: s.x + (t.x - s.x) * u, y: s.y + (t.y - s.y) * u});
  }
  return points;
};
const problems = [];
const labelled = cy.edges().filter((e) => e.data("label"));
const name = (e) => `${e.data("label")} ${e.source().data("label")} -> ${e.target().data("label")}`
  .replace(/\\n/g, " ");
labelled.forEach((e) => {
  const box = labelBox(e);
  cy.nodes().forEach((n) => { if (overlap(box, n.boundingBox())) problems.push(`${name(e)} over a node`); });
  labelled.forEach((f) => {
    if (f.id() > e.id() && overlap(box, labelBox(f))) problems.push(`${name(e)} over ${name(f)}`);
  });
  cy.edges().forEach((f) => {
    if (f.id() !== e.id() && path(f).some((p) => inside(p, box))) problems.push(`${name(e)} over edge ${name(f)}`);
  });
});
return {labels: labelled.length, problems};
"""


# -- the browser ------------------------------------------------------------------------------------------------------
@pytest.fixture
def browser(tmp_path: Path) -> Iterator[WebDriver]:
    """Debian's headless Chromium, as automotive bench monitor-page opens it."""
    try:
        with chromium(tmp_path / "chromium") as opened:
            yield opened
    except NoBrowser as missing:
        pytest.fail(str(missing))


def screenshot(browser: WebDriver, path: Path) -> Path:
    """The whole page (as tall as its content) as a PNG."""
    height = browser.execute_script("return document.documentElement.scrollHeight")
    browser.set_window_size(1600, max(900, min(int(height) + 40, 4000)))
    browser.save_screenshot(str(path))
    browser.set_window_size(1600, 1300)
    return path


def until(browser: WebDriver, check: Callable[[WebDriver], T], timeout: float, what: str, shot: Path) -> T:
    """``check`` again until it returns something true (bounded); on timeout, the screenshot and the page's text."""
    try:
        return WebDriverWait(browser, timeout, poll_frequency=0.1).until(check)  # type: ignore[no-any-return]
    except TimeoutException:
        screenshot(browser, shot)
        text = browser.execute_script("return document.body.innerText")
        raise AssertionError(f"the page did not show {what} within {timeout:g} s (screenshot {shot}); its text:\n"
                             f"{str(text)[:5000]}") from None


def flows(browser: WebDriver) -> dict[str, float]:
    """The flows table: topic -> samples/s (NaN where the page shows none)."""
    found: list[list[Any]] = browser.execute_script(
        "return [...document.querySelectorAll('#flows tbody tr[data-topic]')]"
        ".map((row) => [row.dataset.topic, Number(row.dataset.rate)])")
    return {topic: rate for topic, rate in found}


def page_state(browser: WebDriver) -> dict[str, Any]:
    state: dict[str, Any] = browser.execute_script("""
        const graph = document.getElementById('graph');
        return {status: document.getElementById('status').dataset.state,
                updates: Number(document.body.dataset.updates || 0),
                nodes: Number(graph.dataset.nodes), edges: Number(graph.dataset.edges),
                mismatchEdges: Number(graph.dataset.mismatchEdges || 0),
                participants: document.querySelectorAll('#participants tbody tr[data-name]').length,
                programs: Object.fromEntries([...document.querySelectorAll('#programs tbody tr[data-program]')]
                    .map((row) => [row.dataset.program, row.dataset.level])),
                matches: [...document.querySelectorAll('#matches tbody tr[data-topic]')]
                    .map((row) => [...row.cells].slice(0, 3).map((cell) => cell.textContent)),
                alert: document.getElementById('alert').dataset.state,
                alertText: document.getElementById('alert-text').textContent,
                speed: document.getElementById('speed').textContent,
                blinker: document.getElementById('blinker').textContent,
                fused: document.getElementById('fused').textContent};
    """)
    return state


# -- the monitor and the system ---------------------------------------------------------------------------------------
def get(url: str, headers: dict[str, str] | None = None) -> tuple[int, bytes]:
    request = urllib.request.Request(url, headers=headers or {})
    try:
        with urllib.request.urlopen(request, timeout=30) as response:
            return int(response.status), response.read()
    except urllib.error.HTTPError as error:
        return error.code, error.read()


def snapshot(url: str, following: bool = False) -> dict[str, Any]:
    """The monitor's latest snapshot (/snapshot.json, the token of ``url`` with it); ``following``: the next one."""
    base, _, query = url.partition("?")
    query = "&".join(part for part in (query, "next=1" if following else "") if part)
    status, body = get(f"{base}snapshot.json" + (f"?{query}" if query else ""))
    assert status == 200, body[:500]
    document: dict[str, Any] = json.loads(body)
    return document


def snapshot_until(url: str, check: Callable[[dict[str, Any]], bool], what: str,
                   timeout: float = TIMEOUT) -> dict[str, Any]:
    deadline = time.monotonic() + timeout
    while True:
        document = snapshot(url, following=True)  # each the next one: one a second
        if check(document):
            return document
        if time.monotonic() > deadline:
            raise AssertionError(f"the monitor did not see {what} within {timeout:g} s; last snapshot:\n"
                                 f"{json.dumps(document, indent=1)[:5000]}")


def start_monitor(runner: AppRunner, domain: int, *args: str) -> tuple[Child, str]:
    monitor = runner.start("monitor", "--domain", str(domain), "--port", "0", *args)
    line = monitor.wait_for(URL_LINE, timeout=TIMEOUT)
    match = re.search(URL_LINE, line)
    assert match is not None, line
    return monitor, match.group(1)


class System:
    def __init__(self, launcher: Child, url: str, domain: int):
        self.launcher = launcher
        self.url = url
        self.domain = domain


@pytest.fixture(scope="module")
def system(module_domain_id: int, tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    """``automotive launch --monitor`` on the module's domain, all but the camera, with a scene whose tall truck
    raises the alert for 2.5 s of every 6 s."""
    work = tmp_path_factory.mktemp("system")
    runner = AppRunner(work)
    data = scene(work / "scene.csv", SCENE_ROWS, TALL_ROWS)
    launcher = runner.start_command("automotive launch", program_command(
        "launch", "--mode", "background", "--domain", str(module_domain_id), "--monitor", "--monitor-port", "0",
        "--except", "camera_pub,camera_sub", "-D", f"vision:dataFile={data}", "--log-dir", str(work / "logs")),
        env={"DISPLAY": "", "WAYLAND_DISPLAY": ""})
    try:
        line = launcher.wait_for(rf"^launch\s+\| {PAGE_LINE}$", timeout=TIMEOUT)
        match = re.search(PAGE_LINE, line)
        assert match is not None, line
        launcher.wait_for(r"7 application\(s\) running", timeout=TIMEOUT)
        yield System(launcher, match.group(1), module_domain_id)
    finally:
        runner.stop_all()


def this_system(document: dict[str, Any]) -> bool:
    """Every program of the system reports, and its six flows have moved (another run of the suite on this host
    may use the same domain id: these are names, which that run's programs share, so the checks stay loose)."""
    moving = {flow["topic"] for flow in document["flows"] if (flow.get("rate") or 0) > 0}
    return set(PROGRAMS) <= {p["name"] for p in document["programs"]} and set(SIX_FLOWS[:-1]) <= moving


# -- the tests --------------------------------------------------------------------------------------------------------
def test_the_launched_system_shows_its_six_flows_moving_its_health_and_the_vehicle(
        system: System, browser: WebDriver, tmp_path: Path) -> None:
    snapshot_until(system.url, this_system, "the system's programs and flows")
    # The launcher says the page's URL once, in its own name.
    assert len(re.findall(PAGE_LINE, system.launcher.output)) == 1, system.launcher.output[-3000:]
    shot = tmp_path / "system.png"
    opened = time.monotonic()
    browser.get(system.url)
    seen: set[str] = set()  # the flows seen moving (the alert moves while it is raised, and in a burst when it ends)

    def six_flows_moving(page: WebDriver) -> bool:
        seen.update(topic for topic, rate in flows(page).items() if rate > 0)
        return set(SIX_FLOWS) <= seen

    until(browser, six_flows_moving, PAGE_S - (time.monotonic() - opened), "the six flows moving", shot)
    # Waited for, not asserted once: a report older than 5 s shows STALE, which is right on a machine that held
    # every program back that long (seen once in a loaded suite: all eight STALE at one moment, the monitor too).
    state = until(browser, lambda page: (lambda s: s if s["status"] == "live" and set(PROGRAMS) <= set(s["programs"])
                                         and all(s["programs"][name] in ("OK", "WARN") for name in PROGRAMS)
                                         else None)(page_state(page)),
                  PAGE_S - (time.monotonic() - opened), "every program's health OK or WARN", shot)
    assert time.monotonic() - opened <= PAGE_S
    pairs = {tuple(row) for row in state["matches"]}
    assert {("VisionTopic", "vision", "sensor_fusion"), ("rt/LidarTopic", "lidar", "sensor_fusion"),
            ("SensorObjects", "sensor_fusion", "collision_avoidance"), ("AlertTopic", "collision_avoidance", "hmi"),
            ("PlatformControl", "collision_avoidance", "vehicle_platform"),
            ("PlatformStatus", "vehicle_platform", "collision_avoidance")} <= pairs, pairs
    assert state["nodes"] >= len(PROGRAMS) and state["edges"] >= 6, state

    if "vehicle" not in snapshot(system.url):
        screenshot(browser, shot)
        pytest.skip("the snapshot has no 'vehicle' yet (the monitor's own readers): the vehicle is not checked")
    until(browser, lambda page: (lambda s: s["speed"] != "\u2014" and s["blinker"] != "\u2014"
                                 and s["fused"] != "\u2014")(page_state(page)),
          PAGE_S - (time.monotonic() - opened), "the vehicle's speed, blinker and fused objects", shot)
    # Collision avoidance raises the alert while the tall truck leads and clears it when the truck has gone.
    # The state the wait saw raised, read in one go (a second read may come after the page's next update, which
    # can have cleared it already: a loaded run read "none: all clear" there).
    raised = until(browser, lambda page: (lambda s: s if s["alert"] == "raised" else None)(page_state(page)), TIMEOUT,
                   "the alert raised", shot)
    assert "attention" in raised["alertText"].lower(), raised
    until(browser, lambda page: page_state(page)["alert"] == "clear", TIMEOUT, "the alert cleared", shot)
    until(browser, lambda page: page_state(page)["alert"] == "raised", TIMEOUT, "the alert raised again", shot)
    screenshot(browser, shot)


def test_at_1280_by_800_tables_fit_their_boxes_graph_labels_lie_clear_and_quiet_topics_are_not_red(
        system: System, browser: WebDriver, tmp_path: Path) -> None:
    snapshot_until(system.url, this_system, "the system's programs and flows")
    shot = tmp_path / "1280.png"
    browser.set_window_size(1280, 800)
    browser.get(system.url)
    until(browser, lambda page: (lambda s: s["status"] == "live" and s["nodes"] >= len(PROGRAMS) and s["edges"] >= 6
                                 and set(PROGRAMS) <= set(s["programs"]))(page_state(page)), TIMEOUT,
          "the system's graph and health", shot)
    # Every table inside its box: the box does not scroll sideways and the table is no wider than it.
    widths = browser.execute_script("""
        return [...document.querySelectorAll('table')].map((table) => {
          const box = table.closest('section');
          return [table.id, table.getBoundingClientRect().width, box.clientWidth, box.scrollWidth]; });""")
    too_wide = [row for row in widths if row[1] > row[2] or row[3] > row[2]]
    assert not too_wide, widths
    endpoints = browser.execute_script("return document.querySelectorAll('#endpoints tbody tr[data-topic]').length")
    assert endpoints >= 12, endpoints
    # The edges' labels cover no node, no other label and no other edge.
    labels = browser.execute_script(LABELS_CLEAR_JS)
    assert labels["labels"] >= 6 and labels["problems"] == [], labels
    # AlertTopic is written on a change (no deadline): at 0/s it is quiet, not red; the periodic flows move.
    def alert_topic_still(page: WebDriver) -> Any:
        return page.execute_script("""
            const row = document.querySelector('#flows tbody tr[data-topic="AlertTopic"]');
            return row && Number(row.dataset.rate) === 0 ? {className: row.className,
              colour: getComputedStyle(row.querySelector('td.rate')).color} : null;""")

    still = until(browser, alert_topic_still, TIMEOUT, "AlertTopic at 0 samples/s", shot)
    assert still["className"] == "quiet" and still["colour"] != RED, still
    classes = browser.execute_script("return Object.fromEntries([...document.querySelectorAll('#flows tbody tr"
                                     "[data-topic]')].map((row) => [row.dataset.topic, row.className]))")
    assert all(classes[topic] in ("moving", "still") for topic in SIX_FLOWS[:-1]), classes
    browser.save_screenshot(str(shot))


def test_two_participants_of_one_name_are_told_apart_by_their_pids_in_the_graph_and_the_lists(
        system: System, browser: WebDriver, tmp_path: Path) -> None:
    runner = AppRunner(tmp_path)
    shot = tmp_path / "twins.png"
    try:
        pids = []
        for _ in range(2):
            twin = runner.start_command("twin", [sys.executable, "-c", TWIN_SCRIPT, str(system.domain)], stdin=True)
            line = twin.wait_for(r"^twin \d+$", timeout=TIMEOUT)
            pids.append(line.split()[1])
        labels = {f"twin (pid {pid})" for pid in pids}
        browser.get(system.url)

        def twins_shown(page: WebDriver) -> Any:
            shown = page.execute_script("""
                return {participants: [...document.querySelectorAll('#participants tbody tr[data-name="twin"]')]
                          .map((row) => row.cells[0].textContent),
                        nodes: state.cy ? state.cy.nodes().map((node) => node.data('label').split('\\n')[0])
                          .filter((label) => label.startsWith('twin')) : [],
                        matches: [...document.querySelectorAll('#matches tbody tr[data-topic="TwinTopic"]')]
                          .map((row) => [...row.cells].slice(1, 3).map((cell) => cell.textContent)),
                        endpoints: [...document.querySelectorAll('#endpoints tbody tr[data-topic="TwinTopic"]')]
                          .map((row) => row.cells[2].textContent)};""")
            return shown if len(shown["participants"]) == 2 and len(shown["matches"]) >= 2 else None

        shown = until(browser, twins_shown, TIMEOUT, "the two participants named twin", shot)
        assert set(shown["participants"]) == labels, (shown, labels)
        assert set(shown["nodes"]) == labels, (shown, labels)
        one, other = sorted(labels)  # each writes to the other (and to itself)
        assert {(one, other), (other, one)} <= {tuple(pair) for pair in shown["matches"]}, shown
        assert set(shown["endpoints"]) == labels, shown
        screenshot(browser, shot)
    finally:
        runner.stop_all()


def latency_state(browser: WebDriver) -> dict[str, Any]:
    """The latency panel: per topic and per pair the cells' texts, and the alert chain's box."""
    state: dict[str, Any] = browser.execute_script("""
        const rows = (id) => [...document.querySelectorAll(`#${id} tbody tr[data-topic]`)]
            .map((row) => [...[...row.cells].map((cell) => cell.textContent), row.dataset.clock]);
        const chain = document.getElementById('chain');
        return {topics: rows('latency-topics'), pairs: rows('latency-pairs'), chainClock: chain.dataset.clock,
                chainComplete: chain.dataset.complete, chainTotal: document.getElementById('chain-total').textContent,
                chainHops: document.getElementById('chain-hops').textContent,
                chainBasis: document.getElementById('chain-basis').textContent};
    """)
    return state


def test_the_page_shows_the_latency_of_each_topic_each_pair_and_the_alert_chain(
        system: System, browser: WebDriver, tmp_path: Path) -> None:
    snapshot_until(system.url, this_system, "the system's programs and flows")
    shot = tmp_path / "latency.png"
    browser.get(system.url)
    exact = r"^\d[\d,]*(\.\d+)? ms$"  # one host: no "~"

    def latencies_shown(page: WebDriver) -> dict[str, Any] | None:
        state = latency_state(page)
        topics = {(row[0], row[1]): row for row in state["topics"]}
        pairs = {(row[0], row[1], row[2]): row for row in state["pairs"]}
        wanted_topics = [("VisionTopic", "sensor_fusion"), ("SensorObjects", "collision_avoidance"),
                         ("AlertTopic", "hmi"), ("rt/LidarTopic", "sensor_fusion")]
        wanted_pairs = [("VisionTopic", "vision", "sensor_fusion"), ("AlertTopic", "collision_avoidance", "hmi")]
        if not (all(key in topics for key in wanted_topics) and all(key in pairs for key in wanted_pairs)
                and state["chainComplete"] == "true"):
            return None
        return {"state": state, "topics": [topics[key] for key in wanted_topics],
                "pairs": [pairs[key] for key in wanted_pairs]}

    shown = until(browser, latencies_shown, TIMEOUT, "the latency of the alert chain's topics, pairs and sum", shot)
    for row in shown["topics"]:  # topic, reader, p50, p99, samples, clock words, data-clock
        assert re.match(exact, row[2]) and re.match(exact, row[3]) and int(row[4].replace(",", "")) > 0, row
        assert row[5] == "shared (one host)" and row[6] == "shared", row
    for row in shown["pairs"]:  # topic, writer, reader, p50, p99, samples, clock words, data-clock
        assert re.match(exact, row[3]) and re.match(exact, row[4]) and row[7] == "shared", row
    state = shown["state"]
    assert re.match(r"^p50 \d[\d,]*(\.\d+)? ms, p99 \d[\d,]*(\.\d+)? ms$", state["chainTotal"]), state
    assert state["chainClock"] == "shared" and "VisionTopic" in state["chainHops"] and "sum" in state["chainBasis"]
    screenshot(browser, shot)


def test_an_rti_reader_requesting_reliable_from_best_effort_vision_shows_its_reason_in_words(
        system: System, browser: WebDriver, tmp_path: Path) -> None:
    from rti_peer import RtiPeer

    shot = tmp_path / "rti-mismatch.png"
    with RtiPeer(system.domain, readers={"Vision": "ReliableReader"}):
        browser.get(system.url)

        def rti_mismatch(page: WebDriver) -> Any:
            found = page.execute_script("""
                for (const box of document.querySelectorAll('#mismatches .mismatch[data-topic="VisionTopic"]')) {
                  if (box.dataset.writer === 'vision' && box.querySelector('.pair').textContent.includes('(RTI)')) {
                    return {pair: box.querySelector('.pair').textContent,
                            reasons: [...box.querySelectorAll('li.reason')].map((li) => li.textContent)};
                  }
                }
                return null;""")
            return found if found and page_state(page)["mismatchEdges"] >= 1 else None

        found = until(browser, rti_mismatch, TIMEOUT, "the RTI reader's mismatch", shot)
        assert found["reasons"] == [REASON], found
        assert re.match(r"VisionTopic: writer vision \(Cyclone\) \u2192 reader .+ \(RTI\) do not match$",
                        found["pair"]), found
        notices = browser.execute_script(
            "return [...document.querySelectorAll('#notices li')].map((li) => [li.dataset.kind, li.textContent])")
        assert any(kind == "reader matched no writer" and "VisionTopic" in text for kind, text in notices), notices
        # The Hints box explains the mismatch (what to change), rather than saying "none" beside it.
        hints = browser.execute_script("return [...document.querySelectorAll('#hints li')].map((li) => "
                                       "[li.dataset.kind, li.dataset.topic, li.textContent])")
        assert any(kind == "mismatch" and topic == "VisionTopic" and "make the writer RELIABLE" in text
                   for kind, topic, text in hints), hints
        participants = browser.execute_script(
            "return [...document.querySelectorAll('#participants tbody tr[data-vendor]')].map((r) => r.dataset.vendor)")
        assert "RTI Connext DDS" in participants
        wanted = os.environ.get("AUTOMOTIVE_MONITOR_SCREENSHOT")
        if wanted:  # the user's guide's picture: the first screen of the page
            browser.execute_script("window.scrollTo(0, 0)")
            browser.save_screenshot(wanted)
        screenshot(browser, shot)


def test_a_domain_of_100_participants_renders_once_the_page_is_opened(
        domain_id: int, browser: WebDriver, tmp_path: Path) -> None:
    runner = AppRunner(tmp_path)
    try:
        crowd = runner.start_command("crowd", [sys.executable, "-c", CROWD_SCRIPT, str(domain_id), str(CROWD)],
                                     stdin=True)
        crowd.wait_for(rf"crowd of {CROWD} participants", timeout=TIMEOUT)
        _, url = start_monitor(runner, domain_id)
        snapshot_until(url, lambda d: sum(p["name"].startswith("crowd-") for p in d["participants"]) >= CROWD,
                       f"the {CROWD} participants")
        shot = tmp_path / "crowd.png"
        opened = time.monotonic()
        browser.get(url)
        state = until(browser, lambda page: (lambda s: s if s["nodes"] > CROWD and s["participants"] > CROWD
                                             else None)(page_state(page)), CROWD_S, f"{CROWD} participants", shot)
        took = time.monotonic() - opened
        print(f"{CROWD} participants rendered {took:.2f} s after opening the page")
        screenshot(browser, shot)
        assert took <= CROWD_S, f"{took:.2f} s"
        assert state["status"] == "live"
    finally:
        runner.stop_all()


def test_binding_beyond_loopback_needs_a_token_and_every_request_then_carries_it(
        domain_id: int, browser: WebDriver, tmp_path: Path) -> None:
    refused = subprocess.run(program_command("monitor", "--domain", str(domain_id), "--bind", "0.0.0.0"),
                             capture_output=True, text=True, timeout=60)
    assert refused.returncode == 2 and refused.stdout == "", refused
    assert re.fullmatch(r"automotive monitor: --bind 0\.0\.0\.0: serving beyond this host needs --token T .*\n",
                        refused.stderr), refused.stderr

    runner = AppRunner(tmp_path)
    try:
        _, url = start_monitor(runner, domain_id, "--bind", "0.0.0.0", "--token", "s3cret-t0ken")
        base = url.partition("?")[0]
        assert url == f"{base}?token=s3cret-t0ken" and base.startswith("http://127.0.0.1:")
        for path in ("", "static/app.js", "snapshot.json", "ws"):
            assert get(base + path)[0] == 403, path
            assert get(f"{base}{path}?token=wrong")[0] == 403, path
        status, body = get(url)
        assert status == 200 and b"automotive monitor" in body
        status, body = get(base + "snapshot.json", {"Authorization": "Bearer s3cret-t0ken"})
        assert status == 200 and json.loads(body)["domain"] == domain_id
        # The browser: the page with the token, then its files and its WebSocket by the cookie the page set.
        shot = tmp_path / "token.png"
        browser.get(url)
        until(browser, lambda page: page_state(page)["status"] == "live" and page_state(page)["updates"] >= 2,
              PAGE_S, "live snapshots", shot)
        screenshot(browser, shot)
        browser.get(base)  # the cookie stands for the token
        until(browser, lambda page: page_state(page)["status"] == "live", PAGE_S, "live snapshots by the cookie", shot)
        browser.delete_all_cookies()
        browser.get(base)
        assert "403" in browser.execute_script("return document.body.innerText")
    finally:
        runner.stop_all()


def test_a_loopback_page_refuses_other_host_names_and_websockets_of_other_origins(system: System,
                                                                                 tmp_path: Path) -> None:
    assert get(system.url)[0] == 200
    port = system.url.split(":")[2].strip("/")
    assert get(system.url, {"Host": f"attacker.example:{port}"})[0] == 403  # DNS rebinding
    assert get(system.url, {"Host": f"localhost:{port}"})[0] == 200
    upgrade = {"Connection": "Upgrade", "Upgrade": "websocket", "Sec-WebSocket-Version": "13",
               "Sec-WebSocket-Key": "dGhlIHNhbXBsZSBub25jZQ=="}
    assert get(system.url + "ws", {**upgrade, "Origin": "http://attacker.example"})[0] == 403
    assert get(system.url + "static/../server.py")[0] == 404
