// The live view page: wires the live frames (WebSocket), the image, plots and waterfall, the
// daemon's status, and the controls (enabled only while this page holds control).

import { API, ApiError, CLIENT, binary, del, get, post } from "./api.js";
import { FocusPanel } from "./focus.js";
import { ImageView, ZOOMS } from "./image.js";
import { Plots } from "./plots.js";
import { RoiPanel } from "./roi.js";
import { TelemetryPlots } from "./telemetry_plots.js";
import { initSnapshots } from "./snapshot.js";
import { binnedHit, framePixels, initTransport, rawText, showTransport, transportQuery } from "./transport.js";
import { Waterfall } from "./waterfall.js";

const $ = (id) => document.getElementById(id);
const fmt = (v, digits = 1) => (v === null || v === undefined ? "-" : Number(v).toFixed(digits));
const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
const PLOT_INTERVAL_MS = 200;

const page = {
  status: null, // the last GET /status
  inControl: false,
  paused: false,
  framesShown: 0,
  framesReceived: 0,
  skippedTotal: 0,
  lastIndex: null,
  pointer: null, // [x, y] of the mouse over the image, CSS pixels
  backgroundSeq: null,
  errors: [],
};
window.camdLive = page; // for the browser tests and for a curious engineer's console

function showMessage(text, kind = "error") {
  const box = $("message");
  box.textContent = text;
  box.className = `message ${kind}`;
  box.hidden = false;
  clearTimeout(showMessage.timer);
  if (kind === "info") showMessage.timer = setTimeout(() => (box.hidden = true), 8000);
}

$("message").addEventListener("click", () => ($("message").hidden = true)); // read: click it away

// Runs a control action; the daemon's error message is shown as it is (it says what to change).
async function act(what, action) {
  try {
    const result = await action();
    showMessage(`${what}: done`, "info");
    return result;
  } catch (error) {
    showMessage(`${what}: ${error instanceof ApiError ? error.message : error}`);
    return null;
  }
}

// -- the image --------------------------------------------------------------------------------

const colormaps = await (await fetch("/static/live/colormaps.json")).json();
const view = new ImageView($("image"), colormaps);
const plots = new Plots($("hist"), $("profile"));
page.view = view;
page.plots = plots;

initSnapshots(() => view.frame?.meta ?? null, $("image"), showMessage);
// A change while connected goes to the daemon; while (re)connecting, the next URL carries it.
initTransport((settings) => {
  if (page.socket?.readyState === WebSocket.OPEN) page.socket.send(JSON.stringify(settings));
});

for (const name of Object.keys(colormaps)) {
  $("colormap").append(new Option(name, name));
}

function updateReadout() {
  const binned = page.pointer === null ? null : binnedHit(view, ...page.pointer);
  if (binned !== null) {
    // A binned display: the raw pixel under the cursor, its DN from the daemon.
    $("px-row").textContent = binned.row;
    $("px-col").textContent = binned.col;
    $("px-raw").textContent = rawText(binned, (text) => ($("px-raw").textContent = text));
    $("px-sub").textContent = "-";
    const start = page.timing?.window_start_row;
    $("px-sensor").textContent = start === undefined ? "" : `sensor row ${start + binned.row}`;
    return;
  }
  const hit = page.pointer === null ? null : view.pixelAt(...page.pointer);
  $("px-row").textContent = hit ? hit.row : "-";
  $("px-col").textContent = hit ? hit.col : "-";
  $("px-raw").textContent = hit ? hit.raw : "-";
  $("px-sub").textContent = hit && hit.sub !== null ? fmt(hit.sub, 1) : "-";
  const start = page.timing?.window_start_row;
  $("px-sensor").textContent = hit && start !== undefined ? `sensor row ${start + hit.row}` : "";
}

function updateStats() {
  const clip = view.clip;
  $("sat-count").textContent = clip ? clip.saturated : "-";
  $("zero-count").textContent = clip ? clip.zero : "-";
  $("full-scale").textContent = clip ? clip.fullScale : "-";
  const cells = [["raw", view.rawStats], ["sub", view.subStats]];
  for (const [prefix, stats] of cells) {
    for (const key of ["mean", "std", "min", "max"]) {
      $(`${prefix}-${key}`).textContent = stats ? fmt(stats[key], key === "mean" || key === "std" ? 2 : 1) : "-";
    }
  }
}

