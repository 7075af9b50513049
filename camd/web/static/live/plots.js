// Histogram and profile plots, drawn by uPlot (static/vendor/uplot).

/* global uPlot */

function makePlot(element, xLabel, yLabel, stroke, stepped) {
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
      scales: { x: { time: false } },
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
  }

  // counts over `bins` equal bins from lo to hi
  showHistogram(counts, lo, hi) {
    const n = counts.length;
    const width = (hi - lo) / n;
    const x = Array.from({ length: n }, (_, i) => lo + i * width);
    this.hist.setData([x, Array.from(counts)]);
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
