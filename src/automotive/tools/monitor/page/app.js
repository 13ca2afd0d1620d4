// The page of `automotive monitor`: each WebSocket message is one snapshot (the JSON of `automotive monitor --json`),
// at most one a second; this fills the panels from it. Every text from the domain (names of any length, from any
// system) goes in as text (textContent), never as HTML, and is cut for display (the full text in the tooltip).
// A field the snapshot does not carry shows "—".
"use strict";

const DASH = "\u2014";
const NAME_CUT = 60;
const TEXT_CUT = 300;
const TITLE_CUT = 2000;
const GRID_ABOVE = 40; // participants: above this many the graph is a grid, else writers above their readers
const LATE_S = 3; // no snapshot for this long: the status says "late"
const DIAGNOSTICS_TOPIC = "rt/diagnostics";
const MAX_FIT_ZOOM = 1.2; // a graph of a few nodes is not blown up to the panel's size
const VENDORS = {"Eclipse Cyclone DDS": "Cyclone", "RTI Connext DDS": "RTI", "eProsima Fast DDS": "Fast DDS"};
const VENDOR_COLOURS = {"Cyclone": "#1565c0", "RTI": "#6a1b9a", "Fast DDS": "#00838f"};
const HEALTH_COLOURS = {OK: "#2e7d32", WARN: "#ef8f00", ERROR: "#c62828", STALE: "#757575"};

const state = {snapshot: null, receivedAt: 0, socket: null, cy: null, graphKey: "", lidarAt: null, updates: 0};

// -- small helpers ---------------------------------------------------------------------------------------------------
function cut(text, width) {
  if (text === null || text === undefined) return DASH;
  const line = String(text).replace(/[\u0000-\u001f\u007f]/g, "?");
  return line.length <= width ? line : line.slice(0, width - 1) + "\u2026";
}

function el(tag, text, attributes) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) {
    const full = String(text);
    node.textContent = cut(full, TEXT_CUT);
    if (full.length > TEXT_CUT) node.title = cut(full, TITLE_CUT);
  }
  for (const [key, value] of Object.entries(attributes || {})) {
    if (value === undefined || value === null) continue;
    if (key === "className") node.className = value;
    else node.setAttribute(key, value);
  }
  return node;
}

function name(text) { // a name, cut short, the whole in the tooltip
  const node = el("span", null);
  node.textContent = cut(text, NAME_CUT);
  if (text && String(text).length > NAME_CUT) node.title = cut(text, TITLE_CUT);
  return node;
}

function cell(content, className) {
  const td = document.createElement("td");
  if (className) td.className = className;
  if (content instanceof Node) td.appendChild(content);
  else td.textContent = content === null || content === undefined || content === "" ? DASH : String(content);
  return td;
}

function row(cells, attributes) {
  const tr = el("tr", null, attributes);
  for (const item of cells) tr.appendChild(item instanceof HTMLTableCellElement ? item : cell(item));
  return tr;
}

function fill(tableId, rows, emptyText, columns) {
  const body = document.querySelector(`#${tableId} tbody`);
  if (!rows.length) {
    const td = cell(emptyText, "none");
    td.colSpan = columns;
    body.replaceChildren(row([td]));
  } else {
    body.replaceChildren(...rows);
  }
}

function number(value, digits) {
  if (value === null || value === undefined || Number.isNaN(Number(value))) return DASH;
  const n = Number(value);
  return n.toLocaleString("en-US", {maximumFractionDigits: digits === undefined ? 1 : digits});
}

function numberCell(value, digits) {
  const td = cell(number(value, digits), "number");
  if (value === 0) td.classList.add("zero");
  return td;
}

function bytes(value) {
  if (value === null || value === undefined) return DASH;
  const n = Number(value);
  if (n >= 1e6) return `${(n / 1e6).toFixed(2)} MB`;
  if (n >= 1e3) return `${(n / 1e3).toFixed(1)} kB`;
  return `${n.toFixed(0)} B`;
}

function seconds(value) {
  return value === null || value === undefined ? DASH : `${number(value)} s ago`;
}

function levelBadge(level) {
  return el("span", level || DASH, {className: `level ${level || "none"}`});
}