function updatePlots() {
  const shown = view.displayHistogram(256);
  if (shown === null) return;
  plots.showHistogram(...shown);
  const [lo, hi] = view.range;
  $("hist-note").textContent = `display ${fmt(lo)} .. ${fmt(hi)} DN`;
  if (view.contrastMode !== "manual") {
    $("lo").value = fmt(lo);
    $("hi").value = fmt(hi);
  }
  plots.showProfile(view.profile($("profile-kind").value, Number($("profile-index").value)));
}

function updateFrameInfo(meta, missed) {
  const t = (meta.timestamp_ns / 1e9).toFixed(3);
  const stages = meta.mode === "tdi" ? ` M=${meta.stages}` : "";
  const gap = meta.gap_before ? ` · ${meta.gap_before} lost before it` : "";
  $("frame-info").textContent =
    `frame ${meta.counter} · device t ${t} s · ${meta.mode}${stages} · ${meta.rows}x${meta.cols}` +
    ` · shown ${page.framesShown} · skipped ${missed} since the last shown (${page.skippedTotal} in all)${gap}`;
}

function showFrame(meta, buffer) {
  page.framesReceived++;
  // frames the tap passed over plus tap frames this page did not get
  const missed = page.lastIndex === null ? meta.skipped : Math.max(meta.index - page.lastIndex - 1, 0);
  page.lastIndex = meta.index;
  page.skippedTotal += missed;
  page.lastMeta = meta;
  if (page.paused) return;
  // the first frame, or one of another geometry (a binning chosen, a fitted view): the view follows
  const newView = view.frame === null || view.frame.rows !== meta.rows || view.frame.cols !== meta.cols;
  view.setFrame(meta, buffer);
  page.framesShown++;
  if (newView) applyView();
  showTransport(meta);
  updateFrameInfo(meta, missed);
  updateReadout();
  updateStats();
  // The plots at most 5 times a second: more is not readable, and costs the machine's CPU,
  // which on the test PC the acquisition shares.
  const now = performance.now();
  if (!(now - page.plottedAt < PLOT_INTERVAL_MS)) {
    page.plottedAt = now;
    updatePlots();
  }
}

function connectFrames() {
  const scheme = location.protocol === "https:" ? "wss" : "ws";
  const socket = new WebSocket(`${scheme}://${location.host}${API}/live/ws?${transportQuery()}`);
  socket.binaryType = "arraybuffer";
  page.socket = socket;
  let meta = null;
  let decoding = Promise.resolve(); // frames inflated in turn, shown in order
  socket.onopen = () => setBadge("conn", "live", "good");
  socket.onmessage = (event) => {
    if (typeof event.data === "string") {
      const doc = JSON.parse(event.data);
      if (doc.error !== undefined) showMessage(`transport: ${doc.error}`);
      else if (doc.transport !== undefined) page.transport = doc.transport;
      else meta = doc;
    } else if (meta !== null) {
      const frameMeta = meta;
      const payload = event.data;
      meta = null;
      decoding = decoding.then(async () => showFrame(frameMeta, await framePixels(frameMeta, payload)));
    }
  };
  socket.onclose = () => {
    setBadge("conn", "reconnecting", "bad");
    setTimeout(connectFrames, 1000);
  };
}

// -- zoom, pan, readout, profile --------------------------------------------------------------

function applyView() {
  const chosen = $("zoom").value;
  const zoom = chosen === "fit" ? view.fitZoom() : Number(chosen);
  view.setView(zoom, Number($("origin-row").value), Number($("origin-col").value));
  $("origin-row").value = view.originRow;
  $("origin-col").value = view.originCol;
  updateReadout();
}

for (const id of ["zoom", "origin-row", "origin-col"]) $(id).addEventListener("change", applyView);

