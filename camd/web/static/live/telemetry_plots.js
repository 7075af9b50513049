// Telemetry over time (docs/live-view.md): each chosen channel over a chosen range, one plot per
// channel. One request per refresh asks the archive for every channel bucketed (bucket_s: about
// BUCKETS buckets whatever the range), so an answer stays small for 10 minutes as for a day: the
// min..max band and the mean of each bucket. The channel's yellow and red limits (GET
// /api/v1/telemetry's `limits`, the ranges the daemon classifies with) are drawn as dashed
// lines, and whatever lies beyond a limit, line, band or point, is painted in that limit's
// colour. Drag across a plot to zoom in time; Reset zoom shows the whole range again.

/* global uPlot */

import { ApiError, get } from "./api.js";

const BUCKETS = 300;
// A range ending now moves on every 5 s or every bucket, whichever is longer (a day's 288 s
// buckets change little in 5 s), unless the user zoomed in.
const REFRESH_MS = 5000;
const RANGES = [["600", "last 10 min"], ["3600", "last 1 h"], ["86400", "last 24 h"], ["custom", "start .. end"]];
const LEVEL = { ok: [79, 195, 247], yellow: [249, 168, 37], red: [211, 47, 47] }; // live.css
const UNIT_S = { s: 1, m: 60, h: 3600, d: 86400 };

const rgba = ([r, g, b], alpha) => `rgba(${r}, ${g}, ${b}, ${alpha})`;

// Seconds since 1970 of a time as the API takes it (ISO 8601, Unix seconds, now, -10m), to size
// the buckets; NaN if it is none of these (the API's answer then says what is wrong).
function parseTime(text, nowS) {
  const t = text.trim();
  if (t === "" || t === "now") return nowS;
  const relative = /^-(\d+(?:\.\d*)?)([smhd]?)$/.exec(t);
  if (relative) return nowS - Number(relative[1]) * UNIT_S[relative[2] || "s"];
  if (/^\d+(?:\.\d*)?$/.test(t)) return Number(t);
  const zoned = /(Z|[+-]\d\d:?\d\d)$/.test(t) ? t : `${t}Z`; // without a zone it is UTC
  return Date.parse(zoned) / 1000;
}

// A vertical gradient over the plot area with hard stops at the limits: red beyond red, yellow
// beyond yellow, the ok colour inside.
function levelGradient(u, limits, alpha) {
  const top = u.bbox.top, height = u.bbox.height;
  if (limits === undefined || !(height > 0)) return rgba(LEVEL.ok, alpha);
  const at = (v) => Math.min(Math.max((u.valToPos(v, "y", true) - top) / height, 0), 1);
  const gradient = u.ctx.createLinearGradient(0, top, 0, top + height);
  const bands = [ // from the top (high values) down
    [at(limits.red[1]), LEVEL.red, LEVEL.yellow],
    [at(limits.yellow[1]), LEVEL.yellow, LEVEL.ok],
    [at(limits.yellow[0]), LEVEL.ok, LEVEL.yellow],
    [at(limits.red[0]), LEVEL.yellow, LEVEL.red],
  ];
  gradient.addColorStop(0, rgba(LEVEL.red, alpha));
  for (const [offset, above, below] of bands) {
    gradient.addColorStop(offset, rgba(above, alpha));
    gradient.addColorStop(offset, rgba(below, alpha));
  }
  gradient.addColorStop(1, rgba(LEVEL.red, alpha));
  return gradient;
}

// The limits as dashed lines where they fall inside the plot.
function drawLimits(u, limits) {
  if (limits === undefined) return;
  const { ctx } = u;
  const { left, top, width, height } = u.bbox;
  ctx.save();
  ctx.lineWidth = 1;
  ctx.setLineDash([5, 4]);
  for (const [level, values] of [["yellow", limits.yellow], ["red", limits.red]]) {
    for (const v of values) {
      const y = Math.round(u.valToPos(v, "y", true)) + 0.5;
      if (y < top || y > top + height) continue;
      ctx.strokeStyle = rgba(LEVEL[level], 1);
      ctx.beginPath();
      ctx.moveTo(left, y);
      ctx.lineTo(left + width, y);
      ctx.stroke();
    }
  }
  ctx.restore();
}

// One channel's buckets of both sources (camera packet, daemon poll) merged per bucket start:
// [t, mean, min, max], oldest first.
function merged(channel) {
  const buckets = new Map();
  channel.t_s.forEach((t, i) => {
    const b = buckets.get(t) ?? { min: Infinity, max: -Infinity, sum: 0, count: 0 };
    b.min = Math.min(b.min, channel.min[i]);
    b.max = Math.max(b.max, channel.max[i]);
    b.sum += channel.mean[i] * channel.count[i];
    b.count += channel.count[i];
    buckets.set(t, b);
  });
  const t = [...buckets.keys()].sort((a, b) => a - b);
  const at = (key) => t.map((k) => (key === "mean" ? buckets.get(k).sum / buckets.get(k).count : buckets.get(k)[key]));
  return [t, at("mean"), at("min"), at("max")];
}