function shortVendor(vendor) { return VENDORS[vendor] || vendor || "unknown"; }

function rates(map) { // {"vision": 10.0} -> "vision 10"
  const entries = Object.entries(map || {});
  return entries.length ? entries.map(([who, rate]) => `${cut(who, NAME_CUT)} ${number(rate)}`).join(", ") : DASH;
}

// -- the panels ------------------------------------------------------------------------------------------------------
function renderHeader(snapshot) {
  document.getElementById("domain").textContent = `domain ${snapshot.domain}`;
  const count = (list) => (list || []).length;
  document.getElementById("summary").textContent =
    `${count(snapshot.participants)} participants, ${count(snapshot.topics)} topics, ` +
    `${count(snapshot.matches)} matched pairs, ${count(snapshot.mismatches)} mismatches · ${snapshot.taken_at}`;
}

function renderVehicle(vehicle) {
  const v = vehicle || {};
  const alert = document.getElementById("alert");
  const text = document.getElementById("alert-text");
  const owner = document.getElementById("alert-owner");
  if (!Array.isArray(v.alert)) {
    alert.dataset.state = "unknown";
    text.textContent = DASH;
  } else if (v.alert.length) {
    alert.dataset.state = "raised";
    text.textContent = (v.alert_texts && v.alert_texts.length ? v.alert_texts : v.alert).join(", ");
  } else {
    alert.dataset.state = "clear";
    text.textContent = "none: all clear";
  }
  alert.dataset.alerts = Array.isArray(v.alert) ? v.alert.join(",") : "";
  owner.textContent = v.redundant || v.alert_owner
    ? `owner: ${cut(v.alert_owner, NAME_CUT)}` +
      (v.alert_owner_strength !== null && v.alert_owner_strength !== undefined
        ? ` (strength ${v.alert_owner_strength})` : "")
    : "";
  const unit = (value, suffix, digits) => value === null || value === undefined ? DASH
    : `${number(value, digits)}${suffix}`;
  document.getElementById("speed").textContent = unit(v.speed_kmh, " km/h");
  document.getElementById("steer").textContent = unit(v.steer_angle, "", 2);
  document.getElementById("blinker").textContent = v.blinker || DASH;
  document.getElementById("fused").textContent = unit(v.fused_objects, "", 0);
  const command = [];
  if (v.command_speed !== null && v.command_speed !== undefined) command.push(`speed ${number(v.command_speed)}`);
  if (v.command_steer_angle !== null && v.command_steer_angle !== undefined) {
    command.push(`steer ${number(v.command_steer_angle, 2)}`);
  }
  if (v.command_blinker) command.push(`blinker ${v.command_blinker}`);
  document.getElementById("command").textContent = command.length ? command.join(", ") : DASH;
  const camera = [];
  if (v.camera_rate !== null && v.camera_rate !== undefined) camera.push(`${number(v.camera_rate)} frames/s`);
  if (v.camera_latency_ms !== null && v.camera_latency_ms !== undefined) {
    camera.push(`latency p50 ${number(v.camera_latency_ms)} ms`);
  }
  if (camera.length && v.camera_program) camera.push(`(${cut(v.camera_program, NAME_CUT)})`);
  document.getElementById("camera").textContent = camera.length ? camera.join(" ") : DASH;
  const lidarFacts = [];
  if (v.lidar_points !== null && v.lidar_points !== undefined) lidarFacts.push(`${number(v.lidar_points, 0)} points`);
  if (v.lidar_age_s !== null && v.lidar_age_s !== undefined) lidarFacts.push(`cloud ${seconds(v.lidar_age_s)}`);
  document.getElementById("lidar-facts").textContent = lidarFacts.length ? lidarFacts.join(", ") : DASH;
  const image = document.getElementById("lidar");
  const none = document.getElementById("lidar-none");
  const at = v.lidar_image_at;
  if (at === null || at === undefined) {
    image.hidden = true;
    none.hidden = false;
  } else if (at !== state.lidarAt) { // a new cloud: at most one a second (the monitor keeps one a second)
    state.lidarAt = at;
    const token = new URLSearchParams(location.search).get("token");
    image.src = `lidar.png?at=${encodeURIComponent(at)}` + (token ? `&token=${encodeURIComponent(token)}` : "");
    image.hidden = false;
    none.hidden = true;
  }
}