const canvas = $("image");
const local = (event) => {
  const rect = canvas.getBoundingClientRect();
  return [event.clientX - rect.left, event.clientY - rect.top];
};
let drag = null;
canvas.addEventListener("mousedown", (event) => {
  const [x, y] = local(event);
  drag = { x, y, row: view.originRow, col: view.originCol, moved: false, line: event.shiftKey, start: view.pixelAt(x, y) };
});
window.addEventListener("mouseup", (event) => {
  if (drag === null) return;
  const [x, y] = local(event);
  if (!drag.moved && !drag.line) {
    const hit = view.pixelAt(x, y);
    const kind = $("profile-kind").value;
    if (hit !== null && kind !== "line") {
      $("profile-index").value = kind === "row" ? hit.row : hit.col;
      view.profileMark = { kind, index: kind === "row" ? hit.row : hit.col };
      view.profileLine = null;
      view.draw();
      updatePlots();
    }
  }
  drag = null;
});
canvas.addEventListener("mousemove", (event) => {
  const [x, y] = local(event);
  page.pointer = [x, y];
  if (drag !== null && (Math.abs(x - drag.x) > 3 || Math.abs(y - drag.y) > 3)) drag.moved = true;
  if (drag !== null && drag.moved) {
    if (drag.line) {
      const end = view.pixelAt(x, y);
      if (drag.start !== null && end !== null) {
        view.profileLine = [[drag.start.row, drag.start.col], [end.row, end.col]];
        view.profileMark = null;
        $("profile-kind").value = "line";
        view.draw();
        updatePlots();
      }
    } else {
      $("origin-row").value = Math.round(drag.row - (y - drag.y) / view.zoom);
      $("origin-col").value = Math.round(drag.col - (x - drag.x) / view.zoom);
      applyView();
    }
  }
  updateReadout();
});
canvas.addEventListener("mouseleave", () => {
  page.pointer = null;
  updateReadout();
});
canvas.addEventListener(
  "wheel",
  (event) => {
    event.preventDefault();
    const [x, y] = local(event);
    const hit = view.pixelAt(x, y);
    // the next zoom of ZOOMS in the wheel's direction (from "fit"'s 1/k too), across 1x
    const zoom =
      (event.deltaY < 0 ? ZOOMS.find((z) => z > view.zoom) : ZOOMS.findLast((z) => z < view.zoom)) ?? view.zoom;
    $("zoom").value = String(zoom);
    if (hit !== null) {
      // keep the pixel under the cursor where it is
      $("origin-row").value = Math.round(hit.row - y / zoom);
      $("origin-col").value = Math.round(hit.col - x / zoom);
    }
    applyView();
  },
  { passive: false },
);
$("profile-kind").addEventListener("change", () => {
  const kind = $("profile-kind").value;
  view.profileMark = kind === "line" ? null : { kind, index: Number($("profile-index").value) };
  if (kind !== "line") view.profileLine = null;
  view.draw();
  updatePlots();
});
$("profile-index").addEventListener("change", () => {
  const kind = $("profile-kind").value;
  if (kind !== "line") view.profileMark = { kind, index: Number($("profile-index").value) };
  view.draw();
  updatePlots();
});
$("pause").addEventListener("click", () => {
  page.paused = !page.paused;
  $("pause").textContent = page.paused ? "Resume" : "Pause";
});

// -- contrast, colours ------------------------------------------------------------------------

function applyDisplay() {
  view.contrastMode = $("contrast").value;
  view.manual = [Number($("lo").value), Number($("hi").value)];
  if (view.colormapName !== $("colormap").value) view.setColormap($("colormap").value);
  view.refresh();
  updatePlots();
}
for (const id of ["contrast", "colormap"]) $(id).addEventListener("change", applyDisplay);
$("clip-overlay").addEventListener("change", () => {
  view.clipOverlay = $("clip-overlay").checked;
  view.refresh();
});
$("hist-log").addEventListener("change", () => {
  plots.setHistogramLog($("hist-log").checked);
  updatePlots();
});
for (const id of ["lo", "hi"]) {
  $(id).addEventListener("change", () => {
    $("contrast").value = "manual";
    applyDisplay();
  });
}

