// The live view's regions of interest (docs/live-view.md): drawn, moved and resized on the image
// with the ROI tool, edited by number and deleted in the list, their statistics as the daemon
// computes them on every frame (GET /api/v1/live/roi/stats), and one statistic plotted over the
// newest frames. The page computes none of these numbers itself: a script or a campaign reading
// the API gets the same ones. Defining and deleting need control; the daemon's refusal is shown.

/* global uPlot */

import { ApiError, del, get, post } from "./api.js";

// One colour per ROI, by its place in the list: its outline, its name in the list, its curve.
const COLOURS = ["#ff5252", "#69f0ae", "#ffd740", "#e040fb", "#40c4ff", "#ff9e40", "#b2ff59", "#ff80ab"];
// [field of the API, column title, decimals]
const STATS = [
  ["mean_dn", "mean", 2], ["std_dn", "std", 2], ["min_dn", "min", 0], ["max_dn", "max", 0],
  ["sum_dn", "sum", 0], ["snr", "SNR", 2], ["saturated", "sat.", 0], ["bg_mean_dn", "- bg", 2],
];
const FIELDS = ["x", "y", "width", "height"];
const POLL_MS = 1000;
const CLICK_PX = 3; // a press that moves less than this (CSS pixels) is a click, not a drag
const CORNER_PX = 6; // a press this close (CSS pixels) to an ROI's bottom-right corner resizes it
const LINE_PX = 2; // outline width, device pixels: both pixels either side of the ROI's border

const clamp = (v, lo, hi) => Math.min(Math.max(v, lo), hi);
const fmt = (v, digits) => (v === null || v === undefined ? "-" : Number(v).toFixed(digits));

export class RoiPanel {
  // view: the ImageView (its image<->canvas mapping and overlays); element: the empty box the
  // panel fills; showMessage(text): the page's message toast.
  constructor(view, element, showMessage) {
    this.view = view;
    this.showMessage = showMessage;
    this.rois = []; // the daemon's ROI list, {name, x, y, width, height}
    this.seq = null; // rois_seq of the statistics last shown
    this.stats = null; // the last GET /live/roi/stats
    this.drag = null; // {kind: "new"|"move"|"resize", roi, from: {row, col}}
    this.preview = null; // the rectangle being dragged, drawn dashed until the daemon answers
    this.plot = null;
    element.innerHTML = `
      <div class="plot-title">Regions of interest <span id="roi-note" class="muted"></span></div>
      <div class="toolbar">
        <button id="roi-tool" aria-pressed="false" title="drag on the image: a new ROI; inside an ROI: move it; at its bottom-right corner: resize it">ROI tool</button>
        <label>name <input id="roi-name" type="text" size="10" placeholder="roi1" title="the next ROI's name (one of the same name is replaced)"></label>
        <label>plot <select id="roi-stat">${STATS.map(([f, t]) => `<option value="${f}">${t}</option>`).join("")}</select></label>
        <label>over <input id="roi-history" type="number" min="1" max="4096" value="500"> frames</label>
      </div>
      <div class="roi-scroll"><table id="roi-list" class="stats"><thead><tr><th>ROI</th>${FIELDS.map((f) => `<th>${f}</th>`).join("")}
        ${STATS.map(([, t]) => `<th>${t}</th>`).join("")}<th></th></tr></thead><tbody></tbody></table></div>
      <div id="roi-plot"></div>`;
    this.element = element;
    this.tool = element.querySelector("#roi-tool");
    this.tool.addEventListener("click", () => {
      const on = this.tool.getAttribute("aria-pressed") !== "true";
      this.tool.setAttribute("aria-pressed", String(on));
      this.tool.classList.toggle("on", on);
      view.canvas.classList.toggle("roi-tool", on);
    });
    element.querySelector("#roi-stat").addEventListener("change", () => this.showPlot(true));
    view.overlays.push((ctx, dpr) => this.paint(ctx, dpr));
    // Caught on the way down, before the image's own handlers (pan, profile): with the tool on,
    // a press on the image belongs to the ROIs.
    view.canvas.parentElement.addEventListener("mousedown", (event) => this.press(event), true);
    window.addEventListener("mousemove", (event) => this.follow(event));
    window.addEventListener("mouseup", (event) => this.release(event));
    window.addEventListener("keydown", (event) => {
      if (event.key !== "Escape" || this.drag === null) return;
      this.drag = this.preview = null; // the drag is dropped: nothing sent
      view.draw();
    });
  }