function renderPrograms(programs) {
  fill("programs", (programs || []).map((p) => row([
    cell(name(p.name)), cell(levelBadge(p.level)), cell(name(p.host)), cell(p.pid),
    cell(seconds(p.report_age_s)), cell(p.message)], {"data-program": cut(p.name, TITLE_CUT),
    "data-level": p.level})), "no program reports on rt/diagnostics", 6);
}

function renderFlows(flows) {
  fill("flows", (flows || []).map((f) => {
    const rate = f.rate;
    const moving = typeof rate === "number" && rate > 0;
    // Red only where data is expected all the time (a deadline): a topic written on change is quiet by design.
    const look = moving ? "moving" : f.periodic ? "still" : "quiet";
    const rateCell = numberCell(rate, 1);
    rateCell.classList.add("rate");
    const tr = row([cell(name(f.topic)), rateCell, cell(bytes(f.bytes_per_s), "number bytes"),
      cell(seconds(f.last_sample_age_s), "age"), cell(rates(f.writers)), cell(rates(f.readers)),
      numberCell(f.deadline_missed, 0), numberCell(f.liveliness_changes, 0), numberCell(f.samples_lost, 0),
      numberCell(f.incompatible_qos, 0)], {"data-topic": cut(f.topic, TITLE_CUT), "data-rate": rate,
      className: look});
    return tr;
  }), "no flow reported yet", 10);
}

// A latency in ms; "~" in front when writer and reader do not share a clock (another host, or a host not known).
function latencyText(value, clock) {
  if (value === null || value === undefined) return DASH;
  return `${clock === "shared" ? "" : "~"}${number(value, 2)} ms`;
}

function clockWords(clock) {
  if (clock === "shared") return "shared (one host)";
  if (clock === "not shared") return "not shared: another host";
  return "host not known";
}

function latencyCells(figure) {
  const p50 = cell(latencyText(figure.p50_ms, figure.clock), "number p50");
  const p99 = cell(latencyText(figure.p99_ms, figure.clock), "number p99");
  for (const td of [p50, p99]) if (figure.clock !== "shared") td.classList.add("unsynced");
  return [p50, p99, numberCell(figure.samples, 0), cell(clockWords(figure.clock), "clock")];
}

function renderLatency(snapshot) {
  const topicRows = [];
  for (const f of snapshot.flows || []) {
    for (const [reader, figure] of Object.entries(f.latency || {})) {
      topicRows.push(row([cell(name(f.topic)), cell(name(reader)), ...latencyCells(figure)],
        {"data-topic": cut(f.topic, TITLE_CUT), "data-reader": cut(reader, TITLE_CUT), "data-clock": figure.clock}));
    }
  }
  fill("latency-topics", topicRows, "no program reports a latency yet", 6);
  fill("latency-pairs", (snapshot.latencies || []).map((l) => row([cell(name(l.topic)), cell(name(l.writer)),
    cell(name(l.reader)), ...latencyCells(l)], {"data-topic": cut(l.topic, TITLE_CUT),
    "data-writer": cut(l.writer, TITLE_CUT), "data-reader": cut(l.reader, TITLE_CUT), "data-clock": l.clock})),
  "no program reports a latency yet", 7);
  const chain = snapshot.chain;
  const box = document.getElementById("chain");
  const total = document.getElementById("chain-total");
  if (!chain) {
    box.dataset.clock = "unknown";
    total.textContent = DASH;
    return;
  }
  box.dataset.clock = chain.clock;
  const missing = chain.missing || [];
  total.textContent = chain.p50_ms === null || chain.p50_ms === undefined ? "unknown (no hop reports)"
    : `p50 ${latencyText(chain.p50_ms, chain.clock)}, p99 ${latencyText(chain.p99_ms, chain.clock)}` +
      (missing.length ? `, without ${missing.join(", ")} (no sample in the last 10 s)` : "");
  box.dataset.complete = missing.length ? "false" : "true";
  document.getElementById("chain-hops").textContent = "(" + (chain.hops || []).map((hop) =>
    `${cut(hop.topic, NAME_CUT)} ` + (hop.latency ? `${latencyText(hop.latency.p50_ms, hop.latency.clock)}/` +
      `${latencyText(hop.latency.p99_ms, hop.latency.clock)}` : DASH)).join(" + ") + ")";
  document.getElementById("chain-basis").textContent = chain.basis || "";
}