// -- background -------------------------------------------------------------------------------

async function refreshBackground() {
  const status = await get("/live/background");
  const text = {
    none: "none",
    capturing: `capturing ${status.frames_done}/${status.frames_wanted} frames`,
    ready: `mean of ${status.frames_done} frames, ${status.rows}x${status.cols}, ${fmt(status.mean_dn, 1)} DN` +
      (status.saved_to?.length ? `; saved in ${status.saved_to.at(-1)}` : "; saved with the next recording"),
    failed: `failed: ${status.error}`,
  }[status.state];
  $("bg-state").textContent = text;
  if (status.state === "ready" && status.seq !== page.backgroundSeq) {
    const answer = await binary("/live/background/frame", "X-Camd-Background");
    if (answer !== null) {
      const [meta, buffer] = answer;
      page.backgroundSeq = status.seq;
      view.setBackground({ meta, data: new Float32Array(buffer), rows: meta.rows, cols: meta.cols });
      updateStats();
      updatePlots();
    }
  } else if (status.state === "none" && view.background !== null) {
    page.backgroundSeq = null;
    view.setBackground(null);
    updateStats();
  }
  if (view.background !== null && view.frame !== null && !view.backgroundMatches()) {
    $("bg-state").textContent += ` (does not match the ${view.frame.rows}x${view.frame.cols} frames: not subtracted)`;
  }
  return status;
}

$("bg-capture").addEventListener("click", async () => {
  const frames = Number($("bg-frames").value);
  const started = await act("capture a background", () => post("/live/background", { frames }));
  if (started === null) return;
  for (let i = 0; i < 600; i++) {
    const status = await refreshBackground();
    if (status.state !== "capturing") break;
    await sleep(200);
  }
});
$("bg-clear").addEventListener("click", async () => {
  await act("clear the background", () => del("/live/background"));
  await refreshBackground();
});
$("bg-subtract").addEventListener("change", () => {
  view.subtract = $("bg-subtract").checked;
  view.refresh();
  updateStats();
  updatePlots();
  updateReadout();
});

// -- status, telemetry, events ----------------------------------------------------------------

function setBadge(id, text, kind = "") {
  const badge = $(id);
  badge.textContent = text;
  badge.className = `badge ${kind}`;
}

function showControl(status) {
  const control = status.control;
  page.inControl = control.holder !== null && control.holder === control.you;
  const holder = control.holder ?? "nobody";
  setBadge("control", `control: ${holder}`, page.inControl ? "good" : control.holder ? "warn" : "");
  $("you").textContent = `you: ${control.you}`;
  $("take-control").hidden = page.inControl;
  $("release-control").hidden = !page.inControl;
  $("readonly").hidden = page.inControl;
  $("readonly-why").textContent = control.holder
    ? `${control.holder} holds control (${control.why}); this page only watches`
    : "nobody holds control; take it to change the camera from this page";
  for (const button of document.querySelectorAll(".needs-control")) button.disabled = !page.inControl;
  $("controls").classList.toggle("locked", !page.inControl);
  const activity = control.activity;
  $("activity").textContent = activity
    ? `${activity.text}${activity.total ? ` (${activity.done}/${activity.total})` : ""}`
    : "";
}

// The emergency-stop latch: a red banner with how to release it, while it holds.
function showEstop(status) {
  const latch = status.estop;
  $("estop-latched").hidden = !latch.latched;
  if (!latch.latched) return;
  const since = new Date(latch.since_t_s * 1000).toLocaleTimeString();
  const failed = latch.failed.length ? `; could not stop ${latch.failed.join("; ")}` : "";
  $("estop-why").textContent = `since ${since} by ${latch.by} (stopped ${latch.stopped.join(", ") || "nothing"}${failed})`;
  const holder = status.control.holder;
  const mayRelease = holder === null || holder === status.control.you;
  $("estop-release").disabled = !mayRelease;
  $("estop-release-why").textContent = mayRelease ? "" : `${holder} holds control: they release it, or take control first`;
}

