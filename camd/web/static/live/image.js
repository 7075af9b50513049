// The live image: the newest frame's real values (uint16), an optional background (float32
// mean of N frames) subtracted, contrast and colour map, and a nearest-neighbour zoom and pan
// so that pixels stay pixels. Below 1x (1/k) the display is the k x k block mean of the values
// (every pixel counts, none is dropped), while the full frame is kept for the readout, the
// statistics and the clipping counts. Everything the readout and the plots show comes from the
// real values, never from the 8-bit display image.

export const ZOOMS = [1 / 8, 1 / 4, 1 / 2, 1, 2, 3, 4, 6, 8, 12, 16];

// The clipping overlay's colours (raw full scale, raw 0), as [r, g, b].
export const CLIP_RGB = { full: [255, 32, 32], zero: [0, 96, 255] };

const LITTLE_ENDIAN = new Uint8Array(new Uint32Array([1]).buffer)[0] === 1;

// An opaque colour as one Uint32 of ImageData's RGBA bytes, in this machine's byte order.
function packRgb([r, g, b]) {
  return LITTLE_ENDIAN ? ((0xff << 24) | (b << 16) | (g << 8) | r) >>> 0 : ((r << 24) | (g << 16) | (b << 8) | 0xff) >>> 0;
}
const CLIP_FULL = packRgb(CLIP_RGB.full);
const CLIP_ZERO = packRgb(CLIP_RGB.zero);

function clamp(v, lo, hi) {
  return v < lo ? lo : v > hi ? hi : v;
}

// mean, std, min, max of a typed array
export function statistics(values) {
  const n = values.length;
  if (n === 0) return null;
  let sum = 0, sum2 = 0, min = Infinity, max = -Infinity;
  for (let i = 0; i < n; i++) {
    const v = values[i];
    sum += v;
    sum2 += v * v;
    if (v < min) min = v;
    if (v > max) max = v;
  }
  const mean = sum / n;
  return { mean, std: Math.sqrt(Math.max(sum2 / n - mean * mean, 0)), min, max, n };
}

// A histogram of `bins` equal bins over [lo, hi] (the last bin includes hi).
export function histogram(values, lo, hi, bins) {
  const counts = new Float64Array(bins);
  const scale = hi > lo ? bins / (hi - lo) : 0;
  for (let i = 0; i < values.length; i++) {
    counts[clamp(Math.floor((values[i] - lo) * scale), 0, bins - 1)]++;
  }
  return counts;
}

// The value below which `fraction` of the values lie, from a fine histogram over [lo, hi].
function percentileFrom(counts, lo, hi, fraction) {
  let total = 0;
  for (const c of counts) total += c;
  const wanted = fraction * total;
  let running = 0;
  const width = (hi - lo) / counts.length;
  for (let i = 0; i < counts.length; i++) {
    running += counts[i];
    if (running >= wanted) return lo + (i + 0.5) * width;
  }
  return hi;
}

// One pass over raw uint16 values: their histogram by value (into `counts`, 65536 bins), from
// which the statistics, percentiles and plotted histogram follow without another pass.
function countValues(data, counts) {
  counts.fill(0);
  for (let i = 0; i < data.length; i++) counts[data[i]]++;
  let min = -1, max = -1, sum = 0, sum2 = 0;
  for (let v = 0; v < counts.length; v++) {
    const c = counts[v];
    if (c === 0) continue;
    if (min < 0) min = v;
    max = v;
    sum += c * v;
    sum2 += c * v * v;
  }
  const n = data.length;
  const mean = sum / n;
  return { mean, std: Math.sqrt(Math.max(sum2 / n - mean * mean, 0)), min, max, n };
}

// The value below which `fraction` of the counted values lie (whole DN).
function percentileOfCounts(counts, n, fraction) {
  const wanted = fraction * n;
  let running = 0;
  for (let v = 0; v < counts.length; v++) {
    running += counts[v];
    if (running >= wanted) return v;
  }
  return counts.length - 1;
}