function endpointOwners(snapshot) {
  const owner = new Map();
  for (const e of snapshot.endpoints || []) owner.set(e.key, e.participant);
  return owner;
}

// Participant key -> its label: the name, with the pid or host where another participant has the same name.
function labelsOf(snapshot) {
  const label = new Map();
  for (const p of snapshot.participants || []) label.set(p.key, p.label || p.name);
  return label;
}

// An endpoint's participant's label (the name the snapshot gives with the pair when it is not known).
function ownerLabel(owners, labels, endpoint, fallback) {
  return labels.get(owners.get(endpoint)) || fallback;
}

function vendorOf(snapshot) {
  const vendor = new Map();
  for (const p of snapshot.participants || []) vendor.set(p.key, p.vendor);
  return vendor;
}

function renderAnalysis(snapshot) {
  const owner = endpointOwners(snapshot);
  const labels = labelsOf(snapshot);
  const vendor = vendorOf(snapshot);
  const writerOf = (m) => ownerLabel(owner, labels, m.writer, m.writer_participant);
  const readerOf = (m) => ownerLabel(owner, labels, m.reader, m.reader_participant);
  const box = document.getElementById("mismatches");
  const items = (snapshot.mismatches || []).map((m) => {
    const div = el("div", null, {className: "mismatch", "data-topic": cut(m.topic, TITLE_CUT),
      "data-reader": cut(m.reader_participant, TITLE_CUT), "data-writer": cut(m.writer_participant, TITLE_CUT)});
    const pair = el("div", null, {className: "pair"});
    pair.append(name(m.topic), ": writer ", name(writerOf(m)),
      ` (${shortVendor(vendor.get(owner.get(m.writer)))}) \u2192 reader `, name(readerOf(m)),
      ` (${shortVendor(vendor.get(owner.get(m.reader)))}) do not match`);
    div.appendChild(pair);
    const list = el("ul");
    for (const r of m.reasons || []) {
      const li = el("li", null, {className: "reason", "data-policy": r.policy});
      li.append(el("span", r.policy, {className: "policy"}), ": offered ",
        el("span", r.offered, {className: "offered"}), ", requested ",
        el("span", r.requested, {className: "requested"}), " ", el("span", `(${r.rule})`, {className: "rule"}));
      li.title = cut(r.words, TITLE_CUT);
      list.appendChild(li);
    }
    for (const hint of m.hints || []) list.appendChild(el("li", `hint: ${hint}`, {className: "hint"}));
    div.appendChild(list);
    return div;
  });
  if (items.length) box.replaceChildren(...items);
  else box.replaceChildren(el("p", "No mismatch: every writer and reader of one topic match.", {className: "none"}));

  const notices = (snapshot.notices || []).map((n) => el("li", n.words, {"data-kind": n.kind,
    "data-topic": n.topic === null ? null : cut(n.topic, TITLE_CUT)}));
  const noticeList = document.getElementById("notices");
  if (notices.length) noticeList.replaceChildren(...notices);
  else noticeList.replaceChildren(el("li", "none", {className: "none"}));

  const hints = [];
  for (const p of snapshot.participants || []) {
    for (const hint of p.hints || []) {
      hints.push(el("li", `${cut(p.label || p.name, NAME_CUT)}: ${hint}`, {className: "hint"}));
    }
  }
  // The mismatches' hints too (what to change), beside those of matched pairs: the box never says "none" beside a
  // mismatch it can explain.
  for (const [list, kind] of [[snapshot.mismatches, "mismatch"], [snapshot.matches, "match"]]) {
    for (const m of list || []) {
      for (const hint of m.hints || []) {
        hints.push(el("li", `${cut(m.topic, NAME_CUT)} ${cut(writerOf(m), NAME_CUT)} \u2192 ` +
          `${cut(readerOf(m), NAME_CUT)}: ${hint}`, {className: "hint", "data-kind": kind,
          "data-topic": cut(m.topic, TITLE_CUT)}));
      }
    }
  }
  const hintList = document.getElementById("hints");
  if (hints.length) hintList.replaceChildren(...hints);
  else hintList.replaceChildren(el("li", "none", {className: "none"}));
}