async function showAcquisition(status) {
  const acq = status.acquisition;
  const progress = $("scan-progress");
  page.scan = null; // the scan's document while the last acquisition is a scan (the motion panel's)
  if (acq === null) {
    $("acq").textContent = "none yet";
    progress.hidden = true;
    return;
  }
  const since = new Date(acq.started_t_s * 1000).toLocaleTimeString();
  const by = acq.client ? ` by ${acq.client}` : "";
  let text = `${acq.kind} ${acq.running ? "running" : "ended"}: ${acq.description} (started${by} at ${since})`;
  if (acq.kind === "scan") {
    const scan = await get("/scan");
    page.scan = scan;
    text += ` · ${scan.state}: ${scan.lines} lines, ${scan.complete_lines} complete, ${scan.lost_frames} frames lost`;
    progress.hidden = scan.lines_wanted === 0;
    progress.max = Math.max(scan.lines_wanted, 1);
    progress.value = Math.min(scan.complete_lines, scan.lines_wanted);
  } else {
    progress.hidden = true;
  }
  $("acq").textContent = text;
}

// The motion panel: the encoder's M |dV/V| of the scan beside the image's motion measured from
// blocks of TDI frames (GET /live/motion, the newest block only: cheap at the status cadence)
// and, while the last acquisition is a scan, the scan's means over its measurable blocks.
// Fixed digits, so a figure reads the same from one second to the next.
const percent = (v) => (v === null || v === undefined ? "-" : (100 * v).toFixed(3));

function showEncoderMotion(scan) {
  const level = scan?.mismatch_level ?? null;
  const encoder = scan !== null && scan.mismatch_max !== null;
  $("mo-enc-state").textContent = scan === null ? "no scan" : encoder ? `scan ${scan.state}` : "no encoder";
  $("mo-enc-last").textContent = encoder ? fmt(scan.mismatch_last, 3) : "-";
  $("mo-enc-max").textContent = encoder ? fmt(scan.mismatch_max, 3) : "-";
  $("mo-enc-rms").textContent = encoder ? fmt(scan.mismatch_rms, 3) : "-";
  $("mo-enc-level").textContent = encoder ? level : "-";
  // coloured as the telemetry's levels: the worst level reached is the max's
  for (const id of ["mo-enc-max-row", "mo-enc-level-row"]) $(id).className = encoder ? `level-${level}` : "";
}

function showImageMotion(motion, scan) {
  const block = motion.latest;
  const measured = block !== null && block.measurable;
  $("mo-table").hidden = !measured;
  if (block === null) {
    $("mo-note").textContent = motion.enabled
      ? "no TDI frames measured yet: the image's motion is measured from TDI streams and scans"
      : "not measured: motion.image_measure is off";
    $("mo-age").textContent = "";
  } else {
    const age = Math.max(0, Math.round(Date.now() / 1000 - block.measured_t_s));
    $("mo-age").textContent = `measured ${age} s ago (frames ${block.counter_first}-${block.counter_last})`;
    $("mo-note").textContent = measured ? block.why : `not measurable: ${block.why}`;
  }
  $("mo-dv").textContent = measured ? percent(block.dv_over_v) : "-";
  $("mo-dv-err").textContent = measured ? percent(block.dv_over_v_stderr) : "-";
  $("mo-mdv").textContent = measured ? fmt(block.m_dv_over_v, 3) : "-";
  $("mo-stages").textContent = block === null ? "-" : block.stages;
  $("mo-theta").textContent = measured ? fmt(block.theta_deg, 3) : "-";
  const summary = scan?.image_motion ?? null;
  $("mo-scan").hidden = summary === null || summary.blocks === 0;
  if (summary === null) return;
  const any = summary.measurable_blocks > 0;
  $("mo-scan-table").hidden = !any; // no row of dashes under "none of its blocks measurable"
  $("mo-scan-blocks").textContent = any
    ? `mean over ${summary.measurable_blocks} blocks (of ${summary.blocks} measured)`
    : `none of its ${summary.blocks} blocks measurable`;
  $("mo-scan-dv").textContent = any ? percent(summary.dv_over_v_mean) : "-";
  $("mo-scan-dv-sem").textContent = any ? percent(summary.dv_over_v_sem) : "-";
  $("mo-scan-mdv").textContent = any ? fmt(summary.m_dv_over_v_mean, 3) : "-";
  $("mo-scan-theta").textContent = any ? fmt(summary.theta_deg_mean, 3) : "-";
}

