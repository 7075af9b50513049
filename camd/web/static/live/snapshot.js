// Snapshots (docs/live-view.md, "Snapshots"): the buttons that download the frame on show as a
// TIFF of raw DN with its settings, the canvas as displayed as a PNG, and the ROIs' statistics
// on that frame as CSV. The TIFF and the CSV are asked for by the shown frame's seq: if the
// live view has moved on, the daemon says so (409 frame_gone) rather than save another frame.

import { API, ApiError, CLIENT } from "./api.js";

// Saves `blob` as `name` through a temporary link (the browser's download).
function download(blob, name) {
  const url = URL.createObjectURL(blob);
  const link = document.createElement("a");
  link.href = url;
  link.download = name;
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

async function fetchFile(path, seq) {
  const response = await fetch(`${API}/live/snapshot/${path}?seq=${seq}`, {
    headers: { "X-Camd-Client": CLIENT },
    cache: "no-store",
  });
  if (!response.ok) {
    const body = await response.json().catch(() => ({}));
    throw new ApiError(response.status, body.code ?? "http_error", body.error ?? response.statusText);
  }
  return response.blob();
}

// Wires the buttons #snapshot-tiff, #snapshot-png and #snapshot-csv. `shownMeta()` gives the
// description of the frame on show (null before one); `canvas` is the displayed image;
// `report(text, kind)` shows the outcome.
export function initSnapshots(shownMeta, canvas, report) {
  const name = (meta, suffix) => `camd-snapshot-${meta.seq}.${suffix}`;
  const save = async (what, suffix, make) => {
    const meta = shownMeta();
    if (!meta) {
      report(`${what}: no frame on show yet: start a stream, a stare or a scan`);
      return;
    }
    try {
      download(await make(meta), name(meta, suffix));
      report(`${what}: saved ${name(meta, suffix)}`, "info");
    } catch (error) {
      report(`${what}: ${error instanceof ApiError ? error.message : error}`);
    }
  };
  document.getElementById("snapshot-tiff").addEventListener("click", () =>
    save("TIFF snapshot", "tiff", (meta) => fetchFile("frame.tiff", meta.seq)),
  );
  document.getElementById("snapshot-csv").addEventListener("click", () =>
    save("ROI statistics", "csv", (meta) => fetchFile("roi.csv", meta.seq)),
  );
  document.getElementById("snapshot-png").addEventListener("click", () =>
    save(
      "PNG of the display",
      "png",
      () => new Promise((resolve, reject) =>
        canvas.toBlob((blob) => (blob ? resolve(blob) : reject(new Error("the canvas is empty"))), "image/png"),
      ),
    ),
  );
}