const fmtLimit = (v) => String(Number(v));

export class TelemetryPlots {
  constructor(element) {
    this.element = element;
    this.plots = {}; // channel -> uPlot
    this.range = null; // [start_s, end_s] of the last answer: the whole range, unzoomed
    this.zoomed = false;
    this.asked = 0; // requests made: only the newest answer is drawn
    this.syncing = false; // while one plot's zoom is applied to the others
    this.shownAt = -Infinity; // performance.now() of the last request
    this.channelsKnown = false;
    element.innerHTML = `
      <h2>Telemetry over time</h2>
      <div id="tmp-channels" class="tmp-channels"></div>
      <div class="row">
        <select id="tmp-range">${RANGES.map(([v, t]) => `<option value="${v}">${t}</option>`).join("")}</select>
        <span id="tmp-custom" hidden>
          <input id="tmp-start" type="text" size="14" placeholder="-2h, ISO 8601 UTC" value="-2h" title="ISO 8601 (UTC without a zone), Unix seconds, now, or before now: -30s, -10m, -2h, -1d">
          .. <input id="tmp-end" type="text" size="8" value="now">
        </span>
        <button id="tmp-plot">Plot</button>
        <button id="tmp-reset" title="show the whole range again after a drag-zoom">Reset zoom</button>
      </div>
      <div id="tmp-note" class="muted">choose channels to plot</div>
      <div id="tmp-plots"></div>`;
    const $ = (id) => element.querySelector(`#${id}`);
    this.$ = $;
    $("tmp-range").addEventListener("change", () => {
      $("tmp-custom").hidden = $("tmp-range").value !== "custom";
      this.show();
    });
    $("tmp-plot").addEventListener("click", () => this.show());
    $("tmp-reset").addEventListener("click", () => this.resetZoom());
    for (const id of ["tmp-start", "tmp-end"]) $(id).addEventListener("change", () => this.show());
  }

  chosen() {
    return [...this.element.querySelectorAll("#tmp-channels input:checked")].map((box) => box.value);
  }

  // The channels to choose from and their limits, from GET /api/v1/telemetry.
  async loadChannels() {
    const telemetry = await get("/telemetry");
    this.limits = telemetry.limits ?? {};
    const names = [...new Set([...Object.keys(telemetry.latest), ...Object.keys(this.limits)])];
    this.channelsKnown = Object.keys(telemetry.latest).length > 0; // before a first sample, not all
    const box = this.$("tmp-channels");
    if (box.childElementCount === names.length) return;
    const chosen = new Set(this.chosen()); // kept when channels are added
    box.replaceChildren();
    for (const name of names) {
      const label = document.createElement("label");
      const input = Object.assign(document.createElement("input"), { type: "checkbox", value: name, checked: chosen.has(name) });
      input.addEventListener("change", () => this.show());
      label.append(input, ` ${name}`);
      box.append(label);
    }
  }

  // [start, end, bucket_s] of the chosen range, as the API takes them.
  rangeAsked() {
    const nowS = Date.now() / 1000;
    const choice = this.$("tmp-range").value;
    if (choice !== "custom") return [`-${choice}s`, "now", Number(choice) / BUCKETS];
    const start = this.$("tmp-start").value.trim(), end = this.$("tmp-end").value.trim() || "now";
    const span = parseTime(end, nowS) - parseTime(start, nowS);
    return [start, end, span > 0 ? span / BUCKETS : 60];
  }

  async show() {
    const channels = this.chosen();
    const asked = ++this.asked;
    if (channels.length === 0) {
      this.draw(null);
      this.$("tmp-note").textContent = "choose channels to plot";
      return;
    }
    const [start, end, bucketS] = this.rangeAsked();
    this.shownAt = performance.now();
    const query = new URLSearchParams({ channel: channels.join(","), start, end, bucket_s: String(bucketS) });
    try {
      const answer = await get(`/telemetry/history?${query}`);
      if (asked !== this.asked) return; // a newer request is on its way
      this.draw(answer);
      const seconds = bucketS >= 1 ? `${Number(bucketS.toPrecision(3))} s` : `${(bucketS * 1e3).toPrecision(3)} ms`;
      this.$("tmp-note").textContent =
        `${new Date(answer.start_s * 1000).toLocaleString()} .. ${new Date(answer.end_s * 1000).toLocaleString()}` +
        ` · min..max band and mean per ${seconds} bucket`;
    } catch (error) {
      if (asked !== this.asked) return;
      this.$("tmp-note").textContent = `telemetry history: ${error instanceof ApiError ? error.message : error}`;
    }
  }