async function showMotion() {
  const motion = await get("/live/motion");
  page.motion = motion;
  showEncoderMotion(page.scan);
  showImageMotion(motion, page.scan);
  page.motionScan = page.scan; // the scan document the panel shows (for the tests)
}

function showTelemetry(telemetry) {
  const table = $("telemetry");
  table.replaceChildren();
  for (const [name, channel] of Object.entries(telemetry.latest)) {
    const row = table.insertRow();
    row.id = `tm-${name}`;
    row.className = `level-${channel.limit}`;
    row.insertCell().textContent = name;
    const value = row.insertCell();
    value.className = "value num";
    value.textContent = `${Number(channel.value).toPrecision(4)} ${channel.unit}`;
    row.insertCell().textContent = channel.limit;
  }
}

function showLink(link) {
  const table = $("link");
  table.replaceChildren();
  // counters, flattened: {"injected": {"drop": 3}} -> "device injected.drop 3"
  const flat = (prefix, object) =>
    Object.entries(object).flatMap(([k, v]) =>
      v !== null && typeof v === "object" ? flat(`${prefix}${k}.`, v) : [[`${prefix}${k}`, v]],
    );
  const entries = [...flat("", link.host), ...(link.device ? flat("device ", link.device) : [])];
  for (const [name, value] of entries) {
    const row = table.insertRow();
    row.insertCell().textContent = name;
    const cell = row.insertCell();
    cell.className = "num";
    cell.textContent = value;
  }
}

function showEvents(events) {
  const list = $("events");
  list.replaceChildren();
  for (const event of events.events.slice().reverse()) {
    const item = document.createElement("li");
    item.className = event.level;
    const t = new Date(event.t_s * 1000).toLocaleTimeString();
    item.textContent = `${t} ${event.source}: ${event.message}`;
    list.append(item);
  }
}

async function refreshTiming() {
  try {
    page.timing = await get("/timing");
    $("exposure-now").textContent = `now ${page.timing.exposure_lines} lines = ${(page.timing.exposure_s * 1e3).toFixed(3)} ms`;
    if (!$("ctl-exposure").value) $("ctl-exposure").value = page.timing.exposure_lines;
  } catch (error) {
    $("exposure-now").textContent = `timing unknown: ${error.message}`;
  }
}

async function pollStatus() {
  let tick = 0;
  for (;;) {
    try {
      const status = await get("/status");
      page.status = status;
      const state = status.state;
      setBadge("state", `state: ${state}`, state === "idle" || state === "streaming" ? "good" : state === "fault" || state === "disconnected" ? "bad" : "warn");
      setBadge("mode", `mode: ${status.mode ?? "?"}`);
      if (status.mode && !page.modeShown) {
        $("ctl-mode").value = status.mode; // start from the camera's mode, then the user's choice
        page.modeShown = true;
      }
      showControl(status);
      showEstop(status);
      await showAcquisition(status);
      await showMotion();
      showTelemetry(await get("/telemetry"));
      showEvents(await get("/events?limit=40"));
      if (tick % 2 === 0) showLink(await get("/link"));
      if (tick % 10 === 0) await refreshTiming();
      await refreshBackground();
      page.polls = (page.polls ?? 0) + 1;
    } catch (error) {
      setBadge("state", `daemon: ${error.message}`, "bad");
    }
    tick++;
    await sleep(1000);
  }
}

// -- control ----------------------------------------------------------------------------------

