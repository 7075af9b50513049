// The focus aid: the daemon's sharpness figure of the live frames (GET /api/v1/live/focus), for
// the whole frame or one ROI, with its history plotted (uPlot) and the best since the last reset
// marked. Off until switched on: asking is what keeps the daemon measuring (at most 4 figures a
// second, on a thread of its own), so a page that does not show the aid costs the daemon nothing.

/* global uPlot */

import { del, get } from "./api.js";

const POLL_MS = 500;
const HISTORY = 240; // figures plotted: a minute at the daemon's 4 a second

const fmt = (v) => (v === null || v === undefined ? "-" : Number(v).toPrecision(4));

export class FocusPanel {
  // elements: {on, target, value, best, reset, plot, note}: the checkbox, the target's select,
  // the figure and best texts, the reset button, the plot's element and a note for errors.
  constructor(elements) {
    this.el = elements;
    this.doc = null; // the last GET /live/focus
    this.shown = { value: null, best: null, counter: null };
    this.running = false;
    this.plot = null;
    elements.on.addEventListener("change", () => (elements.on.checked ? this.start() : this.stop()));
    elements.target.addEventListener("change", () => this.show());
    elements.reset.addEventListener("click", async () => {
      try {
        const answer = await del("/live/focus/best");
        // the answer holds no history (none asked): the plotted one stays until the next poll
        this.doc = { ...answer, history: this.doc?.history ?? answer.history };
        this.show();
      } catch (error) {
        elements.note.textContent = `reset: ${error.message}`;
      }
    });
  }

  // The frame counters of the figures plotted (for the browser tests).
  counters() {
    return this.doc?.history.counter ?? [];
  }

  makePlot() {
    const element = this.el.plot;
    const axis = { stroke: "#8b939c", grid: { stroke: "#2a2e33" }, ticks: { stroke: "#2a2e33" } };
    this.plot = new uPlot(
      {
        width: Math.max(element.getBoundingClientRect().width, 200),
        height: 150,
        legend: { show: false },
        cursor: { drag: { x: false, y: false } },
        scales: { x: { time: true } },
        axes: [{ ...axis }, { ...axis, label: "sharpness G", size: 60 }],
        series: [
          {},
          { stroke: "#81c784", width: 1 },
          // the best: one point where it is, no line
          { stroke: "#ffeb3b", fill: "#ffeb3b", width: 0, paths: () => null, points: { show: true, size: 9 } },
        ],
      },
      [[], [], []],
      element,
    );
  }

  start() {
    if (this.running) return;
    this.running = true;
    this.el.plot.hidden = false;
    if (this.plot === null) this.makePlot();
    this.loop();
  }

  stop() {
    this.running = false;
  }

  async loop() {
    while (this.running) {
      try {
        this.doc = await get(`/live/focus?history=${HISTORY}`);
        this.el.note.textContent = this.doc.latest
          ? `${this.doc.measured} figures, at most ${this.doc.rate_hz} a second`
          : "no figure yet: the figures are of the live frames while something streams";
        this.show();
      } catch (error) {
        this.el.note.textContent = `focus: ${error.message}`;
      }
      await new Promise((resolve) => setTimeout(resolve, POLL_MS));
    }
  }

  // The chosen target's figure, best and history (the targets: the frame and each ROI).
  show() {
    const doc = this.doc;
    if (doc === null) return;
    const targets = Object.keys(doc.latest?.values ?? { frame: null });
    const select = this.el.target;
    if ([...select.options].map((o) => o.value).join() !== targets.join()) {
      const chosen = select.value;
      select.replaceChildren(...targets.map((t) => new Option(t, t)));
      select.value = targets.includes(chosen) ? chosen : targets[0];
    }
    const target = select.value;
    const value = doc.latest?.values[target] ?? null;
    const best = doc.best[target] ?? null;
    this.shown = { value, best: best?.value ?? null, counter: doc.latest?.counter ?? null };
    this.el.value.textContent = fmt(value);
    this.el.best.textContent = best ? `${fmt(best.value)} at frame ${best.counter}` : "-";
    const h = doc.history;
    const values = h.values[target] ?? h.seq.map(() => null);
    const marks = h.seq.map((seq, i) => (best !== null && seq === best.seq ? values[i] : null));
    this.plot?.setData([h.t_s, values, marks]);
  }

  resize() {
    this.plot?.setSize({ width: Math.max(this.el.plot.getBoundingClientRect().width, 200), height: 150 });
  }
}