  // One plot per channel of the answer (kept while the channels stay, so a refresh only moves
  // the data), x over the whole range asked.
  draw(answer) {
    const channels = answer?.channels ?? [];
    const box = this.$("tmp-plots");
    const names = channels.map((c) => c.channel);
    if (names.join() !== Object.keys(this.plots).join()) {
      for (const plot of Object.values(this.plots)) plot.destroy();
      this.plots = {};
      box.replaceChildren();
      for (const channel of channels) this.plots[channel.channel] = this.makePlot(box, channel.channel, channel.unit);
    }
    if (answer === null) return;
    this.range = [answer.start_s, answer.end_s];
    this.zoomed = false;
    for (const channel of channels) {
      const plot = this.plots[channel.channel];
      plot.setData(merged(channel));
      plot.setScale("x", { min: answer.start_s, max: answer.end_s });
    }
  }

  makePlot(box, name, unit) {
    const limits = this.limits?.[name];
    const holder = document.createElement("div");
    holder.dataset.channel = name;
    const title = document.createElement("div");
    title.className = "tmp-title";
    title.textContent = `${name} (${unit})` + (limits
      ? ` · yellow ${fmtLimit(limits.yellow[0])} .. ${fmtLimit(limits.yellow[1])} ${unit}, red ${fmtLimit(limits.red[0])} .. ${fmtLimit(limits.red[1])} ${unit}`
      : " · no limits");
    const area = document.createElement("div");
    holder.append(title, area);
    box.append(holder);
    const axis = { stroke: "#8b939c", grid: { stroke: "#2a2e33" }, ticks: { stroke: "#2a2e33" } };
    const level = (alpha) => (u) => levelGradient(u, limits, alpha);
    const plot = new uPlot(
      {
        width: Math.max(box.getBoundingClientRect().width, 200),
        height: 150,
        legend: { show: false },
        cursor: { drag: { x: true, y: false, setScale: true } },
        scales: {
          x: { time: true, auto: false },
          // the data and the yellow range: the limits an operator watches stay in sight
          y: {
            range: (u, lo, hi) => {
              const values = [lo, hi, ...(limits ? limits.yellow : [])].filter(Number.isFinite);
              if (values.length === 0) return [0, 1]; // no data, no limits: an empty plot
              const [a, b] = [Math.min(...values), Math.max(...values)];
              const pad = (b - a) * 0.08 || Math.abs(a) * 0.05 || 1;
              return [a - pad, b + pad];
            },
          },
        },
        axes: [axis, { ...axis, size: 55 }],
        series: [
          {},
          { label: "mean", stroke: level(1), width: 1.5, points: { show: true, size: 6, width: 1, stroke: level(1), fill: level(1) } },
          { label: "min", stroke: level(0.6), width: 1, points: { show: false } },
          { label: "max", stroke: level(0.6), width: 1, points: { show: false } },
        ],
        bands: [{ series: [3, 2], fill: level(0.18) }],
        hooks: {
          draw: [(u) => drawLimits(u, limits)],
          setScale: [(u, key) => {
            if (key !== "x" || this.range === null || this.syncing) return;
            this.zoomed = u.scales.x.min !== this.range[0] || u.scales.x.max !== this.range[1];
            // every plot shows the same time span: a zoom in one is a zoom in all
            this.syncing = true;
            for (const other of Object.values(this.plots)) {
              if (other !== u) other.setScale("x", { min: u.scales.x.min, max: u.scales.x.max });
            }
            this.syncing = false;
          }],
        },
      },
      [[], [], [], []],
      area,
    );
    return plot;
  }

  resetZoom() {
    if (this.range === null) return;
    for (const plot of Object.values(this.plots)) plot.setScale("x", { min: this.range[0], max: this.range[1] });
    this.zoomed = false;
  }

  resize() {
    const width = Math.max(this.$("tmp-plots").getBoundingClientRect().width, 200);
    for (const plot of Object.values(this.plots)) plot.setSize({ width, height: 150 });
  }

  async run() {
    for (;;) {
      try {
        // the channels and their limits do not change while the daemon runs: asked until known
        if (!this.channelsKnown) await this.loadChannels();
        const moving = this.$("tmp-range").value !== "custom" || /now|^-/.test(this.$("tmp-end").value.trim() || "now");
        const due = performance.now() - this.shownAt >= Math.max(REFRESH_MS, this.rangeAsked()[2] * 1000);
        if (moving && due && !this.zoomed && this.chosen().length) await this.show();
      } catch (error) {
        this.$("tmp-note").textContent = `telemetry: ${error.message}`;
      }
      await new Promise((resolve) => setTimeout(resolve, REFRESH_MS));
    }
  }
}