  colourOf(name) {
    const i = this.rois.findIndex((r) => r.name === name);
    const hex = COLOURS[(i < 0 ? 0 : i) % COLOURS.length];
    return [1, 3, 5].map((k) => parseInt(hex.slice(k, k + 2), 16)).concat(255);
  }

  // -- drawing and editing on the image ---------------------------------------------------------

  imagePoint(event) {
    const box = this.view.canvas.getBoundingClientRect();
    return this.view.canvasToImage(event.clientX - box.left, event.clientY - box.top);
  }

  press(event) {
    const frame = this.view.frame;
    if (this.tool.getAttribute("aria-pressed") !== "true" || event.button !== 0 || frame === null) return;
    const from = this.imagePoint(event);
    const near = (roi) => {
      const corner = this.view.imageToCanvas(roi.y + roi.height, roi.x + roi.width);
      const here = this.view.imageToCanvas(from.row, from.col);
      return Math.hypot(corner.x - here.x, corner.y - here.y) <= CORNER_PX;
    };
    const inside = (roi) =>
      from.col >= roi.x && from.col < roi.x + roi.width && from.row >= roi.y && from.row < roi.y + roi.height;
    const hit = [...this.rois].reverse(); // the last drawn is on top
    const corner = hit.find(near);
    const body = hit.find(inside);
    const size = this.view.imageSize; // the camera frame's, also when the display is binned
    const onFrame = from.row >= 0 && from.col >= 0 && from.row < size.rows && from.col < size.cols;
    if (corner === undefined && body === undefined && !onFrame) return; // off the image: it pans
    event.stopPropagation();
    event.preventDefault();
    if (corner !== undefined) this.drag = { kind: "resize", roi: corner, from };
    else if (body !== undefined) this.drag = { kind: "move", roi: body, from };
    else this.drag = { kind: "new", roi: { name: this.nextName() }, from };
    this.drag.at = [event.clientX, event.clientY];
  }

  // The rectangle the drag gives now, kept on the frame.
  dragged(to) {
    const { rows, cols } = this.view.imageSize;
    const { kind, roi, from } = this.drag;
    if (kind === "move") {
      const x = clamp(roi.x + Math.round(to.col - from.col), 0, cols - roi.width);
      const y = clamp(roi.y + Math.round(to.row - from.row), 0, rows - roi.height);
      return { ...roi, x, y };
    }
    if (kind === "resize") {
      const width = clamp(Math.floor(to.col) - roi.x + 1, 1, cols - roi.x);
      const height = clamp(Math.floor(to.row) - roi.y + 1, 1, rows - roi.y);
      return { ...roi, width, height };
    }
    const c0 = clamp(Math.floor(from.col), 0, cols - 1), c1 = clamp(Math.floor(to.col), 0, cols - 1);
    const r0 = clamp(Math.floor(from.row), 0, rows - 1), r1 = clamp(Math.floor(to.row), 0, rows - 1);
    const x = Math.min(c0, c1), y = Math.min(r0, r1);
    return { name: roi.name, x, y, width: Math.abs(c1 - c0) + 1, height: Math.abs(r1 - r0) + 1 };
  }

  follow(event) {
    if (this.drag === null) return;
    const [x, y] = this.drag.at;
    this.drag.moved ||= Math.abs(event.clientX - x) > CLICK_PX || Math.abs(event.clientY - y) > CLICK_PX;
    this.preview = this.dragged(this.imagePoint(event));
    this.view.draw();
  }

  async release(event) {
    if (this.drag === null) return;
    const roi = this.dragged(this.imagePoint(event));
    // a click is no drag: it neither draws a 1 x 1 ROI nor nudges one
    const unchanged = !this.drag.moved || (this.drag.kind !== "new" && FIELDS.every((f) => roi[f] === this.drag.roi[f]));
    this.drag = null;
    this.preview = roi;
    if (!unchanged) await this.define(roi);
    this.preview = null;
    this.view.draw();
  }