export class ImageView {
  constructor(canvas, colormaps) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    this.colormaps = colormaps;
    this.lut = null;
    this.setColormap(Object.keys(colormaps)[0]);
    this.offscreen = document.createElement("canvas");
    this.offCtx = this.offscreen.getContext("2d");
    this.frame = null; // { meta, data: Uint16Array, rows, cols }
    this.background = null; // { meta, data: Float32Array, rows, cols }
    this.subtract = false;
    this.subtracted = null; // Float32Array for the current frame, when subtracting
    this.zoom = 1;
    this.originRow = 0;
    this.originCol = 0;
    this.contrastMode = "p01";
    this.manual = [0, 4095];
    this.range = [0, 1];
    this.rawStats = null;
    this.rawCounts = new Uint32Array(65536); // the frame's values counted (countValues)
    this.imageData = null; // reused while the frame size stays
    this.subStats = null;
    this.profileLine = null; // [[row, col], [row, col]] of a drawn line, image pixels
    this.profileMark = null; // {kind: "row"|"column", index}
    this.overlays = []; // paint(ctx, dpr) after each draw, in device pixels (roi.js)
    this.clipOverlay = false; // full-scale and zero pixels drawn in colour
    this.clip = null; // {fullScale, saturated, zero}: counted on the full frame
  }

  // Frame pixels per displayed pixel along each axis: k below 1x (zoom 1/k), else 1.
  get block() {
    return this.zoom < 1 ? Math.round(1 / this.zoom) : 1;
  }

  // The zoom that shows the frame's whole width in the canvas: 1/k for the smallest whole k
  // that fits a wider frame, else the largest zoom of ZOOMS (1x and up) that still fits.
  fitZoom() {
    const f = this.frame;
    if (f === null) return 1;
    const { width } = this.size();
    if (f.cols > width) return 1 / Math.ceil(f.cols / Math.max(width, 1));
    return ZOOMS.filter((z) => z >= 1 && f.cols * z <= width).at(-1) ?? 1;
  }

  setColormap(name) {
    const table = this.colormaps[name];
    const lut = new Uint32Array(256);
    for (let i = 0; i < 256; i++) lut[i] = packRgb(table[i]);
    this.lut = lut;
    this.colormapName = name;
  }

  // The values on screen: raw, or raw - background when subtracting a matching background.
  displayValues() {
    return this.subtracted ?? this.frame?.data ?? null;
  }

  backgroundMatches() {
    const f = this.frame, b = this.background;
    return f !== null && b !== null && f.rows === b.rows && f.cols === b.cols;
  }

  setFrame(meta, buffer) {
    let data = new Uint16Array(buffer);
    if (new Uint8Array(new Uint16Array([1]).buffer)[0] !== 1) {
      // The daemon sends little-endian; a big-endian browser swaps.
      const view = new DataView(buffer);
      data = Uint16Array.from({ length: data.length }, (_, i) => view.getUint16(2 * i, true));
    }
    this.frame = { meta, data, rows: meta.rows, cols: meta.cols };
    this.refresh();
  }

  setBackground(background) {
    this.background = background;
    this.refresh();
  }

  // Recompute the subtracted values, statistics and contrast, and redraw.
  refresh() {
    const f = this.frame;
    if (f === null) return;
    this.rawStats = countValues(f.data, this.rawCounts);
    // Clipping: the stream's full scale (2^bits - 1, from the frame's description) and 0.
    const fullScale = 2 ** (f.meta.bits ?? 16) - 1;
    let saturated = 0;
    for (let v = fullScale; v < this.rawCounts.length; v++) saturated += this.rawCounts[v];
    // A binned frame's block means hide clipped pixels: the daemon counted them on the frame.
    const binned = (f.meta.bin ?? 1) > 1 && f.meta.saturated !== undefined;
    this.clip = binned
      ? { fullScale, saturated: f.meta.saturated, zero: f.meta.zero }
      : { fullScale, saturated, zero: this.rawCounts[0] };
    this.subtracted = null;
    this.subStats = null;
    if (this.backgroundMatches()) {
      const bg = this.background.data;
      if (this.subBuffer?.length !== f.data.length) this.subBuffer = new Float32Array(f.data.length);
      const sub = this.subBuffer; // reused frame after frame: no garbage at 20 frames a second
      for (let i = 0; i < sub.length; i++) sub[i] = f.data[i] - bg[i];
      this.subStats = statistics(sub);
      if (this.subtract) this.subtracted = sub;
    }
    this.computeRange();
    this.renderOffscreen();
    this.draw();
  }

  computeRange() {
    const values = this.displayValues();
    const stats = this.subtracted ? this.subStats : this.rawStats;
    if (values === null || stats === null) return;
    let lo = stats.min, hi = stats.max;
    if (this.contrastMode === "manual") {
      [lo, hi] = this.manual;
    } else if (this.contrastMode !== "minmax" && hi > lo) {
      const cut = this.contrastMode === "p1" ? 0.01 : 0.001;
      if (this.subtracted === null) {
        lo = percentileOfCounts(this.rawCounts, stats.n, cut);
        hi = percentileOfCounts(this.rawCounts, stats.n, 1 - cut);
      } else {
        const fine = histogram(values, stats.min, stats.max, 4096);
        lo = percentileFrom(fine, stats.min, stats.max, cut);
        hi = percentileFrom(fine, stats.min, stats.max, 1 - cut);
      }
    }
    if (!(hi > lo)) hi = lo + 1;
    this.range = [lo, hi];
  }

  renderOffscreen() {
    const f = this.frame;
    const k = this.block;
    const outCols = Math.ceil(f.cols / k), outRows = Math.ceil(f.rows / k);
    if (this.offscreen.width !== outCols || this.offscreen.height !== outRows) {
      this.offscreen.width = outCols;
      this.offscreen.height = outRows;
    }
    if (this.imageData === null || this.imageData.width !== outCols || this.imageData.height !== outRows) {
      this.imageData = this.offCtx.createImageData(outCols, outRows);
    }
    const pixels = new Uint32Array(this.imageData.data.buffer);
    if (k === 1) this.renderFull(pixels);
    else this.renderBlocks(pixels, k, outCols, outRows);
    this.offCtx.putImageData(this.imageData, 0, 0);
  }

  // One display pixel per frame pixel; clipped raw values in the overlay's colours.
  renderFull(pixels) {
    const values = this.displayValues();
    const raw = this.frame.data;
    const [lo, hi] = this.range;
    const scale = 255 / (hi - lo);
    const lut = this.lut;
    const overlay = this.clipOverlay;
    const fullScale = this.clip.fullScale;
    for (let i = 0; i < values.length; i++) {
      const level = (values[i] - lo) * scale;
      pixels[i] = lut[level <= 0 ? 0 : level >= 255 ? 255 : level | 0];
      if (overlay) {
        const v = raw[i];
        if (v >= fullScale) pixels[i] = CLIP_FULL;
        else if (v === 0) pixels[i] = CLIP_ZERO;
      }
    }
  }

  // Each display pixel the mean of a k x k block (fewer at the right and bottom edges); with the
  // overlay, a block holding a full-scale pixel is red, else one holding a zero blue, so that
  // no clipped pixel hides in a mean.
  renderBlocks(pixels, k, outCols, outRows) {
    const f = this.frame;
    const values = this.displayValues();
    const raw = f.data;
    const cols = f.cols;
    const [lo, hi] = this.range;
    const scale = 255 / (hi - lo);
    const lut = this.lut;
    const overlay = this.clipOverlay;
    const fullScale = this.clip.fullScale;
    if (this.blockOf?.length !== cols || this.blockK !== k) {
      this.blockOf = Int32Array.from({ length: cols }, (_, c) => Math.floor(c / k));
      this.blockK = k;
    }
    const blockOf = this.blockOf;
    const sums = new Float64Array(outCols);
    const flags = new Uint8Array(outCols);
    for (let br = 0; br < outRows; br++) {
      sums.fill(0);
      flags.fill(0);
      const r0 = br * k, r1 = Math.min(f.rows, r0 + k);
      for (let r = r0; r < r1; r++) {
        const base = r * cols;
        if (!overlay) {
          for (let c = 0; c < cols; c++) sums[blockOf[c]] += values[base + c];
          continue;
        }
        for (let c = 0; c < cols; c++) {
          const b = blockOf[c];
          sums[b] += values[base + c];
          const v = raw[base + c];
          if (v >= fullScale) flags[b] |= 1;
          else if (v === 0) flags[b] |= 2;
        }
      }
      for (let bc = 0; bc < outCols; bc++) {
        const n = (r1 - r0) * (Math.min(cols, (bc + 1) * k) - bc * k);
        const level = (sums[bc] / n - lo) * scale;
        const flag = flags[bc];
        pixels[br * outCols + bc] =
          flag & 1 ? CLIP_FULL : flag & 2 ? CLIP_ZERO : lut[level <= 0 ? 0 : level >= 255 ? 255 : level | 0];
      }
    }
  }

  // Canvas size in CSS pixels (the readout's unit) and the device pixel ratio.
  size() {
    const rect = this.canvas.getBoundingClientRect();
    return { width: rect.width, height: rect.height, dpr: window.devicePixelRatio || 1 };
  }

  // Zoom and the image pixel at the view's top left, kept so that the view stays on the image.
  // Below 1x the origin is a block's corner (a multiple of k), so that the blocks on screen are
  // those the display averaged.
  setView(zoom, originRow, originCol) {
    const blockBefore = this.block;
    this.zoom = zoom;
    const f = this.frame;
    if (f !== null) {
      const { width, height } = this.size();
      originRow = clamp(originRow, 0, Math.max(f.rows - Math.floor(height / zoom), 0));
      originCol = clamp(originCol, 0, Math.max(f.cols - Math.floor(width / zoom), 0));
    }
    const k = this.block;
    this.originRow = Math.max(0, Math.round(originRow));
    this.originCol = Math.max(0, Math.round(originCol));
    this.originRow -= this.originRow % k;
    this.originCol -= this.originCol % k;
    if (f !== null && k !== blockBefore) this.renderOffscreen();
    this.draw();
  }

  draw() {
    const { width, height, dpr } = this.size();
    const w = Math.round(width * dpr), h = Math.round(height * dpr);
    if (this.canvas.width !== w || this.canvas.height !== h) {
      this.canvas.width = w;
      this.canvas.height = h;
    }
    const ctx = this.ctx;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#000";
    ctx.fillRect(0, 0, w, h);
    if (this.frame === null) return;
    const s = this.zoom * dpr;
    const k = this.block; // the offscreen image has one pixel per k x k block
    ctx.imageSmoothingEnabled = false;
    ctx.setTransform(s, 0, 0, s, -this.originCol * s, -this.originRow * s);
    ctx.drawImage(this.offscreen, 0, 0, this.offscreen.width * k, this.offscreen.height * k);
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    this.drawOverlay(ctx, s);
    for (const paint of this.overlays) paint(ctx, dpr);
  }

  // The profile's line (or row/column) over the image, in screen space.
  drawOverlay(ctx, s) {
    const toX = (col) => (col + 0.5 - this.originCol) * s;
    const toY = (row) => (row + 0.5 - this.originRow) * s;
    ctx.strokeStyle = "rgba(79, 195, 247, 0.9)";
    ctx.lineWidth = 1;
    ctx.beginPath();
    if (this.profileLine !== null) {
      const [[r0, c0], [r1, c1]] = this.profileLine;
      ctx.moveTo(toX(c0), toY(r0));
      ctx.lineTo(toX(c1), toY(r1));
    } else if (this.profileMark !== null) {
      const { kind, index } = this.profileMark;
      if (kind === "row") {
        ctx.moveTo(0, toY(index));
        ctx.lineTo(this.canvas.width, toY(index));
      } else {
        ctx.moveTo(toX(index), 0);
        ctx.lineTo(toX(index), this.canvas.height);
      }
    }
    ctx.stroke();
  }

  // The view's mapping between CSS pixels from the canvas's top left and image coordinates
  // (continuous: pixel (r, c) covers rows r..r+1 and columns c..c+1), both ways.
  // Frame pixels per pixel sent: the viewer's binning (transport.js), 1 for full resolution.
  get bin() {
    return this.frame?.meta.bin ?? 1;
  }

  // The camera frame's size, whatever the viewer is sent ({rows, cols}; null before a frame):
  // what ROIs and the readout are in (canvasToImage).
  get imageSize() {
    const f = this.frame;
    if (f === null) return null;
    return { rows: f.meta.frame_rows ?? f.rows, cols: f.meta.frame_cols ?? f.cols };
  }

  // The pixel of the data on show (block means when binned) under a canvas point, fractional.
  // Below 1x, times k, not over the zoom: 1/3 is not exact in floating point, and the readout,
  // the ROI tool and the outlines must agree on the pixel.
  canvasToData(x, y) {
    const k = this.block;
    const along = (v) => (k > 1 ? v * k : v / this.zoom);
    return { row: this.originRow + along(y), col: this.originCol + along(x) };
  }

  // The camera frame's pixel under a canvas point, fractional: the data's times the binning, so
  // that ROIs and the readout are in the frame's pixels whatever the viewer is sent.
  canvasToImage(x, y) {
    const at = this.canvasToData(x, y);
    return { row: at.row * this.bin, col: at.col * this.bin };
  }

  imageToCanvas(row, col) {
    const k = this.block;
    const b = this.bin;
    const across = (v) => (k > 1 ? v / k : v * this.zoom);
    return { x: across(col / b - this.originCol), y: across(row / b - this.originRow) };
  }

  // Image pixel under a point given in CSS pixels from the canvas's top left (null off image).
  pixelAt(x, y) {
    const f = this.frame;
    if (f === null) return null;
    const at = this.canvasToData(x, y);
    const col = Math.floor(at.col);
    const row = Math.floor(at.row);
    if (row < 0 || col < 0 || row >= f.rows || col >= f.cols) return null;
    const i = row * f.cols + col;
    const raw = f.data[i];
    const sub = this.backgroundMatches() ? raw - this.background.data[i] : null;
    return { row, col, raw, sub };
  }

  // The displayed values in `bins` equal bins from their min to their max: [counts, lo, hi].
  displayHistogram(bins) {
    const stats = this.subtracted ? this.subStats : this.rawStats;
    if (stats === null) return null;
    const { min, max } = stats;
    if (this.subtracted !== null) return [histogram(this.subtracted, min, max, bins), min, max];
    const counts = new Float64Array(bins);
    const scale = bins / (max - min + 1);
    for (let v = min; v <= max; v++) counts[Math.floor((v - min) * scale)] += this.rawCounts[v];
    return [counts, min, max + 1];
  }

  // Values along the profile: row, column or a drawn line (nearest pixel per step).
  profile(kind, index) {
    const f = this.frame;
    const values = this.displayValues();
    if (f === null) return null;
    if (kind === "line" && this.profileLine !== null) {
      const [[r0, c0], [r1, c1]] = this.profileLine;
      const steps = Math.max(Math.abs(r1 - r0), Math.abs(c1 - c0), 1);
      const x = [], y = [];
      for (let k = 0; k <= steps; k++) {
        const r = Math.round(r0 + ((r1 - r0) * k) / steps);
        const c = Math.round(c0 + ((c1 - c0) * k) / steps);
        x.push(k);
        y.push(values[r * f.cols + c]);
      }
      return { x, y, label: `line (${r0},${c0})-(${r1},${c1}), px` };
    }
    if (kind === "row") {
      const r = clamp(index, 0, f.rows - 1);
      const y = Array.from(values.subarray(r * f.cols, (r + 1) * f.cols));
      return { x: y.map((_, i) => i), y, label: `row ${r}: column` };
    }
    const c = clamp(index, 0, f.cols - 1);
    const y = [];
    for (let r = 0; r < f.rows; r++) y.push(values[r * f.cols + c]);
    return { x: y.map((_, i) => i), y, label: `column ${c}: row` };
  }
}