function renderMatches(snapshot) {
  const owner = endpointOwners(snapshot);
  const labels = labelsOf(snapshot);
  fill("matches", (snapshot.matches || []).map((m) => row([cell(name(m.topic)),
    cell(name(ownerLabel(owner, labels, m.writer, m.writer_participant))),
    cell(name(ownerLabel(owner, labels, m.reader, m.reader_participant))), cell((m.hints || []).join("; "))],
  {"data-topic": cut(m.topic, TITLE_CUT)})),
  "no matched pair", 4);
}

function renderParticipants(snapshot) {
  fill("participants", (snapshot.participants || []).map((p) => row([
    cell(name((p.label || p.name) + (p.own ? " (this monitor)" : ""))), cell(`${p.vendor} (${p.vendor_id})`),
    cell(name(p.host)),
    cell(p.pid), cell(name(p.process)), cell(p.health ? levelBadge(p.health) : DASH),
    cell((p.writers || []).length, "number"), cell((p.readers || []).length, "number")],
  {"data-name": cut(p.name, TITLE_CUT), "data-vendor": p.vendor})), "no participant seen yet", 8);
}

function renderTopics(snapshot) {
  fill("topics", (snapshot.topics || []).map((t) => row([cell(name(t.name)), cell((t.type_names || []).join(", ")),
    cell((t.writers || []).length, "number"), cell((t.readers || []).length, "number")],
  {"data-topic": cut(t.name, TITLE_CUT)})), "no topic seen yet", 4);
}

function renderEndpoints(snapshot) {
  const labels = labelsOf(snapshot);
  fill("endpoints", (snapshot.endpoints || []).map((e) => {
    const q = e.qos || {};
    return row([cell(name(e.topic)), cell(e.kind), cell(name(labels.get(e.participant) || e.participant_name)),
      cell(name(e.type_name)),
      cell(q.reliability), cell(q.durability), cell(q.deadline), cell(q.latency_budget),
      cell(q.liveliness === undefined ? DASH : `${q.liveliness}, lease ${q.lease_duration}`),
      cell(q.ownership === "EXCLUSIVE" ? `EXCLUSIVE (strength ${q.ownership_strength})` : q.ownership),
      cell((q.partitions || []).map((x) => `'${x}'`).join(", ") || "''"),
      cell((q.data_representation || []).join("/")), cell(q.history), cell((e.matched || []).length, "number")],
    {"data-topic": cut(e.topic, TITLE_CUT), "data-kind": e.kind});
  }), "no writer or reader seen yet", 14);
}

// -- the graph -------------------------------------------------------------------------------------------------------
function graphElements(snapshot) {
  const owner = endpointOwners(snapshot);
  const nodes = (snapshot.participants || []).map((p) => {
    const vendor = shortVendor(p.vendor);
    return {group: "nodes", data: {id: `p:${p.key}`, label: `${cut(p.label || p.name, 28)}\n${cut(vendor, 20)}`,
      colour: HEALTH_COLOURS[p.health] || VENDOR_COLOURS[vendor] || "#546e7a", own: p.own ? "yes" : "no"}};
  });
  // This monitor's own readers match every flow: their edges would hide the system's (the tables list them).
  const own = new Set((snapshot.participants || []).filter((p) => p.own).map((p) => `p:${p.key}`));
  const known = new Set(nodes.map((n) => n.data.id).filter((id) => !own.has(id)));
  const edges = new Map();
  const add = (list, kind) => {
    for (const m of list || []) {
      if (m.topic === DIAGNOSTICS_TOPIC) continue; // every program's: edges to every monitor, no data flow
      const from = `p:${owner.get(m.writer)}`;
      const to = `p:${owner.get(m.reader)}`;
      if (!known.has(from) || !known.has(to) || from === to) continue; // a participant's own pairs: the tables'
      const id = `${kind}|${from}|${to}|${m.topic}`;
      if (!edges.has(id)) {
        edges.set(id, {group: "edges", data: {id, source: from, target: to, label: cut(m.topic, 28), kind}});
      }
    }
  };
  add(snapshot.matches, "match");
  add(snapshot.mismatches, "mismatch");
  return {nodes, edges: [...edges.values()]};
}