  // The first of roi1, roi2, ... not taken, unless a name is typed.
  nextName() {
    const typed = this.element.querySelector("#roi-name").value.trim();
    if (typed) return typed;
    const taken = new Set(this.rois.map((r) => r.name));
    let k = 1;
    while (taken.has(`roi${k}`)) k++;
    return `roi${k}`;
  }

  // POST the ROI (one of its name is replaced in place); the daemon's refusal is shown as it is.
  async define(roi) {
    try {
      const answer = await post("/live/roi", { name: roi.name, ...Object.fromEntries(FIELDS.map((f) => [f, roi[f]])) });
      this.element.querySelector("#roi-name").value = "";
      this.setRois(answer.rois);
    } catch (error) {
      this.showMessage(`define ROI ${roi.name}: ${error instanceof ApiError ? error.message : error}`);
      this.setRois(this.rois, true); // the list shows the daemon's rectangle again
    }
  }

  async remove(name) {
    try {
      this.setRois((await del(`/live/roi/${encodeURIComponent(name)}`)).rois);
    } catch (error) {
      this.showMessage(`delete ROI ${name}: ${error instanceof ApiError ? error.message : error}`);
    }
  }

  // Outlines and names over the image, through the view's own image -> canvas mapping (any zoom).
  paint(ctx, dpr) {
    if (this.view.frame === null) return;
    const shown = this.rois.map((roi) => (this.preview?.name === roi.name ? null : roi)).filter(Boolean);
    ctx.save();
    ctx.lineWidth = LINE_PX;
    ctx.font = `${Math.round(12 * dpr)}px system-ui, sans-serif`;
    const outline = (roi, colour, dashed) => {
      const a = this.view.imageToCanvas(roi.y, roi.x);
      const b = this.view.imageToCanvas(roi.y + roi.height, roi.x + roi.width);
      const [x0, y0, x1, y1] = [a.x, a.y, b.x, b.y].map((v) => Math.round(v * dpr));
      ctx.strokeStyle = ctx.fillStyle = colour;
      ctx.setLineDash(dashed ? [4 * dpr, 3 * dpr] : []);
      ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
      const labelY = y0 - 4 * dpr >= 12 * dpr ? y0 - 4 * dpr : y0 + 14 * dpr;
      ctx.fillText(roi.name, x0 + 3 * dpr, labelY);
    };
    for (const roi of shown) outline(roi, COLOURS[this.rois.indexOf(roi) % COLOURS.length], false);
    if (this.preview !== null) outline(this.preview, "#ffffff", true);
    ctx.restore();
  }

  // -- the list and the plot --------------------------------------------------------------------

  // A new ROI list from the daemon: the table's rows are rebuilt only when it changed (or when a
  // refused edit must be undone), so that a number being typed is not overwritten.
  setRois(rois, force = false) {
    const changed = JSON.stringify(rois) !== JSON.stringify(this.rois);
    this.rois = rois;
    if (changed || force) this.buildList();
    if (changed) {
      this.seq = null; // the statistics of the old set are not these ROIs'
      this.stats = null;
      this.showPlot(true);
      this.view.draw();
    }
  }

  buildList() {
    const body = this.element.querySelector("#roi-list tbody");
    body.replaceChildren();
    this.rois.forEach((roi, i) => {
      const row = body.insertRow();
      row.dataset.roi = roi.name;
      const name = row.insertCell();
      name.textContent = roi.name;
      name.style.color = COLOURS[i % COLOURS.length];
      for (const field of FIELDS) {
        const input = document.createElement("input");
        Object.assign(input, { type: "number", min: field === "x" || field === "y" ? 0 : 1, step: 1, value: roi[field] });
        input.dataset.field = field;
        input.addEventListener("change", () => {
          const edited = { name: roi.name };
          for (const f of FIELDS) edited[f] = Number(row.querySelector(`input[data-field="${f}"]`).value);
          this.define(edited);
        });
        row.insertCell().append(input);
      }
      for (const [field] of STATS) row.insertCell().dataset.stat = field;
      const remove = document.createElement("button");
      remove.textContent = "Delete";
      remove.dataset.action = "delete";
      remove.addEventListener("click", () => this.remove(roi.name));
      row.insertCell().append(remove);
    });
    this.showStats();
  }

