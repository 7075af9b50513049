// Each viewer's transport (docs/live-view.md, "Transport"): the binning, rate and compression
// the daemon sends this page's frames with, chosen in the "transport" bar; the frames inflated
// (deflate) in the browser; and, while the display is binned, the readout's exact raw DN of
// the pixel under the cursor, asked of the daemon (GET /api/v1/live/pixel) for the frame on show.

import { API, ApiError, CLIENT } from "./api.js";

const $ = (id) => document.getElementById(id);
const LOOPBACK = ["127.0.0.1", "localhost", "[::1]", "::1"];

// The settings as the bar shows them: {bin, max_fps, compression}.
export function transportSettings() {
  return {
    bin: Number($("tx-bin").value),
    max_fps: Number($("tx-fps").value),
    compression: $("tx-compression").value,
  };
}

// The WebSocket's query for the settings (a reconnection keeps them).
export function transportQuery() {
  return new URLSearchParams(Object.entries(transportSettings()).map(([k, v]) => [k, String(v)])).toString();
}

// Wires the bar: the default compression is deflate but on this computer (loopback: bytes are
// free, the CPU is not), unless the page's address names the settings; a change is sent to the
// daemon through `send(settings)`.
export function initTransport(send) {
  if (!LOOPBACK.includes(location.hostname)) $("tx-compression").value = "deflate";
  // The address may name them (a bookmark for a viewer on a slow network):
  // /live?bin=4&max_fps=5&compression=deflate; a value the bar does not offer is ignored.
  const query = new URLSearchParams(location.search);
  for (const [key, id] of [["bin", "tx-bin"], ["max_fps", "tx-fps"], ["compression", "tx-compression"]]) {
    const value = query.get(key);
    if (value !== null && [...$(id).options].some((option) => option.value === value)) $(id).value = value;
  }
  for (const id of ["tx-bin", "tx-fps", "tx-compression"]) {
    $(id).addEventListener("change", () => send(transportSettings()));
  }
}

// The pixels of a frame as sent: inflated if deflated.
export async function framePixels(meta, buffer) {
  if (meta.compression !== "deflate") return buffer;
  const stream = new Blob([buffer]).stream().pipeThrough(new DecompressionStream("deflate"));
  return new Response(stream).arrayBuffer();
}

// What the bar says of the frame on show (binned or not, compression, bytes).
export function showTransport(meta) {
  const bin = meta.bin ?? 1;
  const size = meta.bytes === undefined ? "" : ` · ${(meta.bytes / 1024).toFixed(0)} kB a frame`;
  $("transport-note").textContent =
    (bin > 1
      ? `display binned ${bin}x${bin} (block means of the ${meta.frame_rows}x${meta.frame_cols} frame; the readout is raw)`
      : "display at full resolution") + ` · ${meta.compression ?? "none"}${size}`;
}

// The raw pixel under point (x, y) of the canvas when the frame on show is binned (null when
// not binned or off the image): {row, col, binned} in the camera's frame, binned = the block's
// mean on show.
export function binnedHit(view, x, y) {
  const frame = view.frame;
  const bin = frame?.meta.bin ?? 1;
  if (bin === 1) return null;
  const hit = view.pixelAt(x, y);
  if (hit === null) return null;
  const at = view.canvasToImage(x, y); // the camera frame's pixel, at any zoom
  return {
    row: Math.floor(at.row),
    col: Math.floor(at.col),
    binned: hit.raw,
    seq: frame.meta.seq,
  };
}

// One question to the daemon at a time; the newest point asked is the next asked.
const readout = { busy: false, wanted: null, known: new Map() };

// The raw DN of `hit` (binnedHit's) as text: known at once if asked before, else "…" and
// `show(text)` once the daemon answers (if the point is still the one wanted).
export function rawText(hit, show) {
  const key = `${hit.seq}:${hit.row}:${hit.col}`;
  if (readout.known.has(key)) return readout.known.get(key);
  readout.wanted = { key, hit, show };
  if (!readout.busy) askNext();
  return "…";
}

async function askNext() {
  const wanted = readout.wanted;
  if (wanted === null) return;
  readout.wanted = null;
  readout.busy = true;
  const { key, hit, show } = wanted;
  let text;
  try {
    const query = `seq=${hit.seq}&row=${hit.row}&col=${hit.col}`;
    const response = await fetch(`${API}/live/pixel?${query}`, { headers: { "X-Camd-Client": CLIENT }, cache: "no-store" });
    const body = await response.json();
    if (!response.ok) throw new ApiError(response.status, body.code, body.error);
    text = String(body.raw_dn);
    if (readout.known.size > 256) readout.known.clear();
    readout.known.set(key, text);
  } catch (error) {
    // The frame left the live view (409): the readout says so rather than a wrong value.
    text = error instanceof ApiError && error.code === "frame_gone" ? "gone" : "?";
  }
  readout.busy = false;
  if (readout.wanted === null) show(text);
  else askNext();
}
