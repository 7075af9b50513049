// The TDI waterfall: the integrated lines of the running (or last) scan as they leave the
// engine, newest at the bottom. A line the engine could not complete (a lost frame left some
// of its M stages out) is drawn tinted red with a red mark in the left gutter.

import { binary, get } from "./api.js";

const GUTTER = 6; // columns of the gutter, in waterfall pixels
const INCOMPLETE = [255, 40, 40];

export class Waterfall {
  constructor(canvas, onInfo) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.onInfo = onInfo;
    this.scan = null;
    this.after = -1;
    this.lines = 0; // lines drawn for this scan
    this.incomplete = []; // indices of the incomplete lines drawn (newest last)
    this.rows = []; // line index on each canvas row (bottom = newest)
    this.range = null;
    this.stopped = false;
  }

  reset(scan, cols) {
    this.scan = scan;
    this.after = -1;
    this.lines = 0;
    this.incomplete = [];
    this.rows = [];
    this.range = null;
    this.canvas.width = Math.min(cols, 1024) + GUTTER;
    this.ctx.fillStyle = "#000";
    this.ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
  }

  // Add n lines (Float32Array n x cols) at the bottom, scrolling the rest up.
  add(meta, data) {
    const { n, cols } = meta;
    if (n === 0) return;
    const height = this.canvas.height;
    const width = this.canvas.width - GUTTER;
    const step = cols / width; // columns per waterfall pixel (>= 1: decimated to fit)
    // Contrast: percentiles of the new block, eased in, so that the picture does not flicker.
    const sample = Array.from(data.subarray(0, Math.min(data.length, 65536))).sort((a, b) => a - b);
    const lo = sample[Math.floor(0.01 * (sample.length - 1))];
    const hi = sample[Math.floor(0.99 * (sample.length - 1))];
    this.range = this.range === null ? [lo, hi] : [0.8 * this.range[0] + 0.2 * lo, 0.8 * this.range[1] + 0.2 * hi];
    const [a, b] = this.range;
    const scale = b > a ? 255 / (b - a) : 1;
    const shown = Math.min(n, height);
    const first = n - shown;
    this.ctx.drawImage(this.canvas, 0, -shown); // scroll up
    const image = this.ctx.createImageData(this.canvas.width, shown);
    const px = image.data;
    for (let k = 0; k < shown; k++) {
      const line = first + k;
      const complete = meta.complete[line];
      const base = line * cols;
      for (let x = 0; x < this.canvas.width; x++) {
        const o = 4 * (k * this.canvas.width + x);
        if (x < GUTTER) {
          const [r, g, bl] = complete ? [30, 30, 30] : INCOMPLETE;
          px[o] = r; px[o + 1] = g; px[o + 2] = bl; px[o + 3] = 255;
          continue;
        }
        const v = data[base + Math.floor((x - GUTTER) * step)];
        let level = (v - a) * scale;
        level = level < 0 ? 0 : level > 255 ? 255 : level;
        if (complete) {
          px[o] = level; px[o + 1] = level; px[o + 2] = level;
        } else {
          px[o] = 0.5 * level + 0.5 * INCOMPLETE[0];
          px[o + 1] = 0.5 * level; px[o + 2] = 0.5 * level;
        }
        px[o + 3] = 255;
      }
    }
    this.ctx.putImageData(image, 0, height - shown);
    for (let k = 0; k < n; k++) {
      const index = meta.index[k]; // a lost frame has no line: indices may jump
      if (k >= first) this.rows.push(index);
      if (!meta.complete[k]) this.incomplete.push(index);
    }
    this.rows = this.rows.slice(-height);
    this.lines += n;
  }

  // The canvas row (0 = top) showing line `index`, or null if it has scrolled off or never came.
  rowOf(index) {
    const k = this.rows.lastIndexOf(index);
    return k < 0 ? null : this.canvas.height - this.rows.length + k;
  }

  // Long-polls the daemon's lines for as long as the page is open (at most 10 requests a
  // second: a fast scan is shown decimated, the skipped lines counted by the daemon).
  async run() {
    const sleep = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
    while (!this.stopped) {
      const started = performance.now();
      try {
        if (this.scan === null && (await get("/scan")).state === "none") {
          // no scan yet since the daemon started: nothing to ask for
          this.onInfo(null, this);
          await sleep(2000);
          continue;
        }
        const query = `after=${this.after}&max=${this.canvas.height}&timeout_s=2`;
        const answer = await binary(`/live/lines?${query}`, "X-Camd-Lines");
        if (answer === null) {
          this.onInfo(null, this);
          await sleep(2000);
          continue;
        }
        const [meta, buffer] = answer;
        if (meta.scan_seq !== this.scan) {
          const fromStart = this.after === -1;
          this.reset(meta.scan_seq, meta.cols);
          this.file = meta.scan;
          if (!fromStart) continue; // lines of the new scan may lie before `after`: ask again
        }
        if (meta.n > 0) {
          this.add(meta, new Float32Array(buffer));
          this.after = meta.index[meta.n - 1];
        }
        this.onInfo(meta, this);
      } catch (error) {
        this.onInfo(null, this, error);
        await sleep(2000);
      }
      const elapsed = performance.now() - started;
      if (elapsed < 100) await sleep(100 - elapsed);
    }
  }
}