let renewTimer = null;
async function takeControl(force = false) {
  try {
    await post("/control", { ttl_s: 60, force });
    clearInterval(renewTimer);
    // renew the lease while this page holds it
    renewTimer = setInterval(() => post("/control", { ttl_s: 60 }).catch(() => clearInterval(renewTimer)), 20000);
    showMessage("control taken: this page can change the camera", "info");
  } catch (error) {
    const holder = page.status?.control?.holder;
    if (error instanceof ApiError && error.status === 423 && holder && confirm(`${holder} holds control. Take it over?`)) {
      return takeControl(true);
    }
    showMessage(`take control: ${error.message}`);
  }
  page.status = await get("/status");
  showControl(page.status);
}

$("take-control").addEventListener("click", () => takeControl());
$("release-control").addEventListener("click", async () => {
  clearInterval(renewTimer);
  await act("release control", () => del("/control"));
  page.status = await get("/status");
  showControl(page.status);
});
$("estop").addEventListener("click", async () => {
  await act("emergency stop", () => post("/estop"));
  page.status = await get("/status");
  showEstop(page.status);
});
$("estop-release").addEventListener("click", async () => {
  if (!confirm("Release the emergency stop? Motion and acquisition may start again.")) return;
  await act("release the emergency stop", () => post("/estop/release"));
  page.status = await get("/status");
  showEstop(page.status);
});
$("ctl-mode-set").addEventListener("click", () => act(`set mode ${$("ctl-mode").value}`, () => post("/mode", { mode: $("ctl-mode").value })));
$("ctl-exposure-set").addEventListener("click", async () => {
  const lines = Number($("ctl-exposure").value);
  const register = page.timing?.exposure_register;
  if (!register) {
    showMessage("set exposure: the sensor's exposure register is not known yet (GET /api/v1/timing failed)");
    return;
  }
  await act(`set exposure ${lines} lines`, () => post("/registers", { values: { [register]: lines } }));
  await refreshTiming();
});
$("ctl-stream-start").addEventListener("click", () => act("start the stream", () => post("/stream/start", { frames: 0 })));
$("ctl-stream-stop").addEventListener("click", () => act("stop the stream", () => post("/stream/stop")));
$("ctl-stare").addEventListener("click", () => act("stare", () => post("/stream/acquire", { frames: Number($("ctl-stare-frames").value) })));
$("ctl-scan-start").addEventListener("click", () => {
  const body = { stages: Number($("ctl-scan-stages").value), lines: Number($("ctl-scan-lines").value) };
  const out = $("ctl-scan-out").value.trim();
  if (out) body.out = out;
  return act("start a scan", () => post("/scan/start", body));
});
$("ctl-scan-stop").addEventListener("click", () => act("stop the scan", () => post("/scan/stop")));

// -- start ------------------------------------------------------------------------------------

$("you").textContent = `you: ${CLIENT}`;
for (const button of document.querySelectorAll(".needs-control")) button.disabled = true;
page.focus = new FocusPanel({
  on: $("focus-on"), target: $("focus-target"), value: $("focus-value"), best: $("focus-best"),
  reset: $("focus-reset"), plot: $("focus-plot"), note: $("focus-note"),
});
const roiPanel = new RoiPanel(view, $("rois"), showMessage);
const telemetryPlots = new TelemetryPlots($("telemetry-plots"));
Object.assign(page, { roi: roiPanel, telemetryPlots });
window.addEventListener("resize", () => {
  if ($("zoom").value === "fit") applyView();
  view.draw();
  plots.resize();
  page.focus.resize();
  roiPanel.resize();
  telemetryPlots.resize();
});
const waterfall = new Waterfall($("waterfall"), (meta, wf, error) => {
  page.waterfall = wf;
  $("wf-lines").textContent = wf.lines;
  $("wf-incomplete").textContent = wf.incomplete.length;
  $("wf-scan").textContent = meta
    ? `${meta.scan} (${meta.state}, ${meta.lines_done}/${meta.lines_planned || "until stopped"} lines)`
    : error
      ? error.message
      : wf.scan === null
        ? "none yet"
        : $("wf-scan").textContent;
});
page.waterfall = waterfall;
connectFrames();
pollStatus();
waterfall.run();
roiPanel.run();
telemetryPlots.run();