function makeGraph() {
  if (typeof cytoscape !== "function") return null;
  return cytoscape({
    container: document.getElementById("graph"),
    minZoom: 0.1, maxZoom: 4,
    style: [
      {selector: "node", style: {"label": "data(label)", "text-wrap": "wrap", "text-valign": "center",
        "text-halign": "center", "shape": "round-rectangle", "width": 150, "height": 40,
        "background-color": "data(colour)", "color": "#fff", "font-size": 13, "border-width": 0}},
      {selector: "node[own = 'yes']", style: {"border-width": 3, "border-style": "dashed", "border-color": "#1f2a37"}},
      // Edge labels level, on an opaque box, moved off other edges and nodes by placeLabels.
      {selector: "edge", style: {"curve-style": "bezier", "control-point-step-size": 60,
        "target-arrow-shape": "triangle", "width": 2, "label": "data(label)", "font-size": 11,
        "text-background-color": "#fff", "text-background-opacity": 1, "text-background-padding": 2,
        "text-background-shape": "roundrectangle", "text-rotation": "none", "line-color": "#2e7d32",
        "target-arrow-color": "#2e7d32", "z-compound-depth": "top"}},
      {selector: "edge[kind = 'mismatch']", style: {"line-color": "#c62828", "target-arrow-color": "#c62828",
        "line-style": "dashed", "color": "#c62828"}},
    ],
  });
}

// Geometry of the drawn graph (model coordinates), for placeLabels.
function overlaps(a, b) { return a.x1 < b.x2 && b.x1 < a.x2 && a.y1 < b.y2 && b.y1 < a.y2; }

function edgePath(edge) { // points along the drawn edge: a line, or the quadratic curve of a bezier edge
  const s = edge.sourceEndpoint(), t = edge.targetEndpoint(), c = edge.controlPoints() || [];
  const points = [];
  for (let i = 0; i <= 40; i += 1) {
    const u = i / 40;
    points.push(c.length === 1
      ? {x: (1 - u) ** 2 * s.x + 2 * (1 - u) * u * c[0].x + u * u * t.x,
        y: (1 - u) ** 2 * s.y + 2 * (1 - u) * u * c[0].y + u * u * t.y}
      : {x: s.x + (t.x - s.x) * u, y: s.y + (t.y - s.y) * u});
  }
  return points;
}

function labelBox(edge) {
  return edge.boundingBox({includeNodes: false, includeEdges: false, includeLabels: true, includeOverlays: false});
}

// Each edge's label where it covers no node, no label placed before it and no other edge: in the middle of its
// edge, else beside or above/below it (the first free place; else the least covered). Once per layout, not per
// snapshot: a few hundred box tests for a system's graph.
function placeLabels(cy) {
  const edges = cy.edges().filter((edge) => edge.data("label"));
  edges.style({"text-margin-x": 0, "text-margin-y": 0});
  const nodeBoxes = cy.nodes().map((node) => node.boundingBox());
  const paths = new Map(cy.edges().map((edge) => [edge.id(), edgePath(edge)]));
  const placed = [];
  edges.forEach((edge) => {
    const at = labelBox(edge);
    const w = at.w / 2 + 6, h = at.h / 2 + 6;
    let best = null;
    const places = [[0, 0]];
    for (const k of [1, 2]) {
      places.push([k * w, 0], [-k * w, 0], [0, -k * h], [0, k * h], [k * w, -k * h], [-k * w, -k * h], [k * w, k * h],
        [-k * w, k * h]);
    }
    for (const [dx, dy] of places) {
      const box = {x1: at.x1 + dx, x2: at.x2 + dx, y1: at.y1 + dy, y2: at.y2 + dy};
      let covered = nodeBoxes.filter((other) => overlaps(box, other)).length
        + placed.filter((other) => overlaps(box, other)).length;
      for (const [id, points] of paths) {
        if (id !== edge.id() && points.some((p) => p.x > box.x1 && p.x < box.x2 && p.y > box.y1 && p.y < box.y2)) {
          covered += 1;
        }
      }
      if (best === null || covered < best.covered) best = {covered, dx, dy, box};
      if (covered === 0) break;
    }
    edge.style({"text-margin-x": best.dx, "text-margin-y": best.dy});
    placed.push(best.box);
  });
}

