// Histogram and profile plots, drawn by uPlot (static/vendor/uplot). The histogram's counts may
// be on a log scale (empty bins are then left out: a log axis has no 0).

/* global uPlot */

function makePlot(element, xLabel, yLabel, stroke, stepped, log = false) {
  const width = Math.max(element.getBoundingClientRect().width, 200);
  const series = { stroke, width: 1, fill: stepped ? "rgba(79,195,247,0.15)" : undefined };
  if (stepped) series.paths = uPlot.paths.stepped({ align: 1 });
  const axis = { stroke: "#8b939c", grid: { stroke: "#2a2e33" }, ticks: { stroke: "#2a2e33" } };
  return new uPlot(
    {
      width,
      height: 170,
      legend: { show: false },
      cursor: { drag: { x: false, y: false } },
      scales: { x: { time: false }, y: log ? { distr: 3, log: 10 } : {} },
      axes: [{ ...axis, label: xLabel }, { ...axis, label: yLabel, size: 60 }],
      series: [{}, series],
    },
    [[0], [0]],
    element,
  );
}

export class Plots {
  constructor(histElement, profileElement) {
    this.hist = makePlot(histElement, "DN", "pixels", "#4fc3f7", true);
    this.profile = makePlot(profileElement, "pixel", "DN", "#ffb74d", false);
    this.histElement = histElement;
    this.profileElement = profileElement;
    this.histLog = false;
  }

  // A uPlot's scale kind is fixed when it is made: a new histogram plot for the other one.
  setHistogramLog(log) {
    if (log === this.histLog) return;
    this.histLog = log;
    this.hist.destroy();
    this.hist = makePlot(this.histElement, "DN", log ? "pixels (log)" : "pixels", "#4fc3f7", true, log);
  }

  // counts over `bins` equal bins from lo to hi
  showHistogram(counts, lo, hi) {
    const n = counts.length;
    const width = (hi - lo) / n;
    const x = Array.from({ length: n }, (_, i) => lo + i * width);
    const y = Array.from(counts, (c) => (this.histLog && c <= 0 ? null : c));
    this.hist.setData([x, y]);
  }

  showProfile(profile) {
    if (profile === null) return;
    this.profile.axes[0].label = profile.label;
    this.profile.setData([profile.x, profile.y]);
  }

  resize() {
    for (const [plot, element] of [[this.hist, this.histElement], [this.profile, this.profileElement]]) {
      plot.setSize({ width: Math.max(element.getBoundingClientRect().width, 200), height: 170 });
    }
  }
}