  showStats() {
    const latest = this.stats?.latest;
    for (const row of this.element.querySelectorAll("#roi-list tr[data-roi]")) {
      const values = latest?.rois?.[row.dataset.roi];
      for (const [field, , digits] of STATS) {
        row.querySelector(`td[data-stat="${field}"]`).textContent = values ? fmt(values[field], digits) : "-";
      }
    }
    const note = this.element.querySelector("#roi-note");
    note.textContent = this.stats === null || this.rois.length === 0
      ? "none: the ROI tool draws one on the image (needs control)"
      : `frame ${latest?.counter ?? "-"} · ${this.stats.measured} frames measured since the ROIs changed` +
        (this.stats.unfit ? ` · ${this.stats.unfit} frames they did not fit` : "");
  }

  // One curve per ROI of the chosen statistic over the newest frames (x: the frame counter).
  showPlot(rebuild = false) {
    const element = this.element.querySelector("#roi-plot");
    const field = this.element.querySelector("#roi-stat").value;
    if (rebuild || this.plot === null || this.plot.series.length !== this.rois.length + 1) {
      this.plot?.destroy();
      const axis = { stroke: "#8b939c", grid: { stroke: "#2a2e33" }, ticks: { stroke: "#2a2e33" } };
      const title = STATS.find(([f]) => f === field)[1];
      this.plot = new uPlot(
        {
          width: Math.max(element.getBoundingClientRect().width, 200),
          height: 170,
          legend: { show: false },
          scales: { x: { time: false } },
          axes: [{ ...axis, label: "frame counter" }, { ...axis, label: `ROI ${title}`, size: 70 }],
          series: [{}, ...this.rois.map((roi, i) => ({ label: roi.name, stroke: COLOURS[i % COLOURS.length], width: 1 }))],
        },
        [[], ...this.rois.map(() => [])],
        element,
      );
    }
    const history = this.stats?.rois_seq === this.seq ? this.stats?.history : null;
    const first = history?.[this.rois[0]?.name];
    if (!first) {
      this.plot.setData([[], ...this.rois.map(() => [])]);
      return;
    }
    this.plot.setData([first.counter, ...this.rois.map((roi) => history[roi.name]?.[field] ?? [])]);
  }

  // The values plotted for ROI `name` (for the tests, and a curious engineer's console).
  plotted(name) {
    const i = this.rois.findIndex((r) => r.name === name);
    return i < 0 || this.plot === null ? null : Array.from(this.plot.data[i + 1] ?? []);
  }

  resize() {
    const element = this.element.querySelector("#roi-plot");
    this.plot?.setSize({ width: Math.max(element.getBoundingClientRect().width, 200), height: 170 });
  }

  // Every second: the statistics (with their history while there are ROIs), and the ROI list
  // when the daemon's set changed (another page, camctl, a campaign).
  async refresh() {
    const frames = clamp(Math.round(Number(this.element.querySelector("#roi-history").value)) || 500, 1, 4096);
    let stats = await get(`/live/roi/stats?history=${this.rois.length ? frames : 0}`);
    if (stats.rois_seq !== this.seq) {
      const seq = stats.rois_seq; // the list is fetched after it: a later change shows next time
      this.setRois((await get("/live/roi")).rois);
      if (this.rois.length) {
        const again = await get(`/live/roi/stats?history=${frames}`);
        if (again.rois_seq === seq) stats = again;
      }
      this.seq = seq;
    }
    this.stats = stats;
    this.showStats();
    this.showPlot();
  }

  async run() {
    for (;;) {
      try {
        await this.refresh();
      } catch (error) {
        this.element.querySelector("#roi-note").textContent = `statistics unavailable: ${error.message}`;
      }
      await new Promise((resolve) => setTimeout(resolve, POLL_MS));
    }
  }
}