function renderGraph(snapshot) {
  if (!state.cy) state.cy = makeGraph();
  const cy = state.cy;
  const box = document.getElementById("graph");
  if (!cy) {
    box.textContent = "the graph library did not load";
    return;
  }
  const {nodes, edges} = graphElements(snapshot);
  const key = nodes.map((n) => n.data.id).join(" ") + "|" + edges.map((e) => e.data.id).join(" ");
  if (key !== state.graphKey) {
    state.graphKey = key;
    const wanted = new Set([...nodes, ...edges].map((item) => item.data.id));
    cy.batch(() => {
      cy.elements().filter((item) => !wanted.has(item.id())).remove();
      const missing = [...nodes, ...edges].filter((item) => cy.getElementById(item.data.id).empty());
      if (missing.length) cy.add(missing);
    });
    const layout = nodes.length > GRID_ABOVE
      ? {name: "grid", avoidOverlap: true, condense: true, animate: false}
      : {name: "breadthfirst", directed: true, avoidOverlap: true, spacingFactor: 1.2, padding: 20,
        animate: false}; // writers above their readers, deterministic: the picture does not jump at each change
    cy.layout(layout).run();
    if (nodes.length <= GRID_ABOVE) placeLabels(cy);
    cy.fit(undefined, 20);
    if (cy.zoom() > MAX_FIT_ZOOM) {
      cy.zoom(MAX_FIT_ZOOM);
      cy.center();
    }
  }
  cy.batch(() => {
    for (const n of nodes) cy.getElementById(n.data.id).data(n.data);
  });
  box.dataset.nodes = String(cy.nodes().length);
  box.dataset.edges = String(cy.edges().length);
  box.dataset.mismatchEdges = String(cy.edges("[kind = 'mismatch']").length);
}

// -- the connection --------------------------------------------------------------------------------------------------
function render(snapshot) {
  state.snapshot = snapshot;
  renderHeader(snapshot);
  renderVehicle(snapshot.vehicle);
  renderPrograms(snapshot.programs);
  renderFlows(snapshot.flows);
  renderLatency(snapshot);
  renderAnalysis(snapshot);
  renderMatches(snapshot);
  renderParticipants(snapshot);
  renderTopics(snapshot);
  renderEndpoints(snapshot);
  renderGraph(snapshot);
  state.updates += 1;
  document.body.dataset.updates = String(state.updates);
}

function setStatus(kind, text) {
  const status = document.getElementById("status");
  status.dataset.state = kind;
  status.textContent = text;
}

function connect() {
  const token = new URLSearchParams(location.search).get("token");
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws` +
    (token ? `?token=${encodeURIComponent(token)}` : "");
  const socket = new WebSocket(url);
  state.socket = socket;
  socket.onmessage = (event) => {
    let snapshot;
    try {
      snapshot = JSON.parse(event.data);
    } catch (error) {
      setStatus("late", `a snapshot did not parse: ${error}`);
      return;
    }
    state.receivedAt = Date.now();
    setStatus("live", "live");
    render(snapshot);
  };
  socket.onclose = () => {
    setStatus("disconnected", "disconnected: the monitor stopped? trying again every 2 s");
    setTimeout(connect, 2000);
  };
}

setInterval(() => { // a live connection that stopped bringing snapshots says so
  if (state.socket && state.socket.readyState === WebSocket.OPEN && state.receivedAt
      && Date.now() - state.receivedAt > LATE_S * 1000) {
    setStatus("late", `no snapshot for ${Math.round((Date.now() - state.receivedAt) / 1000)} s`);
  }
}, 1000);

connect();
